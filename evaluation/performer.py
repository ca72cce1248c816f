"""A BVH clip's skeleton as a performer: its body parts, its joint centres (the truth), its hinge
axes, and the calibration motions of FORMATS.md §2.4 performed by that same skeleton.

The lab frame is Z up, metres, floor at z = 0 (the CMU floor). A pose is the WORLD rotation of
every BVH joint's frame (n, J, 3, 3) and the root position (n, 3); positions follow by forward
kinematics on the clip's own offsets, so the calibration motions move exactly the bones the clip
moves. Poses are built in the performer's body frame (forward -Y, left +X, up +Z: the CMU rest
pose after `bvh.Y_UP_TO_Z_UP`) and turned by the heading of the clip's first frame.

Anatomy used to build poses (not the engine's numbers):
- hinges: the elbow and knee axes are fitted to the clip's own local rotations (a real CMU
  skeleton's elbow / knee turn about one local axis to within a degree); positive angles flex;
- the standing foot: the clip's own mean foot orientation (relative to the pelvis heading) and
  ankle height over its stance frames, so the calibration stands on the floor the clip walks on;
- the T-pose palms face down (the protocol); the hand keeps that relation to the forearm throughout.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import rot
from .bvh import Clip

SIDES = ("l", "r")
FORWARD = np.array([0.0, -1.0, 0.0])
LEFT = np.array([1.0, 0.0, 0.0])
UP = np.array([0.0, 0.0, 1.0])

# Body parts -> BVH joint names of the two CMU naming schemes ({S} = Left / Right).
SCHEMES = {
    "cmu_cgspeed": {  # 02_01 and most of the cgspeed release
        "pelvis": "Hips", "hip": "{S}UpLeg", "knee": "{S}Leg", "ankle": "{S}Foot", "toe": "{S}ToeBase",
        "chest": "Spine1", "neck": "Neck1", "skull_base": "Head", "clavicle": "{S}Shoulder", "shoulder": "{S}Arm",
        "elbow": "{S}ForeArm", "wrist": "{S}Hand", "fingers": "{S}HandIndex1",
    },
    "cmu_max": {  # the "3dsmax-friendly" release (131_*)
        "pelvis": "Hips", "hip": "{S}Hip", "knee": "{S}Knee", "ankle": "{S}Ankle", "toe": "{S}Toe",
        "chest": "Chest2", "neck": "Neck", "skull_base": "Head", "clavicle": "{S}Collar", "shoulder": "{S}Shoulder",
        "elbow": "{S}Elbow", "wrist": "{S}Wrist", "fingers": "{L}Fingers",
    },
}
SIDE_WORD = {"l": "Left", "r": "Right"}
TRUTH_JOINTS = ("pelvis", "hip_l", "hip_r", "knee_l", "knee_r", "ankle_l", "ankle_r", "toe_l", "toe_r",
                "shoulder_l", "shoulder_r", "elbow_l", "elbow_r", "wrist_l", "wrist_r", "skull_base")
STANCE_SPEED = 0.15  # m/s: a foot is in stance while its ankle moves slower than this ...
STANCE_HEIGHT = 0.04  # ... and is within this of its lowest height in the clip


@dataclass
class Pose:
    G: np.ndarray  # (n, J, 3, 3) world rotation of every joint's frame
    root: np.ndarray  # (n, 3)

    def __len__(self):
        return self.G.shape[0]


def _scheme(names: list[str]) -> dict[str, int]:
    for scheme in SCHEMES.values():
        out = {}
        for part, pattern in scheme.items():
            for s in SIDES:
                name = pattern.format(S=SIDE_WORD[s], L=s.upper() if s == "l" else "R")
                key = part if "{" not in pattern else f"{part}_{s}"
                if name in names:
                    out[key] = names.index(name)
        if len(out) == sum(2 if "{" in p else 1 for p in scheme.values()):
            return out
    raise ValueError("not a CMU skeleton this tool knows (joint names)")


MAX_TURN_DEG_PER_S = 1500.0  # faster than a wrist's or ankle's fastest real turn: a solver's glitch


def repair_glitches(clip: Clip) -> Clip:
    """The clip with its rotation glitches bridged: a joint whose local rotation turns faster than
    MAX_TURN_DEG_PER_S between two frames (131_01's right wrist turns 65 degrees in 1/120 s, an
    Euler flip or a marker swap of the original solve, not a motion) is interpolated, frame by
    frame, across the run of glitching frames from the last good frame to the next."""
    local = clip.local.copy()
    limit = np.radians(MAX_TURN_DEG_PER_S) / clip.fps
    for j in range(len(clip.joints)):
        bad = np.zeros(len(local), bool)
        for grow in range(1, 12):  # a glitch lasting several frames: widen until it is bridged
            turn = np.linalg.norm(rot.log(np.swapaxes(local[:-1, j], -1, -2) @ local[1:, j]), axis=-1)
            jumps = np.flatnonzero(turn > limit)
            if not len(jumps):
                break
            for d in range(-grow + 1, grow + 1):
                bad[np.clip(jumps + d, 0, len(local) - 1)] = True
            good = np.flatnonzero(~bad)
            if len(good) < 2:
                break
            idx = np.flatnonzero(bad)
            k = np.clip(np.searchsorted(good, idx) - 1, 0, len(good) - 2)
            a, b = good[k], good[k + 1]
            frac = np.clip((idx - a) / np.maximum(b - a, 1), 0.0, 1.0)
            local[idx, j] = rot.interpolate(clip.local[a, j], clip.local[b, j], frac)
    return Clip(clip.name, clip.joints, clip.parents, clip.offsets, local, clip.root, clip.fps)


def _rigid_pelvis(clip: Clip, hips: list[int]) -> tuple[Clip, dict[int, np.ndarray]]:
    """The clip with a rigid pelvis, and the fixed local rotations it holds. Some CMU conversions
    (02_01) turn the `LHipJoint` / `RHipJoint` bones between the root and the hips by 5-13 degrees
    per frame, which moves a hip joint by centimetres against the pelvis: no tracker on a pelvis
    could see that. Those bones are held at their mean rotation and the thighs keep their world
    orientation. The calibration poses hold them the same way (`Performer.pose`): at the BVH's
    rest instead, 02_01's hips sat 14-19 mm elsewhere on the pelvis than in the clip."""
    local = clip.local.copy()
    root = int(np.flatnonzero(clip.parents < 0)[0])
    held = {}
    for h in hips:
        between = clip.parents[h]
        if between != root and clip.parents[between] == root and np.linalg.norm(clip.offsets[between]) < 1e-9:
            u, _, vt = np.linalg.svd(local[:, between].mean(axis=0))
            fixed = u @ vt
            local[:, h] = fixed.T @ local[:, between] @ local[:, h]
            local[:, between] = fixed
            held[int(between)] = fixed
    return Clip(clip.name, clip.joints, clip.parents, clip.offsets, local, clip.root, clip.fps), held


