"""Small programmatic body models for the retargeting math tests (numpy only; not collected: no test_ prefix).

`standing_joints()` gives a plausible standing performer (facing -Y, left at +X, arms down, metres,
feet on the floor); `make_body_model(joints)` builds a BodyModel with every canonical bone, capsule
radii and the full shared surface (limb and finger capsules, skull sphere, torso/jaw/palm/sole
crude meshes, surface_layout ids); `pose_joints` / `bone_frames` give per-frame joints and bone
frames for `egocentric.pose_surface`.
"""

from __future__ import annotations

import copy

import numpy as np

from bodycal_addon.body import skeleton as sk
from bodycal_addon.body import surface_layout as sl
from bodycal_addon.body.bodymodel import BodyModel, BoneInfo, Joint, SurfaceElement, SurfacePoint
from bodycal_addon.core.transforms import frame_from_axes

RADII = {"upperarm": (0.045, 0.038), "forearm": (0.036, 0.028), "thigh": (0.075, 0.055), "shin": (0.05, 0.038)}
FINGER_RADIUS = (0.009, 0.008)
FINGER_X = {"thumb": 0.0, "index": 0.03, "middle": 0.01, "ring": -0.01, "pinky": -0.03}
PHALANGES = {"thumb": (0.04, 0.03, 0.025), "index": (0.045, 0.025, 0.02), "middle": (0.05, 0.03, 0.022),
             "ring": (0.047, 0.028, 0.02), "pinky": (0.036, 0.02, 0.018)}


def standing_joints(belly: float = 0.0) -> dict[str, np.ndarray]:
    """Canonical joints of a 1.75 m performer standing, arms down; `belly` pushes the belly
    points forward (used by make_body_model)."""
    j = {"pelvis": np.array([0.0, 0.0, 0.95])}
    j["spine_root"] = j["pelvis"] + [0.0, 0.05, 0.10]
    j["skull_base"] = np.array([0.0, 0.02, 1.58])
    for k in range(1, sk.SPINE_COUNT + 1):
        j[sk.spine_joint(k)] = j["spine_root"] + (j["skull_base"] - j["spine_root"]) * k / sk.SPINE_COUNT
    j["head"] = np.array([0.0, -0.02, 1.72])
    for s, sx in (("l", 1.0), ("r", -1.0)):
        j[f"clavicle_{s}"] = j[sk.spine_joint(sk.CLAVICLE_VERTEBRA)]
        j[f"shoulder_{s}"] = np.array([0.18 * sx, 0.02, 1.42])
        j[f"elbow_{s}"] = np.array([0.22 * sx, 0.03, 1.12])
        j[f"wrist_{s}"] = np.array([0.24 * sx, 0.0, 0.87])
        for f in sk.FINGERS:
            l1, l2, l3 = PHALANGES[f]
            if f == "thumb":
                mcp = j[f"wrist_{s}"] + [0.0, -0.035, -0.04]
                step = np.array([0.0, -0.5, -0.866])
            else:
                mcp = j[f"wrist_{s}"] + [0.0, FINGER_X[f], -0.09]
                step = np.array([0.0, 0.0, -1.0])
            j[f"mcp_{f}_{s}"] = mcp
            j[f"pip_{f}_{s}"] = mcp + l1 * step
            j[f"dip_{f}_{s}"] = mcp + (l1 + l2) * step
            j[f"tip_{f}_{s}"] = mcp + (l1 + l2 + l3) * step
        j[f"hip_{s}"] = np.array([0.09 * sx, 0.0, 0.92])
        j[f"knee_{s}"] = np.array([0.10 * sx, -0.01, 0.50])
        j[f"ankle_{s}"] = np.array([0.10 * sx, 0.02, 0.08])
        j[f"toe_{s}"] = np.array([0.11 * sx, -0.13, 0.02])
    return j


