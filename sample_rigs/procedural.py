"""A procedural humanoid whose true surface is known exactly (numpy only, no Blender).

Limbs and phalanges are capsules of known radii around their bones, the torso is an ellipsoid,
the head a sphere, palms and soles are boxes. Raycasting tests measure this avatar and compare
against `ProceduralAvatar.truth`. Bone names follow the Unreal-style rig of the shared MakeHuman
avatars so the same bone map applies. Rest pose is a T-pose (or an A-pose with `arm_drop_deg`),
facing -Y, left side at +X, metres, feet on z = 0 (Blender's conventions).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

FINGERS = ("thumb", "index", "middle", "ring", "pinky")
SIDES = {"l": 1.0, "r": -1.0}


@dataclass
class BoneSpec:
    head: np.ndarray
    tail: np.ndarray
    parent: str | None
    # Direction the bone's local +Z should point to (Blender's align_roll): it fixes local +X,
    # the flexion axis of hinge joints (FORMATS.md §1).
    z_axis: np.ndarray


@dataclass
class Part:
    name: str
    bone: str
    vertices: np.ndarray  # (n, 3)
    faces: np.ndarray  # (m, 4) quads or (m, 3) triangles, as a list of polygons


@dataclass
class ProceduralAvatar:
    name: str
    bones: dict[str, BoneSpec]
    parts: list[Part]
    truth: dict = field(default_factory=dict)


def capsule_mesh(head, tail, radius, segments=48, rings=12):
    """Closed capsule around head->tail. Vertices lie on the exact capsule surface."""
    head, tail = np.asarray(head, float), np.asarray(tail, float)
    axis = tail - head
    length = np.linalg.norm(axis)
    y = axis / length
    ref = np.array([0.0, 0.0, 1.0]) if abs(y[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(y, ref)
    x /= np.linalg.norm(x)
    z = np.cross(x, y)
    theta = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    # Hemisphere latitudes from the head pole to the equator, then equator to tail pole.
    phi_lo = np.linspace(-np.pi / 2, 0.0, rings + 1)
    phi_hi = np.linspace(0.0, np.pi / 2, rings + 1)
    circles = []
    for phi, centre in [(p, head) for p in phi_lo] + [(p, tail) for p in phi_hi]:
        c = centre + y * radius * np.sin(phi)
        r = radius * np.cos(phi)
        circles.append(c + r * (np.outer(np.cos(theta), x) + np.outer(np.sin(theta), z)))
    return _lathe(circles, segments)


def ellipsoid_mesh(center, semi_axes, segments=96, rings=48):
    """Closed ellipsoid; vertices on the exact surface."""
    center, semi_axes = np.asarray(center, float), np.asarray(semi_axes, float)
    theta = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    circles = []
    for phi in np.linspace(-np.pi / 2, np.pi / 2, rings + 1):
        ring = np.stack([np.cos(phi) * np.cos(theta), np.cos(phi) * np.sin(theta),
                         np.full_like(theta, np.sin(phi))], axis=1)
        circles.append(center + ring * semi_axes)
    return _lathe(circles, segments)


def box_mesh(lo, hi):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    v = np.array([[lo[0], lo[1], lo[2]], [hi[0], lo[1], lo[2]], [hi[0], hi[1], lo[2]], [lo[0], hi[1], lo[2]],
                  [lo[0], lo[1], hi[2]], [hi[0], lo[1], hi[2]], [hi[0], hi[1], hi[2]], [lo[0], hi[1], hi[2]]])
    f = np.array([[0, 3, 2, 1], [4, 5, 6, 7], [0, 1, 5, 4], [1, 2, 6, 5], [2, 3, 7, 6], [3, 0, 4, 7]])
    return v, f


def _lathe(circles, segments):
    """Quads between consecutive rings; degenerate pole rings collapse to one vertex each."""
    verts = [circles[0][:1]]
    for c in circles[1:-1]:
        verts.append(c)
    verts.append(circles[-1][:1])
    verts = np.concatenate(verts)
    n_mid = len(circles) - 2
    faces = []
    j = np.arange(segments)
    jn = (j + 1) % segments
    ring0 = 1
    # Bottom fan as degenerate quads -> triangles.
    faces += [[0, ring0 + b, ring0 + a] for a, b in zip(j, jn)]
    for k in range(n_mid - 1):
        a0, a1 = ring0 + k * segments, ring0 + (k + 1) * segments
        faces += [[a0 + a, a0 + b, a1 + b, a1 + a] for a, b in zip(j, jn)]
    last = ring0 + (n_mid - 1) * segments
    top = len(verts) - 1
    faces += [[last + a, last + b, top] for a, b in zip(j, jn)]
    return verts, faces


def build_spec(name: str = "procedural", scale: float = 1.0, arm_drop_deg: float = 0.0,
               belly: float = 0.0) -> ProceduralAvatar:
    """The avatar at `scale` (1.0 is 1.76 m tall). `arm_drop_deg` lowers the arms from the T-pose
    into an A-pose; `belly` pushes the torso ellipsoid's front semi-axis out by that many metres."""
    s = scale
    bones: dict[str, BoneSpec] = {}
    parts: list[Part] = []
    truth: dict = {"capsules": {}, "scale": s}
    up, fwd = np.array([0.0, 0, 1]), np.array([0.0, -1, 0])

    def bone(n, h, t, parent, z_axis):
        bones[n] = BoneSpec(np.asarray(h, float) * s, np.asarray(t, float) * s, parent,
                            np.asarray(z_axis, float))

    def capsule(n, r):
        b = bones[n]
        v, f = capsule_mesh(b.head, b.tail, r * s)
        parts.append(Part(f"capsule_{n}", n, v, f))
        truth["capsules"][n] = {"head": b.head.copy(), "tail": b.tail.copy(), "radius": r * s}

    bone("Root", [0, 0, 0], [0, 0.1, 0], None, up)
    bone("pelvis", [0, 0, 0.95], [0, 0, 1.10], "Root", fwd)
    bone("spine_01", [0, 0, 1.10], [0, 0, 1.24], "pelvis", fwd)
    bone("spine_02", [0, 0, 1.24], [0, 0, 1.36], "spine_01", fwd)
    bone("spine_03", [0, 0, 1.36], [0, 0, 1.46], "spine_02", fwd)
    bone("neck_01", [0, 0, 1.46], [0, 0, 1.56], "spine_03", fwd)
    bone("head", [0, 0, 1.56], [0, 0, 1.76], "neck_01", fwd)
    drop = np.radians(arm_drop_deg)
    for side, sx in SIDES.items():
        out = np.array([sx * np.cos(drop), 0.0, -np.sin(drop)])  # along the arm, away from the body
        shoulder = np.array([sx * 0.18, 0.0, 1.42])
        elbow = shoulder + 0.28 * out
        wrist = elbow + 0.25 * out
        hand_end = wrist + 0.09 * out
        palm_down = -up - np.dot(-up, out) * out  # straight down, made perpendicular to the arm
        palm_down /= np.linalg.norm(palm_down)
        bone(f"clavicle_{side}", [sx * 0.02, 0, 1.42], shoulder, "spine_03", fwd)
        # Elbow flexion brings the hand forward: local +Z forward makes +X the flexion axis.
        bone(f"upperarm_{side}", shoulder, elbow, f"clavicle_{side}", fwd)
        bone(f"lowerarm_{side}", elbow, wrist, f"upperarm_{side}", fwd)
        bone(f"hand_{side}", wrist, hand_end, f"lowerarm_{side}", palm_down)
        finger_y = {"index": -0.030, "middle": -0.010, "ring": 0.010, "pinky": 0.028}
        lengths = {"index": (0.045, 0.027, 0.022), "middle": (0.050, 0.030, 0.024),
                   "ring": (0.046, 0.028, 0.022), "pinky": (0.036, 0.022, 0.019),
                   "thumb": (0.040, 0.032, 0.026)}
        for f in FINGERS:
            if f == "thumb":
                base = wrist + 0.03 * out + np.array([0, -0.035, -0.01])
                direction = out * 0.7 + fwd * 0.7
            else:
                base = hand_end + np.array([0, finger_y[f], 0])
                direction = out.copy()
            direction = direction / np.linalg.norm(direction)
            head = base
            for i, length in enumerate(lengths[f], start=1):
                tail = head + length * direction
                parent = f"hand_{side}" if i == 1 else f"{f}_{i - 1:02d}_{side}"
                # Fingers curl toward the palm: local +Z toward the palm side.
                bone(f"{f}_{i:02d}_{side}", head, tail, parent, palm_down)
                head = tail
        capsule(f"upperarm_{side}", 0.050)
        capsule(f"lowerarm_{side}", 0.040)
        for f in FINGERS:
            for i in (1, 2, 3):
                capsule(f"{f}_{i:02d}_{side}", 0.0095 if f == "thumb" else 0.0085)
        # Palm box in the hand bone's frame: 0.09 along the hand, 0.08 wide, 0.03 thick.
        hb = bones[f"hand_{side}"]
        v, fc = box_mesh([0.0, -0.045, -0.015], [0.09, 0.045, 0.015])
        hand_x = (hb.tail - hb.head) / np.linalg.norm(hb.tail - hb.head)
        hand_z = -palm_down
        hand_y = np.cross(hand_z, hand_x)
        rot = np.stack([hand_x, hand_y, hand_z], axis=1)
        parts.append(Part(f"palm_{side}", f"hand_{side}", (v * s) @ rot.T + hb.head, fc))
        truth.setdefault("palms", {})[side] = {"origin": hb.head.copy(), "normal_down": palm_down,
                                               "half_thickness": 0.015 * s}

        hip = np.array([sx * 0.10, 0.0, 0.92])
        knee = np.array([sx * 0.10, 0.0, 0.50])
        ankle = np.array([sx * 0.10, 0.0, 0.08])
        ball = np.array([sx * 0.10, -0.14, 0.02])
        bone(f"thigh_{side}", hip, knee, "pelvis", -fwd)
        # Knee flexion moves the shin backward: local +Z backward makes +X the flexion axis.
        bone(f"calf_{side}", knee, ankle, f"thigh_{side}", -fwd)
        bone(f"foot_{side}", ankle, ball, f"calf_{side}", up)
        bone(f"ball_{side}", ball, ball + np.array([0, -0.06, 0]), f"foot_{side}", up)
        capsule(f"thigh_{side}", 0.075)
        capsule(f"calf_{side}", 0.055)
        v, fc = box_mesh([sx * 0.10 - 0.045, -0.22, 0.0], [sx * 0.10 + 0.045, 0.06, 0.07])
        parts.append(Part(f"foot_{side}", f"foot_{side}", v * s, fc))
        truth.setdefault("soles", {})[side] = {"z": 0.0, "x": (sx * 0.10 - 0.045) * s, "x2": (sx * 0.10 + 0.045) * s,
                                               "y": (-0.22 * s, 0.06 * s)}
    capsule("neck_01", 0.055)
    torso_c = np.array([0.0, 0.0, 1.18]) * s
    torso_axes = np.array([0.17, 0.12, 0.30]) * s
    if belly:
        # A belly pushes the front out: shift the centre forward by half and grow the y axis by half.
        torso_c = torso_c + np.array([0.0, -belly / 2, 0.0])
        torso_axes = torso_axes + np.array([0.0, belly / 2, 0.0])
    v, fc = ellipsoid_mesh(torso_c, torso_axes)
    parts.append(Part("torso", "spine_01", v, fc))
    truth["torso"] = {"center": torso_c, "semi_axes": torso_axes}
    head_c = np.array([0.0, 0.0, 1.66]) * s
    v, fc = ellipsoid_mesh(head_c, np.full(3, 0.10 * s), segments=64, rings=32)
    parts.append(Part("skull", "head", v, fc))
    truth["skull"] = {"center": head_c, "radius": 0.10 * s}
    truth["height"] = float(head_c[2] + 0.10 * s)
    return ProceduralAvatar(name, bones, parts, truth)


def torso_surface_distance(points: np.ndarray, center: np.ndarray, semi_axes: np.ndarray) -> np.ndarray:
    """Approximate distance of points to the ellipsoid surface (exact on the surface, first order
    near it): |F(p)| / |grad F(p)| with F(p) = |(p - c)/a|² - 1."""
    q = (np.asarray(points) - center) / semi_axes
    f = (q**2).sum(-1) - 1.0
    grad = 2.0 * q / semi_axes
    return np.abs(f) / np.linalg.norm(grad, axis=-1)