def _smooth_noise(rng, n: int, fps: float, dims: int, rms: float, low=0.2, high=1.2) -> np.ndarray:
    """Band-limited random motion (a few sinusoids between `low` and `high` Hz), RMS `rms` per dim."""
    t = np.arange(n) / fps
    out = np.zeros((n, dims))
    for _ in range(4):
        f = rng.uniform(low, high, dims)
        ph = rng.uniform(0, 2 * np.pi, dims)
        out += np.sin(2 * np.pi * f[None] * t[:, None] + ph[None])
    return out * rms / np.sqrt(2.0)


def hanging(theta, alpha, side: str, down_flex):
    """Direction of a limb raised `theta` from hanging down, toward azimuth `alpha` (0 = forward,
    +90° = out to its side), and its hinge's flexion direction: the hanging one carried along."""
    lateral = LEFT * (1.0 if side == "l" else -1.0)
    theta, alpha = np.asarray(theta, float), np.asarray(alpha, float)
    horiz = np.cos(alpha)[..., None] * FORWARD + np.sin(alpha)[..., None] * lateral
    d = -np.cos(theta)[..., None] * UP + np.sin(theta)[..., None] * horiz
    # the minimal rotation from down to d, applied to the hanging flexion direction
    axis = np.cross(-UP, d)
    flex = np.where(np.linalg.norm(axis, axis=-1, keepdims=True) > 1e-9,
                    np.einsum("...ij,j->...i", rot.axis_angle(axis, theta), down_flex), down_flex)
    return d, flex