def right_hint(direction: np.ndarray) -> np.ndarray:
    """A bone's `right` for the test bodies: world +X unless the bone lies along X."""
    d = np.asarray(direction, float)
    d = d / max(np.linalg.norm(d), 1e-12)
    return np.array([0.0, -1.0, 0.0]) if abs(d[0]) > 0.8 else np.array([1.0, 0.0, 0.0])


def bone_frames(joints: dict[str, np.ndarray], rights: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Bone frames (..., 3, 3) from joints (..., 3) and each bone's right (..., 3)."""
    out = {}
    for b in sk.BONES:
        if b.head in joints and b.tail in joints and b.name in rights:
            out[b.name] = frame_from_axes(joints[b.tail] - joints[b.head], rights[b.name])
    return out


def _local(frames, joints, bone, world):
    return frames[bone].T @ (np.asarray(world, float) - joints[sk.BONE_BY_NAME[bone].head])


def make_body_model(joints: dict[str, np.ndarray] | None = None, kind: str = "user", belly: float = 0.0,
                    name: str = "test") -> BodyModel:
    """A BodyModel with every canonical bone and the full shared surface built around `joints`
    (default standing_joints()). `belly` (m) pushes the front belly points forward."""
    j = {k: np.asarray(v, float) for k, v in (joints or standing_joints()).items()}
    rights = {b.name: right_hint(j[b.tail] - j[b.head]) for b in sk.BONES}
    frames = bone_frames(j, rights)
    bones = {}
    for b in sk.BONES:
        length = float(np.linalg.norm(j[b.tail] - j[b.head]))
        part = b.name.rsplit("_", 1)[0]
        rh = rt = None
        if part in RADII:
            rh, rt = RADII[part]
        elif b.name.split("_")[0] in sk.FINGERS and b.name.split("_")[1] in "123":
            rh, rt = FINGER_RADIUS
        bones[b.name] = BoneInfo(b.head, b.tail, length, rights[b.name], rh, rt)
    surface = [SurfaceElement(f"capsule:{b}", "capsule", b) for b in sl.CAPSULE_BONES]
    skull_centre = j["head"] + [0.0, 0.03, -0.02]
    surface.append(SurfaceElement("sphere:skull", "sphere", "head", center=_local(frames, j, "head", skull_centre),
                                  radius=0.09))
    # Torso crude mesh, around the spine, front at y = -0.12 (plus the belly), back at +0.12.
    spine = np.stack([j[sk.spine_joint(k)] for k in range(sk.SPINE_COUNT + 1)])
    front = {"sternum": (0.0, 1.36), "chest_l": (0.11, 1.30), "chest_r": (-0.11, 1.30),
             "belly_ul": (0.11, 1.12), "belly_ur": (-0.11, 1.12), "belly_ll": (0.10, 0.97),
             "belly_lr": (-0.10, 0.97)}
    tw = {k: np.array([x, -0.12 - (belly if k.startswith("belly") else 0.0), z]) for k, (x, z) in front.items()}
    centre = sl.belly_centre_points(tw["belly_ul"], tw["belly_ur"], tw["belly_ll"], tw["belly_lr"])
    for k, v in centre.items():
        tw[k] = v + [0.0, -0.5 * belly, 0.0]
    tw.update({"back_ul": np.array([0.11, 0.14, 1.30]), "back_ur": np.array([-0.11, 0.14, 1.30]),
               "back_low": np.array([0.0, 0.14, 1.00])})
    pts = {}
    for k in sl.TORSO_POINTS:
        bone = sl.nearest_vertebra(tw[k], spine)
        pts[k] = SurfacePoint(bone, _local(frames, j, bone, tw[k]))
    surface.append(SurfaceElement("mesh:torso", "mesh", "spine_05", points=pts, triangles=list(sl.TORSO_TRIANGLES)))
    h = j["head"]
    jaw = {"ear_l": h + [0.07, 0.02, -0.02], "ear_r": h + [-0.07, 0.02, -0.02], "upper_lip": h + [0.0, -0.10, -0.06],
           "chin": h + [0.0, -0.09, -0.13], "jaw_l": h + [0.05, -0.05, -0.10], "jaw_r": h + [-0.05, -0.05, -0.10]}
    jaw_points = {k: SurfacePoint("head", _local(frames, j, "head", v)) for k, v in jaw.items()}
    surface.append(SurfaceElement("mesh:jaw", "mesh", "head", points=jaw_points, triangles=list(sl.JAW_TRIANGLES)))
    for s, sx in (("l", 1.0), ("r", -1.0)):
        w = j[f"wrist_{s}"]
        # Palm on the inner side of the hand (facing the thigh: -X for the left hand).
        corners = [w + [-0.01 * sx, 0.035, -0.02], w + [-0.01 * sx, -0.035, -0.02],
                   w + [-0.01 * sx, -0.035, -0.09], w + [-0.01 * sx, 0.035, -0.09]]
        names = sl.palm_points(4, s)
        corners = _outward(corners, np.array([-sx, 0.0, 0.0]))
        surface.append(SurfaceElement(f"mesh:palm_{s}", "mesh", f"hand_{s}",
                                      points={n: SurfacePoint(f"hand_{s}", _local(frames, j, f"hand_{s}", c))
                                              for n, c in zip(names, corners)},
                                      triangles=sl.fan_triangles(names)))
        a = j[f"ankle_{s}"]
        corners = [a + [0.04, 0.06, -0.08], a + [-0.04, 0.06, -0.08], a + [-0.04, -0.16, -0.08],
                   a + [0.04, -0.16, -0.08]]
        corners = _outward(corners, np.array([0.0, 0.0, -1.0]))
        names = sl.sole_points(4, s)
        surface.append(SurfaceElement(f"mesh:sole_{s}", "mesh", f"foot_{s}",
                                      points={n: SurfacePoint(f"foot_{s}", _local(frames, j, f"foot_{s}", c))
                                              for n, c in zip(names, corners)},
                                      triangles=sl.fan_triangles(names)))
    return BodyModel(kind, name, {k: Joint(v) for k, v in j.items()}, bones, surface)


def _outward(corners, out_dir):
    c = [np.asarray(x, float) for x in corners]
    n = np.cross(c[1] - c[0], c[2] - c[0])
    return c if n @ out_dir > 0 else c[::-1]


def scale_model(model: BodyModel, s: float) -> BodyModel:
    """The model uniformly scaled by s about the origin (joints, lengths, radii, local points)."""
    out = copy.deepcopy(model)  # not through JSON: it rounds to 7 decimals
    for jt in out.joints.values():
        jt.world = jt.world * s
    for b in out.bones.values():
        b.length *= s
        b.radius_head = None if b.radius_head is None else b.radius_head * s
        b.radius_tail = None if b.radius_tail is None else b.radius_tail * s
    for e in out.surface:
        if e.center is not None:
            e.center = e.center * s
        if e.radius is not None:
            e.radius *= s
        for p in e.points.values():
            p.local = p.local * s
    return out


def random_rotations(rng, n: int) -> np.ndarray:
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                     2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                     2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1).reshape(n, 3, 3)


def pose_joints(model: BodyModel, frames: int, rng, noise: float = 0.05, turn: bool = True):
    """Random poses for invariance tests: the model's joints jittered by `noise` (m) and turned
    about the vertical (feet stay above the floor). Returns (joints {name: (F, 3)}, bone frames)."""
    angle = rng.uniform(-np.pi, np.pi, frames) if turn else np.zeros(frames)
    c, s = np.cos(angle), np.sin(angle)
    rz = np.zeros((frames, 3, 3))
    rz[:, 0, 0], rz[:, 0, 1], rz[:, 1, 0], rz[:, 1, 1], rz[:, 2, 2] = c, -s, s, c, 1.0
    joints = {}
    for name, jt in model.joints.items():
        joints[name] = np.einsum("fij,j->fi", rz, jt.world) + rng.normal(scale=noise, size=(frames, 3))
    rights = {b: np.einsum("fij,j->fi", rz, info.right) for b, info in model.bones.items() if info.right is not None}
    return joints, bone_frames(joints, rights)