class Performer:
    """A CMU clip's skeleton as a performer."""

    def __init__(self, clip: Clip):
        self.parts = _scheme(clip.joints)
        clip, self.held = _rigid_pelvis(repair_glitches(clip), [self.parts["hip_l"], self.parts["hip_r"]])
        self.clip = clip
        self.parents = clip.parents
        self.offsets = clip.offsets
        G, P = clip.fk()
        self._clip_G, self._clip_P = G, P
        self.children = {j: [k for k, p in enumerate(clip.parents) if p == j] for j in range(len(clip.joints))}
        self.hinge = {f"{j}_{s}": self._fit_hinge(f"{j}_{s}") for j in ("elbow", "knee") for s in SIDES}
        self.stance = {s: self._stance(s) for s in SIDES}
        self.heading = self._heading(G, P)  # (F, 3, 3) yaw of the pelvis per clip frame
        self._stand_foot = {s: self._standing_foot(s) for s in SIDES}
        H = self.truth_positions(P)
        self.leg_length = float(np.mean([np.linalg.norm(H[0, TRUTH_JOINTS.index(f"knee_{s}")] -
                                                        H[0, TRUTH_JOINTS.index(f"hip_{s}")]) +
                                         np.linalg.norm(H[0, TRUTH_JOINTS.index(f"ankle_{s}")] -
                                                        H[0, TRUTH_JOINTS.index(f"knee_{s}")]) for s in SIDES]))

    # --- the skeleton ---------------------------------------------------------------------------

    def j(self, part: str) -> int:
        return self.parts[part]

    def child_offset(self, joint: int) -> np.ndarray:
        """The offset of the first descendant that is not at the joint itself (the segment's
        direction and length in its own frame)."""
        stack = list(self.children[joint])
        while stack:
            k = stack.pop(0)
            if np.linalg.norm(self.offsets[k]) > 1e-6:
                return self.offsets[k]
            stack.extend(self.children[k])
        return np.zeros(3)

    def positions(self, pose: Pose) -> np.ndarray:
        """Forward kinematics of a pose: (n, J, 3)."""
        G = pose.G
        P = np.empty(G.shape[:2] + (3,))
        for j, p in enumerate(self.parents):
            P[:, j] = pose.root + self.offsets[j] if p < 0 else P[:, p] + G[:, p] @ self.offsets[j]
        return P

    def truth_positions(self, P: np.ndarray) -> np.ndarray:
        """(n, len(TRUTH_JOINTS), 3): the joint centres the engine's canonical names stand for."""
        out = np.empty(P.shape[:1] + (len(TRUTH_JOINTS), 3))
        for k, name in enumerate(TRUTH_JOINTS):
            if name == "pelvis":  # the engine's pelvis joint: the middle of the hip joints
                out[:, k] = 0.5 * (P[:, self.j("hip_l")] + P[:, self.j("hip_r")])
            else:
                out[:, k] = P[:, self.j(name)]
        return out

    def _fit_hinge(self, name: str):
        """(axis in the proximal segment's frame with positive = flexion, clip angle range)."""
        j = self.j(name)
        w = rot.log(self.clip.local[:, j])
        _, _, vt = np.linalg.svd(w, full_matrices=False)
        axis = vt[0]
        ang = w @ axis
        if np.mean(ang) < 0:
            axis, ang = -axis, -ang
        return axis, (float(ang.min()), float(ang.max()))

    def _heading(self, G, P) -> np.ndarray:
        left = P[:, self.j("hip_l")] - P[:, self.j("hip_r")]
        left[:, 2] = 0.0
        left = rot.unit(left)
        yaw = np.arctan2(left[:, 1], left[:, 0])  # body frame: left = +X at yaw 0
        return rot.yaw(yaw)

    def _stance(self, s: str) -> np.ndarray:
        a = self._clip_P[:, self.j(f"ankle_{s}")]
        v = np.gradient(a, axis=0) * self.clip.fps
        speed = np.linalg.norm(v, axis=1)
        low = a[:, 2] < np.percentile(a[:, 2], 2) + STANCE_HEIGHT
        return (speed < STANCE_SPEED) & low

    def _standing_foot(self, s: str):
        """(foot rotation relative to the heading, ankle height) averaged over the clip's stance."""
        st = self.stance[s]
        if st.sum() < 3:
            st = np.ones_like(st)
        rel = np.swapaxes(self.heading[st], -1, -2) @ self._clip_G[st, self.j(f"ankle_{s}")]
        u, _, vt = np.linalg.svd(rel.mean(axis=0))
        m = u @ vt
        if np.linalg.det(m) < 0:
            u[:, -1] *= -1
            m = u @ vt
        return m, float(np.median(self._clip_P[st, self.j(f"ankle_{s}"), 2]))

    # --- poses (body frame) ---------------------------------------------------------------------

    def _segment_rotation(self, part: str, direction, flex_dir):
        """World rotation of a limb's proximal segment pointing along `direction` with its hinge
        flexing the distal segment toward `flex_dir`."""
        j = self.j(part)
        d0 = rot.unit(self.child_offset(j))
        axis0 = self.hinge[("elbow_" if part.startswith("shoulder") else "knee_") + part[-1]][0]
        direction = rot.unit(direction)
        a = np.cross(direction, flex_dir)  # a positive turn about a moves the distal bone toward flex_dir
        return rot.basis(np.broadcast_to(d0, np.shape(direction)), np.broadcast_to(axis0, np.shape(direction)),
                         direction, a)

    def pose(self, n: int, *, arm=None, leg=None, root_offset=None, rng=None, sway_mm: float = 3.0,
             wobble_deg: float = 4.0, stance_deg: float = 0.0, bends_deg=(5.0, 3.0), root_rot=None,
             held=None) -> Pose:
        """A pose held or moving over n frames. `arm` / `leg`: {side: (direction (n, 3) of the
        upper arm / thigh, flexion direction (n, 3), hinge angle (n,) radians)}; defaults: T-pose
        arms, straight legs `stance_deg` out from under the hips, elbows and knees bent by
        `bends_deg`. With `rng`, the body sways and the hands and feet wander `wobble_deg` at the
        wrists and ankles (nobody holds them still). `root_rot` (n, 3, 3): the pelvis turned (the
        trunk bent at the hips; the legs keep their world directions); `held`: {(limb, side):
        (world rotation (n, 3, 3) of the upper arm / thigh, hinge angle (n,), world rotation of
        the hand / foot or None)}, a limb placed by `touching.reach` (its hand held where a touch
        puts it: no wander)."""
        J = len(self.parents)
        G = np.empty((n, J, 3, 3))
        fixed = {}
        arm = dict(arm or {})
        leg = dict(leg or {})
        held = dict(held or {})
        for s in SIDES:
            arm.setdefault(s, (np.broadcast_to(LEFT * (1 if s == "l" else -1), (n, 3)),
                               np.broadcast_to(FORWARD, (n, 3)), np.full(n, np.radians(bends_deg[0]))))
            out = np.radians(stance_deg) * (1 if s == "l" else -1)
            leg.setdefault(s, (np.broadcast_to(-UP * np.cos(out) + LEFT * np.sin(out), (n, 3)),
                               np.broadcast_to(-FORWARD, (n, 3)), np.full(n, np.radians(bends_deg[1]))))
        for s in SIDES:
            for limb, (prox, dist, end) in (("arm", ("shoulder", "elbow", "wrist")), ("leg", ("hip", "knee",
                                                                                            "ankle"))):
                axis0 = self.hinge[f"{dist}_{s}"][0]
                if (limb, s) in held:
                    g1, angle, end_rot = held[(limb, s)]
                    g2 = g1 @ rot.axis_angle(axis0, angle)
                    fixed[self.j(f"{prox}_{s}")] = g1
                    fixed[self.j(f"{dist}_{s}")] = g2
                    if end_rot is not None:
                        fixed[self.j(f"{end}_{s}")] = end_rot
                        continue
                else:
                    direction, flex_dir, angle = (arm if limb == "arm" else leg)[s]
                    g1 = self._segment_rotation(f"{prox}_{s}", direction, flex_dir)
                    g2 = g1 @ rot.axis_angle(axis0, angle)
                    fixed[self.j(f"{prox}_{s}")] = g1
                    fixed[self.j(f"{dist}_{s}")] = g2
                wander = np.broadcast_to(np.eye(3), (n, 3, 3))
                if rng is not None and wobble_deg:
                    wander = rot.exp(_smooth_noise(rng, n, self.clip.fps, 3, np.radians(wobble_deg), 0.2, 1.0))
                rest = self.wrist_twist(s) if limb == "arm" else self.ankle_rest(s)
                fixed[self.j(f"{end}_{s}")] = g2 @ rest @ wander
        for j, p in enumerate(self.parents):
            if j in fixed:
                G[:, j] = fixed[j]
            elif p < 0:
                G[:, j] = np.eye(3) if root_rot is None else root_rot
            else:  # the rest pose, the pelvis as rigid as the clip's (`_rigid_pelvis`)
                G[:, j] = G[:, p] @ self.held[j] if j in self.held else G[:, p]
        root = np.zeros((n, 3))
        if rng is not None and sway_mm:
            root += _smooth_noise(rng, n, self.clip.fps, 3, sway_mm / 1000.0, 0.1, 0.6) * np.array([1, 1, 0.3])
        if root_offset is not None:
            root += root_offset
        return Pose(G, root)

    def wrist_twist(self, s: str) -> np.ndarray:
        """The hand's rotation relative to the forearm: palm down in the T-pose."""
        if not hasattr(self, "_wrist"):
            self._wrist = {}
        if s not in self._wrist:
            direction = LEFT * (1 if s == "l" else -1)
            g1 = self._segment_rotation(f"shoulder_{s}", direction, FORWARD)
            g2 = g1 @ rot.axis_angle(self.hinge[f"elbow_{s}"][0], np.radians(5.0))
            h0 = rot.unit(self.child_offset(self.j(f"wrist_{s}")))
            palm0 = self.palm_normal_rest(s)
            hand = rot.basis(h0, palm0, direction, -UP)
            self._wrist[s] = g2.T @ hand
        return self._wrist[s]

    def palm_normal_rest(self, s: str) -> np.ndarray:
        """Out of the palm, in the hand's own frame (the rest pose's palm-down / palm-in)."""
        h0 = rot.unit(self.child_offset(self.j(f"wrist_{s}")))
        if abs(h0 @ UP) > 0.7:  # arms-down rest (cmu_max): palms toward the body
            return -LEFT * (1 if s == "l" else -1)
        return -UP

    def ankle_rest(self, s: str) -> np.ndarray:
        """The foot relative to a straight, vertical shin: the clip's standing foot."""
        if not hasattr(self, "_ankle"):
            self._ankle = {}
        if s not in self._ankle:
            g1 = self._segment_rotation(f"hip_{s}", -UP, -FORWARD)
            g2 = g1 @ rot.axis_angle(self.hinge[f"knee_{s}"][0], np.radians(3.0))
            self._ankle[s] = g2.T @ self._stand_foot[s][0]
        return self._ankle[s]

    def standing_root_height(self) -> float:
        """Root height that puts the standing ankles at the clip's stance ankle height."""
        pose = self.pose(1)
        P = self.positions(pose)
        ank = np.mean([P[0, self.j(f"ankle_{s}"), 2] for s in SIDES])
        target = np.mean([self._stand_foot[s][1] for s in SIDES])
        return float(target - ank)
