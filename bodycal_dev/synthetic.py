"""A virtual performer with exact ground truth: the reference of every calibration and retargeting
test and benchmark. Numpy only; every stage is vectorised over frames. Development only
(the `bodycal_dev` package is not in the extension zip).

It is an independent truth generator, not a client of the engine: it poses its bones with its own
rotation helpers (Rodrigues rotations; quaternions from matrices by the eigenvector of Bar-Itzhack's
K matrix where the engine uses Shepperd's method) and places its limbs with its own two-bone IK rather than the engine's
`transforms` and `retarget.ik`, so that a bug in the engine's math cannot appear on both sides of a
test and cancel out. It shares only data definitions with the engine (the canonical skeleton's
names and topology, the surface layout's element list, the file formats). Its anatomical
assumptions (where a tracker sits, how a joint moves) are the engine's, which is why every stage is
also tested on recordings that `evaluation/` makes from real motion capture.

The performer is a kinematic human on the canonical skeleton (skeleton.py): facing -Y, left at +X,
Z up, floor at z = 0, metres. Bones are posed by local rotations (FK); hinge bones (forearm, shin,
finger phalanges 2/3) rotate only about their local +X, positive flexes (FORMATS.md §1). Bone
frames follow surface_layout.bone_frame: origin at the head joint, +Y along the bone, +X the bone's
`right`. Rest pose = T-pose, palms down, fingers extended.

True surface (what calibration measures and contacts touch):
- capsules around limb bones and phalanges, radii per joint (radius_head / radius_tail);
- the torso: per height an ellipse (lateral half width A, depth D) behind which the spine runs at
  a fixed depth, plus a Gaussian belly bulge of depth `belly`; torso points ride their nearest
  vertebra (surface_layout.nearest_vertebra at rest);
- the back of the skull: a sphere in the head bone frame; jaw points in the head bone frame;
- palms: the plane z = +zp of the hand bone frame (+Z of the hand bone frame points out of the
  palm, for both hands); soles: the outline of the foot on the floor, in the foot bone frame.

Definitions the ground truth relies on (also written into the truth file):
- Hand LEDs (`hand_led1..3_<s>`) sit on the back of the hand; the glove rigid body's pose is built
  from them with the rule of the synthetic API (origin = LED centroid, Y = led2 - led1,
  Z = (led2 - led1) x (led3 - led1) out of the back of the hand, X = Y x Z).
- Fingertip LEDs (`<finger>_tip_<s>`) sit on top (nail side) of the fingertip, one finger radius
  from the `tip_<finger>_<s>` joint; with the fingers extended flat on the palm plane they lie two
  finger radii from it (Delahaye 2023, appendix B: "finger radius = half the distance between the LED
  and its projection on the palm plane").
- Palm centre (the effector of `by: palm_<s>` touches and of palm contacts) = the hand device
  frame's origin (LED centroid, or the controller origin) projected onto the palm plane.
- Controller tip (`controller_tip_<s>`, minimal profile) = CONTROLLER_TIP_LOCAL in the
  controller's frame; it is also recorded as a marker.
- Touches: the `by` point lies exactly on the true surface point during the touch segment (plus
  noise); a touch segment is the ~0.6 s the effector holds still.
- Diametric touches: elbow_in/out, knee_in/out, ankle_in/out lie on the joint's hinge / lateral
  axis (bone local +-X) one joint radius from the joint centre; wrist_top/bottom along the hand's
  palm normal; shoulder_front/back and hip_front/back along the limb bone's local Z; so each
  pair's mean is the true joint centre and half their distance the true radius. skull_base_l/r
  are symmetric about the skull base joint. mcp_<f>_<s> is the top of the finger base: one finger
  radius above the MCP joint along the back-of-hand normal.

Noise model: trackers are attached to bones with fixed per-seed offsets (position a few cm off the
skin, random orientation); soft-tissue wobble is a smooth (0.2-1.5 Hz) perturbation of each
device in its own frame with RMS 3D amplitude `wobble_mm` (and wobble_mm / 100 mm radians of
rotation); white noise `noise_mm` per axis on positions and markers, noise_mm / 100 mm radians on
rotations; dropouts are runs of 3-30 invalid frames holding the last value (never NaN); outliers
are frames where a device (not a marker) jumps 3-8 cm and a few degrees while still valid.
"""

from __future__ import annotations

import functools
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from bodycal_addon.body import skeleton as sk
from bodycal_addon.body import surface_layout as sl
from bodycal_addon.body.bodymodel import BodyModel, BoneInfo, Joint, SurfaceElement, SurfacePoint
from bodycal_addon.core.errors import BodyCalError
from bodycal_addon.recording.model import Device, Recording, Segment

BUILDS = ("child", "thin", "average", "heavy", "tall", "long_arms")
PROFILES = ("full", "minimal")
MOTIONS = ("squat", "arm_raise", "clap", "hand_on_belly", "hand_on_head", "hands_on_thighs", "walk_in_place")
SIDE_SIGN = {"l": 1.0, "r": -1.0}
OTHER = {"l": "r", "r": "l"}
CONTROLLER_TIP_LOCAL = np.array([0.0, 0.09, 0.0])  # in the controller's device frame, metres
FULL_ROLES = ("head", "hand_l", "hand_r", "pelvis", "chest", "upperarm_l", "upperarm_r", "forearm_l", "forearm_r",
              "thigh_l", "thigh_r", "shin_l", "shin_r", "foot_l", "foot_r")
MINIMAL_ROLES = ("head", "hand_l", "hand_r", "pelvis", "foot_l", "foot_r")
ROLE_BONE = {"head": "head", "pelvis": "sacrum", "chest": "spine_08",
             **{f"{b}_{s}": f"{b}_{s}" for s in sk.SIDES for b in ("hand", "upperarm", "forearm", "thigh", "shin",
                                                                   "foot")}}

# Build defaults: height, belly depth, radius scale, arm / leg / torso / head scale.
_BUILD_PARAMS = {
    "average": dict(height=1.75, belly=0.03, radius_scale=1.0, arm_scale=1.0, leg_scale=1.0, torso_scale=1.0,
                    head_scale=1.0),
    "child": dict(height=1.30, belly=0.02, radius_scale=0.9, arm_scale=0.97, leg_scale=0.95, torso_scale=0.95,
                  head_scale=1.2),
    "thin": dict(height=1.75, belly=0.0, radius_scale=0.8, arm_scale=1.0, leg_scale=1.0, torso_scale=0.88,
                 head_scale=1.0),
    "heavy": dict(height=1.75, belly=0.11, radius_scale=1.3, arm_scale=1.0, leg_scale=1.0, torso_scale=1.2,
                  head_scale=1.0),
    "tall": dict(height=1.95, belly=0.03, radius_scale=1.0, arm_scale=1.0, leg_scale=1.0, torso_scale=1.0,
                 head_scale=1.0),
    "long_arms": dict(height=1.75, belly=0.03, radius_scale=1.0, arm_scale=1.12, leg_scale=1.0, torso_scale=1.0,
                      head_scale=1.0),
}
# Joint radii for a 1.75 m average performer (scaled by height and radius_scale).
_JOINT_RADII = {"shoulder": 0.055, "elbow": 0.040, "wrist": 0.028, "hip": 0.085, "knee": 0.055, "ankle": 0.035}
_FINGER_RADII = {"thumb": 0.0105, "index": 0.0092, "middle": 0.0095, "ring": 0.0090, "pinky": 0.0080}
_PHALANGES = {"thumb": (0.035, 0.030, 0.024), "index": (0.043, 0.025, 0.020), "middle": (0.047, 0.029, 0.021),
              "ring": (0.044, 0.028, 0.021), "pinky": (0.034, 0.020, 0.019)}
# MCP joints in the hand bone frame for 1.75 m: (u = toward the thumb, y = along the hand).
_MCP_UY = {"thumb": (0.035, 0.035), "index": (0.022, 0.082), "middle": (0.0, 0.085), "ring": (-0.019, 0.080),
           "pinky": (-0.036, 0.072)}
_PALM_UY = ((0.030, 0.015), (-0.030, 0.015), (-0.035, 0.066), (0.026, 0.074))
_LIMB_JOINTS = {"upperarm": ("shoulder", "elbow"), "forearm": ("elbow", "wrist"), "thigh": ("hip", "knee"),
                "shin": ("knee", "ankle")}

_BONE_NAMES = tuple(b.name for b in sk.BONES)
_BONE_INDEX = {n: i for i, n in enumerate(_BONE_NAMES)}
_PARENT = np.array([_BONE_INDEX[b.parent] if b.parent else -1 for b in sk.BONES])


# --- small rotation helpers (matrices act on column vectors, leading frame axes) -------------------

def normalize(v) -> np.ndarray:
    v = np.asarray(v, float)
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, n, out=np.zeros_like(v), where=n > 1e-12)


def quat_to_matrix(q) -> np.ndarray:
    """Unit quaternions (..., 4) (w, x, y, z) to matrices, as R = (w^2 - v.v) I + 2 v v^T + 2 w [v]x."""
    q = np.asarray(q, float)
    w, v = q[..., 0, None, None], q[..., 1:]
    cross = np.zeros(q.shape[:-1] + (3, 3))
    cross[..., 0, 1], cross[..., 0, 2], cross[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    cross = cross - np.swapaxes(cross, -1, -2)
    vv = (v * v).sum(-1)[..., None, None]
    return (w * w - vv) * np.eye(3) + 2.0 * v[..., :, None] * v[..., None, :] + 2.0 * w * cross


def matrix_to_quat(m) -> np.ndarray:
    """Rotation matrices (..., 3, 3) to unit quaternions with w >= 0: the eigenvector of the largest
    eigenvalue of Bar-Itzhack's symmetric 4x4 K (exact for a rotation, robust near 180 degrees)."""
    m = np.asarray(m, float)
    a = lambda i, j: m[..., i, j]  # noqa: E731
    k = np.stack([
        np.stack([a(0, 0) + a(1, 1) + a(2, 2), a(2, 1) - a(1, 2), a(0, 2) - a(2, 0), a(1, 0) - a(0, 1)], -1),
        np.stack([a(2, 1) - a(1, 2), a(0, 0) - a(1, 1) - a(2, 2), a(0, 1) + a(1, 0), a(0, 2) + a(2, 0)], -1),
        np.stack([a(0, 2) - a(2, 0), a(0, 1) + a(1, 0), a(1, 1) - a(0, 0) - a(2, 2), a(1, 2) + a(2, 1)], -1),
        np.stack([a(1, 0) - a(0, 1), a(0, 2) + a(2, 0), a(1, 2) + a(2, 1), a(2, 2) - a(0, 0) - a(1, 1)], -1),
    ], -2)
    q = np.linalg.eigh(k)[1][..., :, -1]
    return q * np.where(q[..., :1] < 0, -1.0, 1.0)


def _rot(axis, angle) -> np.ndarray:
    """Rotation matrices about `axis` (3,) or (n, 3) by `angle` (scalar or (n,)), Rodrigues."""
    axis = normalize(np.asarray(axis, float))
    angle = np.asarray(angle, float)
    x, y, z = np.moveaxis(np.broadcast_to(axis, np.broadcast_shapes(axis.shape, angle.shape + (3,))), -1, 0)
    c, s = np.cos(angle), np.sin(angle)
    t = 1 - c
    m = np.stack([t * x * x + c, t * x * y - s * z, t * x * z + s * y,
                  t * x * y + s * z, t * y * y + c, t * y * z - s * x,
                  t * x * z - s * y, t * y * z + s * x, t * z * z + c], -1)
    return m.reshape(m.shape[:-1] + (3, 3))


def _rx(angle) -> np.ndarray:
    return _rot(np.array([1.0, 0.0, 0.0]), angle)


def _between(a, b) -> np.ndarray:
    """Shortest-arc rotation matrices taking direction a to b (never antiparallel here)."""
    a, b = normalize(a), normalize(b)
    a, b = np.broadcast_arrays(a, b)
    axis = np.cross(a, b)
    s = np.linalg.norm(axis, axis=-1)
    c = (a * b).sum(-1)
    ang = np.arctan2(s, c)
    safe = np.where(s[..., None] > 1e-12, axis, np.array([1.0, 0.0, 0.0]))
    return _rot(safe, ang)


def _frame(x_hint, y) -> np.ndarray:
    """Columns (x, y, z): y exact, x closest to x_hint, z = x × y."""
    y = normalize(np.asarray(y, float))
    x_hint = np.asarray(x_hint, float)
    x = normalize(x_hint - (x_hint * y).sum(-1, keepdims=True) * y)
    return np.stack([x, y, np.cross(x, y)], -1)


def _orient(local_a, local_b, world_a, world_b) -> np.ndarray:
    """R with R local_a = world_a and R local_b as close as possible to world_b."""
    fl = _frame(local_b, local_a)
    fw = _frame(world_b, world_a)
    return fw @ np.swapaxes(fl, -1, -2)


def _mv(m, v) -> np.ndarray:
    return np.einsum("...ij,...j->...i", m, v)


def _smooth(t) -> np.ndarray:
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3 - 2 * t)


# --- the performer ----------------------------------------------------------------------------------

@dataclass
class Performer:
    """Body parameters and the derived rest geometry. Build with `make_performer`."""

    params: dict
    build: str
    seed: int
    rest: dict[str, np.ndarray] = field(default_factory=dict)  # joint -> rest (T-pose) world position
    radius: dict[str, float] = field(default_factory=dict)  # "elbow_l", "finger_index_l", ...
    hand: dict = field(default_factory=dict)  # hand geometry in the hand bone frame, per side
    skull_center: np.ndarray | None = None  # head bone frame
    skull_radius: float = 0.0
    eye_local: np.ndarray | None = None  # head bone frame
    surface_points: dict[str, tuple[str, np.ndarray, np.ndarray]] = field(default_factory=dict)  # (bone, local, n)
    mounts: dict[str, tuple[str, np.ndarray, np.ndarray]] = field(default_factory=dict)  # role -> (bone, p, R)
    controller: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)  # side -> (p, R) in hand
    rest_rot: np.ndarray | None = None  # (B, 3, 3) bone rest frames
    rest_head: np.ndarray | None = None  # (B, 3)
    length: np.ndarray | None = None  # (B,)

    @property
    def height(self) -> float:
        return float(self.params["height"])

    @property
    def belly(self) -> float:
        return float(self.params["belly"])

    def bone_radii(self, bone: str) -> tuple[float, float] | None:
        """(radius_head, radius_tail) of a capsule bone, else None."""
        parts = bone.rsplit("_", 1)
        if len(parts) != 2 or parts[1] not in sk.SIDES:
            return None
        base, s = parts
        if base in _LIMB_JOINTS:
            a, b = _LIMB_JOINTS[base]
            return self.radius[f"{a}_{s}"], self.radius[f"{b}_{s}"]
        finger = base.split("_")[0]
        if finger in sk.FINGERS and base.count("_") == 1 and base.split("_")[1] in ("1", "2", "3"):
            r = self.radius[f"finger_{finger}_{s}"]
            return r, r
        return None

    def to_dict(self) -> dict:
        return {"build": self.build, "seed": self.seed, "params": {k: float(v) for k, v in self.params.items()}}


def make_performer(height: float | None = None, build: str = "average", seed: int = 0, **overrides) -> Performer:
    """A performer of a given build (BUILDS). `height` defaults to the build's (child 1.30 m, tall
    1.95 m, else 1.75 m). Overrides: any build parameter (belly, radius_scale, arm_scale, leg_scale,
    torso_scale, head_scale), a joint radius `radius_<joint>` (shoulder, elbow, wrist, hip, knee,
    ankle; both sides), `<limb>_radius` (upperarm, forearm, thigh, shin: both end radii), or a
    finger radius `radius_<finger>`. The seed fixes the tracker mounting offsets."""
    if build not in _BUILD_PARAMS:
        raise BodyCalError(f"unknown build '{build}'", field="build", hint=f"use one of {', '.join(BUILDS)}")
    params = dict(_BUILD_PARAMS[build])
    if height is not None:
        params["height"] = float(height)
    known = set(params) | {f"radius_{j}" for j in _JOINT_RADII} | {f"{b}_radius" for b in _LIMB_JOINTS} \
        | {f"radius_{f}" for f in sk.FINGERS}
    for k, v in overrides.items():
        if k not in known:
            raise BodyCalError(f"unknown performer parameter '{k}'", field=k,
                               hint=f"use one of {', '.join(sorted(known))}")
        params[k] = float(v)
    if not 0.8 <= params["height"] <= 2.3:
        raise BodyCalError(f"height {params['height']} m is outside 0.8-2.3 m", field="height")
    perf = Performer(params=params, build=build, seed=int(seed))
    _build_geometry(perf)
    return perf


def _build_geometry(perf: Performer) -> None:
    P = perf.params
    H = P["height"]
    s = H / 1.75
    rs = P["radius_scale"] * s
    ts = P["torso_scale"]
    j = {}
    hip_h = 0.53 * H * P["leg_scale"]
    hip_w = 0.10 * H
    j["pelvis"] = np.array([0.0, 0.0, hip_h])
    # Spine root 0.10 m above and 0.05 m behind the sacrum origin (Delahaye 2023, appendix B "Trunk").
    j["spine_root"] = j["pelvis"] + np.array([0.0, 0.05, 0.10])
    skull_base = np.array([0.0, 0.04 * s, 0.895 * H])
    for k in range(1, sk.SPINE_COUNT + 1):
        j[sk.spine_joint(k)] = j["spine_root"] + (skull_base - j["spine_root"]) * k / sk.SPINE_COUNT
    j["skull_base"] = skull_base.copy()
    j["head"] = skull_base + np.array([0.0, 0.0, 0.10 * s])
    sh_z = 0.818 * H
    upper, fore = 0.186 * H * P["arm_scale"], 0.146 * H * P["arm_scale"]
    thigh = 0.245 * H * P["leg_scale"]
    ankle_h = 0.045 * H
    shin = hip_h - thigh - ankle_h
    radius = {}
    for side, ss in SIDE_SIGN.items():
        x = ss
        j[f"shoulder_{side}"] = np.array([x * 0.1025 * H, 0.0, sh_z])
        j[f"clavicle_{side}"] = j[sk.spine_joint(sk.CLAVICLE_VERTEBRA)].copy()
        j[f"elbow_{side}"] = j[f"shoulder_{side}"] + np.array([x * upper, 0, 0])
        j[f"wrist_{side}"] = j[f"elbow_{side}"] + np.array([x * fore, 0, 0])
        j[f"hip_{side}"] = j["pelvis"] + np.array([x * hip_w / 2, 0, 0])
        j[f"knee_{side}"] = j[f"hip_{side}"] - np.array([0, 0, thigh])
        j[f"ankle_{side}"] = j[f"knee_{side}"] - np.array([0, 0, shin])
        j[f"toe_{side}"] = j[f"ankle_{side}"] + np.array([0, -0.08 * H, -(ankle_h - 0.012 * H)])
        for name, r in _JOINT_RADII.items():
            radius[f"{name}_{side}"] = P.get(f"radius_{name}", r * rs)
        for f, r in _FINGER_RADII.items():
            radius[f"finger_{f}_{side}"] = P.get(f"radius_{f}", r * rs)
    for limb, (a, b) in _LIMB_JOINTS.items():
        if f"{limb}_radius" in P:
            for side in sk.SIDES:
                radius[f"{a}_{side}"] = radius[f"{b}_{side}"] = P[f"{limb}_radius"]
    perf.radius = radius

    # Hands: geometry in the hand bone frame (x = right, y = wrist -> middle base, z out of the palm).
    hand = {}
    for side, ss in SIDE_SIGN.items():
        m = -ss  # local x of a point `u` toward the thumb: x = m * u
        r_mid = radius[f"finger_middle_{side}"]
        zp = r_mid  # palm plane: the middle finger's axis lies one radius behind it
        thick = 0.028 * s
        g = {"zp": zp, "thickness": thick, "m": m}
        mcp, dirs = {}, {}
        for f in sk.FINGERS:
            u, y = _MCP_UY[f]
            rf = radius[f"finger_{f}_{side}"]
            mcp[f] = np.array([m * u * s, y * s, zp - rf])  # one finger radius behind the palm plane
            dirs[f] = normalize(np.array([m * 0.6, 0.8, 0.0])) if f == "thumb" else np.array([0.0, 1.0, 0.0])
        g["mcp"], g["dir"] = mcp, dirs
        zl = zp - thick - 0.006
        g["leds"] = np.array([[0.0, 0.015 * s, zl], [0.0, 0.070 * s, zl], [0.025 * s, 0.045 * s, zl]])
        c = g["leds"].mean(0)
        g["palm_centre"] = np.array([c[0], c[1], zp])
        palm = np.array([[m * u * s, y * s, zp] for u, y in _PALM_UY])
        tri_n = np.cross(palm[1] - palm[0], palm[2] - palm[0])
        if tri_n[2] < 0:  # fan normal out of the palm (+z)
            palm = palm[::-1].copy()
        g["palm"] = palm
        hand[side] = g
        # Controller held in the fist: origin in the grip, its axis pointing forward out of the fist
        # (along the hand, a little toward the thumb and the palm).
        ctrl_p = np.array([0.0, 0.06 * s, zp + 0.025 * s])
        ctrl_r = _frame(np.array([m, 0.0, 0.0]), np.array([m * 0.3, 1.0, 0.4]))
        perf.controller[side] = (ctrl_p, ctrl_r)
    perf.hand = hand

    # Hand and finger joints in world at rest from the hand rest frame.
    for side, ss in SIDE_SIGN.items():
        Rh = np.stack([np.array([0, ss, 0.0]), np.array([ss, 0, 0.0]), np.array([0, 0, -1.0])], -1)
        wrist = j[f"wrist_{side}"]
        g = hand[side]
        for f in sk.FINGERS:
            p = g["mcp"][f]
            j[f"mcp_{f}_{side}"] = wrist + Rh @ p
            d = Rh @ g["dir"][f]
            acc = j[f"mcp_{f}_{side}"]
            for name, L in zip(("pip", "dip", "tip"), _PHALANGES[f], strict=True):
                acc = acc + d * L * s
                j[f"{name}_{f}_{side}"] = acc
    perf.rest = j

    # Bone rest frames from joints and right hints (FORMATS.md §1: hinges flex about +X).
    B = len(sk.BONES)
    rot = np.zeros((B, 3, 3))
    head = np.zeros((B, 3))
    length = np.zeros(B)
    for i, b in enumerate(sk.BONES):
        h, t = j[b.head], j[b.tail]
        rot[i] = _frame(_right_hint(b.name), t - h)
        head[i] = h
        length[i] = np.linalg.norm(t - h)
    perf.rest_rot, perf.rest_head, perf.length = rot, head, length

    # Head: skull sphere, eyes, jaw (head bone frame: x = +X left, y = up, z = forward).
    hs = s * P["head_scale"] ** 0.5
    perf.skull_center = np.array([0.0, 0.075 * hs, 0.03 * hs])
    perf.skull_radius = 0.09 * hs
    perf.eye_local = np.array([0.0, 0.06 * hs, 0.085 * hs])
    _surface_points(perf, s, ts, hs)
    _mounts(perf, s, ts)


def _right_hint(bone: str) -> np.ndarray:
    side = bone[-1] if bone[-2:] in ("_l", "_r") else None
    ss = SIDE_SIGN.get(side, 1.0)
    base = bone[:-2] if side else bone
    if base in ("clavicle", "upperarm", "forearm"):
        return np.array([0.0, 0.0, -ss])
    if base == "hand" or base.startswith("metacarpal_") or base.split("_")[0] in sk.FINGERS:
        return np.array([0.0, ss, 0.0])
    if base == "hip":
        return np.array([0.0, 0.0, 1.0])
    return np.array([1.0, 0.0, 0.0])


def _torso_geometry(perf: Performer, s: float, ts: float):
    zr = perf.rest["spine_root"][2]
    A, D = 0.15 * s * ts, 0.21 * s * ts
    back_off = 0.05 * s * ts  # the spine runs this far inside the back

    def spine_y(z):
        a, b = perf.rest["spine_root"], perf.rest["skull_base"]
        return a[1] + (b[1] - a[1]) * (z - a[2]) / (b[2] - a[2])

    def belly(u, z):
        return perf.belly * math.exp(-(u / (0.11 * s)) ** 2 - ((z - (zr + 0.07 * s)) / (0.12 * s)) ** 2)

    def front(u, z):
        yc = spine_y(z) + back_off - D / 2
        return np.array([u, yc - D / 2 * math.sqrt(max(1 - (u / A) ** 2, 0.0)) - belly(u, z), z])

    def back(u, z):
        yc = spine_y(z) + back_off - D / 2
        return np.array([u, yc + D / 2 * math.sqrt(max(1 - (u / A) ** 2, 0.0)), z])

    return zr, front, back


def _surface_points(perf: Performer, s: float, ts: float, hs: float) -> None:
    pts: dict[str, tuple[str, np.ndarray, np.ndarray]] = {}
    rot, head = perf.rest_rot, perf.rest_head

    def to_local(bone, world, n_world):
        i = _BONE_INDEX[bone]
        return bone, rot[i].T @ (world - head[i]), rot[i].T @ normalize(n_world)

    # Torso: rest world points, stored in the nearest vertebra's frame (Delahaye 2023, appendix B).
    zr, front, back = _torso_geometry(perf, s, ts)
    spine = np.array([perf.rest[sk.spine_joint(k)] for k in range(sk.SPINE_COUNT + 1)])
    lat = 0.085 * s * ts
    spec = {"sternum": (front, 0.0, 0.32), "chest_l": (front, lat, 0.36), "chest_r": (front, -lat, 0.36),
            "belly_ul": (front, lat, 0.17), "belly_ur": (front, -lat, 0.17), "belly_ll": (front, lat, -0.02),
            "belly_lr": (front, -lat, -0.02), "back_ul": (back, lat, 0.33), "back_ur": (back, -lat, 0.33),
            "back_low": (back, 0.0, 0.05)}
    uz = {k: (u, zr + dz * s) for k, (_, u, dz) in spec.items()}
    for name, (a, b) in sl.BELLY_CENTRE_UV.items():
        (u0, z0), (u1, _), (_, z1) = uz["belly_ul"], uz["belly_ur"], uz["belly_ll"]
        spec[name] = (front, None, None)
        uz[name] = (u0 + a * (u1 - u0), z0 + b * (z1 - z0))
    for name, (fun, _, _) in spec.items():
        u, z = uz[name]
        p = fun(u, z)
        e = 1e-4
        n = normalize(np.cross(fun(u + e, z) - fun(u - e, z), fun(u, z + e) - fun(u, z - e)))
        outward = -1.0 if fun is front else 1.0  # front faces -Y, back +Y
        if n[1] * outward < 0:
            n = -n
        pts[name] = to_local(sl.nearest_vertebra(p, spine), p, n)

    # Head: skull sphere points, jaw, skull base (head bone frame).
    c, R = perf.skull_center, perf.skull_radius
    for name, d in {"skull_top": (0, 1, 0), "skull_left": (1, 0, 0), "skull_right": (-1, 0, 0),
                    "skull_back": (0, 0, -1)}.items():
        d = np.array(d, float)
        pts[name] = ("head", c + R * d, d)
    jaw = {"ear_l": (0.07, 0.035, 0.0), "ear_r": (-0.07, 0.035, 0.0), "upper_lip": (0.0, 0.01, 0.105),
           "chin": (0.0, -0.045, 0.095), "jaw_l": (0.055, -0.025, 0.06), "jaw_r": (-0.055, -0.025, 0.06)}
    for name, p in jaw.items():
        p = np.array(p) * hs
        pts[name] = ("head", p, normalize(p - np.array([0.0, 0.03, 0.02]) * hs))
    for side, ss in SIDE_SIGN.items():
        pts[f"skull_base_{side}"] = ("head", np.array([ss * 0.035 * hs, 0.0, 0.0]),
                                     normalize(np.array([ss, 0.0, -1.0])))

    for side, ss in SIDE_SIGN.items():
        g = perf.hand[side]
        rw = perf.radius[f"wrist_{side}"]
        hb = f"hand_{side}"
        pts[f"wrist_top_{side}"] = (hb, np.array([0.0, 0.0, -rw]), np.array([0.0, 0.0, -1.0]))
        pts[f"wrist_bottom_{side}"] = (hb, np.array([0.0, 0.0, rw]), np.array([0.0, 0.0, 1.0]))
        for f in sk.FINGERS:
            # The true MCP joint of a hand bone is the rest joint expressed in the hand bone frame.
            mcp = rot[_BONE_INDEX[hb]].T @ (perf.rest[f"mcp_{f}_{side}"] - head[_BONE_INDEX[hb]])
            rf = perf.radius[f"finger_{f}_{side}"]
            pts[f"mcp_{f}_{side}"] = (hb, mcp + np.array([0.0, 0.0, -rf]), np.array([0.0, 0.0, -1.0]))
        for k, p in enumerate(g["palm"], start=1):
            pts[f"palm_{k}_{side}"] = (hb, p.copy(), np.array([0.0, 0.0, 1.0]))
        # Limbs: diametric pairs (see the module docstring).
        for limb, joint, bone, axis, c_in in (("elbow", "elbow", f"forearm_{side}", 0, ss),
                                              ("knee", "knee", f"shin_{side}", 0, -ss),
                                              ("ankle", "ankle", f"foot_{side}", 0, -ss)):
            r = perf.radius[f"{joint}_{side}"]
            d = np.zeros(3)
            d[axis] = c_in
            pts[f"{limb}_in_{side}"] = (bone, r * d, d.copy())
            pts[f"{limb}_out_{side}"] = (bone, -r * d, -d)
        r = perf.radius[f"shoulder_{side}"]
        pts[f"shoulder_front_{side}"] = (f"upperarm_{side}", np.array([0, 0, r]), np.array([0, 0, 1.0]))
        pts[f"shoulder_back_{side}"] = (f"upperarm_{side}", np.array([0, 0, -r]), np.array([0, 0, -1.0]))
        r = perf.radius[f"hip_{side}"]
        pts[f"hip_front_{side}"] = (f"thigh_{side}", np.array([0, 0, -r]), np.array([0, 0, -1.0]))
        pts[f"hip_back_{side}"] = (f"thigh_{side}", np.array([0, 0, r]), np.array([0, 0, 1.0]))
        # Soles: the foot's outline on the floor (heel, outer ball, toe tip, inner ball).
        a = perf.rest[f"ankle_{side}"]
        outline = [(0.0, 0.035), (ss * 0.033, -0.10), (0.0, -0.145), (-ss * 0.028, -0.10)]
        world = [np.array([a[0] + dx * s, a[1] + dy * s, 0.0]) for dx, dy in outline]
        if np.cross(world[1] - world[0], world[2] - world[0])[2] > 0:  # fan normal down
            world = world[::-1]
        for k, w in enumerate(world, start=1):
            outward = normalize(np.array([w[0] - a[0], w[1] - a[1] + 0.05 * s, 0.0])) + np.array([0, 0, 1.0])
            pts[f"sole_{k}_{side}"] = to_local(f"foot_{side}", w, outward)
        # Contact targets of the motions.
        th = f"thigh_{side}"
        L = perf.length[_BONE_INDEX[th]]
        r_mid = 0.5 * (perf.radius[f"hip_{side}"] + perf.radius[f"knee_{side}"])
        pts[f"thigh_front_{side}"] = (th, np.array([0.0, 0.5 * L, -r_mid]), np.array([0, 0, -1.0]))
    perf.surface_points = pts


def _mounts(perf: Performer, s: float, ts: float) -> None:
    """Tracker mounting: position a few cm off the skin in the bone frame, a random orientation."""
    rng = np.random.default_rng([perf.seed, 7919])
    L = perf.length
    mounts = {}

    def r_at(bone, t):
        rh, rt = perf.bone_radii(bone)
        return rh + (rt - rh) * t

    for side, ss in SIDE_SIGN.items():
        b = f"upperarm_{side}"
        mounts[b] = (b, np.array([-ss * (r_at(b, 0.55) + 0.02), 0.55 * L[_BONE_INDEX[b]], 0.0]))
        b = f"forearm_{side}"
        mounts[b] = (b, np.array([-ss * (r_at(b, 0.75) + 0.018), 0.75 * L[_BONE_INDEX[b]], 0.0]))
        b = f"thigh_{side}"
        d = np.array([ss * math.cos(0.6), 0.0, -math.sin(0.6)]) * (r_at(b, 0.45) + 0.02)
        mounts[b] = (b, d + np.array([0.0, 0.45 * L[_BONE_INDEX[b]], 0.0]))
        b = f"shin_{side}"
        mounts[b] = (b, np.array([0.0, 0.35 * L[_BONE_INDEX[b]], -(r_at(b, 0.35) + 0.015)]))
        b = f"foot_{side}"
        mounts[b] = (b, np.array([0.0, 0.5 * L[_BONE_INDEX[b]], -0.045 * s]))
    mounts["pelvis"] = ("sacrum", np.array([0.0, 0.06, -(0.12 * s * ts + 0.02)]))
    _, front, _ = _torso_geometry(perf, s, ts)
    i8 = _BONE_INDEX["spine_08"]
    p = front(0.0, perf.rest_head[i8][2]) + np.array([0.0, -0.02, 0.0])
    mounts["chest"] = ("spine_08", perf.rest_rot[i8].T @ (p - perf.rest_head[i8]))
    mounts["head"] = ("head", perf.eye_local.copy())
    out = {}
    for role in FULL_ROLES:
        if role.startswith("hand_"):
            continue
        bone, p = mounts[role]
        jitter = np.zeros(3) if role == "head" else rng.uniform(-0.008, 0.008, 3)
        q = rng.normal(size=4)
        out[role] = (bone, p + jitter, quat_to_matrix(q / np.linalg.norm(q)))
    perf.mounts = out


# --- forward kinematics -----------------------------------------------------------------------------

_REL_ROT: dict[int, np.ndarray] = {}


def _fk(perf: Performer, root_pos, root_rot, local: dict[str, np.ndarray]):
    """Bone world frames G (n, B, 3, 3) and heads (n, B, 3): G_b = G_parent R_rel Q_b."""
    n = len(root_pos)
    B = len(_BONE_NAMES)
    G = np.empty((n, B, 3, 3))
    Hd = np.empty((n, B, 3))
    R, Hr = perf.rest_rot, perf.rest_head
    for i, name in enumerate(_BONE_NAMES):
        p = _PARENT[i]
        if p < 0:
            g = root_rot @ R[i]
            h = root_pos
        else:
            # One BLAS product for all frames: (n * 3, 3) @ (3, 3).
            g = (G[:, p].reshape(-1, 3) @ (R[p].T @ R[i])).reshape(n, 3, 3)
            h = Hd[:, p] + G[:, p] @ (R[p].T @ (Hr[i] - Hr[p]))
        q = local.get(name)
        if q is not None:
            g = g @ q
        G[:, i] = g
        Hd[:, i] = h
    return G, Hd


_JOINT_SOURCE = {}
for _i, _b in enumerate(sk.BONES):
    if _b.shortcut and not _b.name.startswith("hip_"):
        continue
    _JOINT_SOURCE.setdefault(_b.tail, (_i, True))
    _JOINT_SOURCE.setdefault(_b.head, (_i, False))
for _s in sk.SIDES:  # the clavicle joint is the clavicle bone's root (on vertebra 5)
    _JOINT_SOURCE[f"clavicle_{_s}"] = (_BONE_INDEX[f"clavicle_{_s}"], False)
_JOINT_BONE = np.array([_JOINT_SOURCE[jn][0] for jn in sk.JOINTS])
_JOINT_TAIL = np.array([_JOINT_SOURCE[jn][1] for jn in sk.JOINTS])


def _joints(perf: Performer, G, Hd) -> np.ndarray:
    """(n, J, 3) joint positions in sk.JOINTS order."""
    y = G[:, _JOINT_BONE][..., 1] * (perf.length[_JOINT_BONE] * _JOINT_TAIL)[None, :, None]
    return Hd[:, _JOINT_BONE] + y


def _point(G, Hd, bone: str, local) -> np.ndarray:
    i = _BONE_INDEX[bone]
    return Hd[:, i] + _mv(G[:, i], np.asarray(local, float))


def _rest_local(perf: Performer, bone: str, world_rot) -> np.ndarray:
    """Local rotation that turns `bone` by the world rotation `world_rot` about its head when its
    parent is at rest (R_rest^T W R_rest)."""
    R = perf.rest_rot[_BONE_INDEX[bone]]
    return R.T @ world_rot @ R


def _local_from_world(perf: Performer, G, bone: str, world) -> np.ndarray:
    """Local rotation Q that gives `bone` the world frame `world`, given its parent's frames in G."""
    i = _BONE_INDEX[bone]
    p = _PARENT[i]
    base = G[:, p] @ (perf.rest_rot[p].T @ perf.rest_rot[i])
    return np.swapaxes(base, -1, -2) @ world


# --- clips: a pose per frame, built from postures, IK and interpolation ---------------------------

@dataclass
class _Clip:
    n: int
    root_pos: np.ndarray
    root_rot: np.ndarray
    local: dict[str, np.ndarray]
    planted: np.ndarray  # (n, 2) bool, sides l, r
    segments: list = field(default_factory=list)  # (step, f0, f1, point, by), frames inclusive
    contacts: list = field(default_factory=list)  # (motion, effector, (bone, local), target, (bone, local), mask)
    touches: list = field(default_factory=list)  # (point, bone, local, f0, f1)
    miss: float = 0.0  # the largest IK reach shortfall (m)


def _const(m, n):
    return np.broadcast_to(m, (n, 3, 3)).copy()


def _stand_locals(perf: Performer, n: int, *, arms="down", fingers="relaxed") -> dict[str, np.ndarray]:
    loc = {}
    if arms == "down":
        for side, ss in SIDE_SIGN.items():
            loc[f"upperarm_{side}"] = _const(_rest_local(perf, f"upperarm_{side}",
                                                         _rot([0, 1.0, 0], ss * math.radians(80))), n)
            loc[f"forearm_{side}"] = _const(_rx_const(0.15), n)
    for side in sk.SIDES:
        for f in sk.FINGERS:
            if fingers == "relaxed":
                a = (0.15, 0.25, 0.15) if f != "thumb" else (0.1, 0.1, 0.1)
            elif fingers == "grip":
                a = (1.1, 1.3, 0.6) if f != "thumb" else (0.5, 0.4, 0.3)
            elif fingers == "point":  # index extended, the others curled
                a = (0.0, 0.0, 0.0) if f == "index" else ((1.2, 1.4, 0.7) if f != "thumb" else (0.5, 0.4, 0.3))
            else:
                continue
            for k in range(3):
                loc[f"{f}_{k + 1}_{side}"] = _const(_rx_const(a[k]), n)
    return loc


@functools.lru_cache(maxsize=256)
def _rx_const(angle: float) -> np.ndarray:
    return _rx(angle)


def _posture(perf: Performer, n: int, k: float = 0.0, *, fingers="relaxed", arms="down", twist=0.0) -> _Clip:
    """Standing (k = 0) to crouched deep and bent forward (k = 1), the trunk turned by `twist`
    (radians about the spine, positive to the left); feet planted at rest (leg IK)."""
    s = perf.height / 1.75
    k = np.broadcast_to(np.asarray(k, float), (n,))
    drop = k * 0.62 * s
    root = perf.rest["pelvis"] + np.stack([0.0 * drop, 0.15 * drop, -drop], -1)
    loc = _stand_locals(perf, n, arms=arms, fingers=fingers)
    flex = k * 2.0 / sk.SPINE_COUNT
    turn = _rot(np.array([0.0, 1.0, 0.0]), np.broadcast_to(np.asarray(twist, float), (n,)) / sk.SPINE_COUNT)
    for v in range(1, sk.SPINE_COUNT + 1):
        loc[f"spine_{v:02d}"] = turn @ _rx(flex)
    clip = _Clip(n, root, _const(np.eye(3), n), loc, np.ones((n, 2), bool))
    _plant_feet(perf, clip)
    return clip


def _plant_feet(perf: Performer, clip: _Clip, ankle=None, foot_rot=None, sides=sk.SIDES) -> None:
    """Leg IK: ankles at `ankle[side]` (n, 3) (default the rest ankles) with the foot frame
    `foot_rot[side]` (default flat, as at rest)."""
    G, Hd = _fk(perf, clip.root_pos, clip.root_rot, clip.local)
    for side in sides:
        tgt = perf.rest[f"ankle_{side}"] if ankle is None or side not in ankle else ankle[side]
        tgt = np.broadcast_to(tgt, (clip.n, 3))
        hip = _joints_of(perf, G, Hd, f"hip_{side}")
        pole = np.broadcast_to(normalize(np.array([SIDE_SIGN[side] * 0.15, -1.0, 0.0])), (clip.n, 3))
        G1, theta, miss = _two_bone(hip, tgt, perf.length[_BONE_INDEX[f"thigh_{side}"]],
                                    perf.length[_BONE_INDEX[f"shin_{side}"]], pole)
        clip.miss = max(clip.miss, float(np.max(miss)))
        clip.local[f"thigh_{side}"] = _local_from_world(perf, G, f"thigh_{side}", G1)
        clip.local[f"shin_{side}"] = _rx(theta)
        G2 = G1 @ _rx(theta)
        fr = perf.rest_rot[_BONE_INDEX[f"foot_{side}"]] if foot_rot is None or side not in foot_rot \
            else foot_rot[side]
        fr = np.broadcast_to(fr, (clip.n, 3, 3))
        i = _BONE_INDEX[f"foot_{side}"]
        p = _PARENT[i]
        base = G2 @ (perf.rest_rot[p].T @ perf.rest_rot[i])
        clip.local[f"foot_{side}"] = np.swapaxes(base, -1, -2) @ fr


def _joints_of(perf, G, Hd, joint: str) -> np.ndarray:
    i, tail = _JOINT_SOURCE[joint]
    return Hd[:, i] + (G[:, i, :, 1] * perf.length[i] if tail else 0.0)


def _two_bone(S, T, L1, L2, pole):
    """Analytic two-bone IK: upper bone frame (x = hinge axis, y along the bone, z toward the lower
    bone's bend) and the hinge angle (positive flexes, FORMATS.md §1); `miss` = reach shortfall."""
    d = T - S
    D = np.linalg.norm(d, axis=-1)
    u = d / D[:, None]
    Dc = np.clip(D, abs(L1 - L2) + 1e-6, L1 + L2)
    cos_a = (L1 * L1 + Dc * Dc - L2 * L2) / (2 * L1 * Dc)
    sin_a = np.sqrt(np.clip(1 - cos_a ** 2, 0, 1))
    v = normalize(pole - (pole * u).sum(-1, keepdims=True) * u)
    E = S + L1 * (cos_a[:, None] * u + sin_a[:, None] * v)
    W = S + Dc[:, None] * u
    y1 = (E - S) / L1
    y2 = (W - E) / L2
    # The lower bone bends away from the pole within the (u, v) plane; defined even when straight.
    z1 = sin_a[:, None] * u - cos_a[:, None] * v
    x1 = np.cross(y1, z1)
    theta = np.arctan2((y2 * z1).sum(-1), (y2 * y1).sum(-1))
    return np.stack([x1, y1, z1], -1), theta, np.abs(D - Dc)


def _arm_ik(perf: Performer, clip: _Clip, side: str, target, hand_rot, eff_local, pole=None, exact=None,
            fk=None) -> None:
    """Place the point `eff_local` (hand bone frame) at `target` (n, 3) with the hand's world frame
    `hand_rot` (n, 3, 3): two-bone IK for the arm, the hand's rotation relative to the forearm."""
    n = clip.n
    # `fk`: the body's frames when they are the same on every frame (one row broadcasts).
    G, Hd = fk if fk is not None else _fk(perf, clip.root_pos, clip.root_rot, clip.local)
    ss = SIDE_SIGN[side]
    wrist = target - _mv(hand_rot, eff_local)
    S = _joints_of(perf, G, Hd, f"shoulder_{side}")
    if pole is None:
        pole = np.broadcast_to(normalize(np.array([ss * 0.6, 0.5, -1.0])), (n, 3))
    L1 = perf.length[_BONE_INDEX[f"upperarm_{side}"]]
    L2 = perf.length[_BONE_INDEX[f"forearm_{side}"]]
    G1, theta, miss = _two_bone(S, wrist, L1, L2, pole)
    if exact is not None:  # only these frames must reach (the rest is an approach path)
        miss = miss[exact]
    clip.miss = max(clip.miss, float(np.max(miss, initial=0.0)))
    clip.local[f"upperarm_{side}"] = _local_from_world(perf, G, f"upperarm_{side}", G1)
    clip.local[f"forearm_{side}"] = _rx(theta)
    G2 = G1 @ _rx(theta)
    i = _BONE_INDEX[f"hand_{side}"]
    p = _PARENT[i]
    base = G2 @ (perf.rest_rot[p].T @ perf.rest_rot[i])
    clip.local[f"hand_{side}"] = np.swapaxes(base, -1, -2) @ hand_rot


def _effector(perf: Performer, profile: str, by: str) -> tuple[str, np.ndarray]:
    """(bone, local) of a touch effector: a fingertip LED, a palm centre or a controller tip."""
    side = by[-1]
    if by.startswith("palm_"):
        if profile == "minimal":
            p, R = perf.controller[side]
            c = perf.hand[side]
            return f"hand_{side}", np.array([p[0], p[1], c["zp"]])
        return f"hand_{side}", perf.hand[side]["palm_centre"].copy()
    if by.startswith("controller_tip_"):
        p, R = perf.controller[side]
        return f"hand_{side}", p + R @ CONTROLLER_TIP_LOCAL
    finger = by.split("_")[0]
    # Fingertip LED with the finger extended (touch pose "point"), in the hand bone frame.
    return f"hand_{side}", _tip_led_in_hand(perf, side, finger)


def _tip_led_in_hand(perf: Performer, side: str, finger: str) -> np.ndarray:
    hb = _BONE_INDEX[f"hand_{side}"]
    R, h = perf.rest_rot[hb], perf.rest_head[hb]
    tip = R.T @ (perf.rest[f"tip_{finger}_{side}"] - h)
    return tip + np.array([0.0, 0.0, -perf.radius[f"finger_{finger}_{side}"]])


def _world_dir(G, bone: str, d_local) -> np.ndarray:
    return _mv(G[:, _BONE_INDEX[bone]], np.asarray(d_local, float))


def _touch_plan(perf: Performer, profile: str, points) -> tuple[str, float, float]:
    """(toucher side, crouch k, trunk twist) for touching every point of `points` (one point, or a
    foot's sole outline, which then shares one posture so the hand moves little between them).

    The opposite hand by default (FORMATS.md §2.4); the same-side hand only where the opposite one
    cannot reach (the far side of the foot). Among postures, the least crouched and least turned
    one from which the hand reaches with a margin (evaluated in one batch)."""
    side = _point_side(points[0])
    torso = points[0] in sl.TORSO_POINTS
    first = (side or "r") if torso and points[0].startswith("back_") else (OTHER[side] if side else "r")
    fingers = "grip" if profile == "minimal" else "point"
    best = None
    for toucher in (first, OTHER[first]) if side else (first,):
        _, eff_local = _effector(perf, profile, _by(profile, torso, toucher))
        turns = (0.0, 0.35, 0.7) if side and side != toucher else (0.0, 0.35, -0.35, 0.7, -0.7)
        tw_sign = -SIDE_SIGN[toucher] if side and side != toucher else 1.0
        grid = [(float(k), tw_sign * tw) for k in np.linspace(0.0, 1.3, 14) for tw in turns]
        K, TW = np.array(grid).T
        bad = np.zeros(len(grid))
        for point in points:
            bone, local, nrm = perf.surface_points[point]
            clip = _posture(perf, len(grid), K, fingers=fingers, twist=TW)
            _touched_limb(perf, clip, point, side)
            G, Hd = _fk(perf, clip.root_pos, clip.root_rot, clip.local)
            tgt = _point(G, Hd, bone, local)
            nw = _world_dir(G, bone, nrm)
            R = _touch_hand_rot(perf, G, Hd, toucher, tgt, nw, torso and profile == "full", eff_local,
                                floor=point.startswith("sole_") and profile == "full")
            wrist = tgt - _mv(R, eff_local)
            S = _joints_of(perf, G, Hd, f"shoulder_{toucher}")
            L1 = perf.length[_BONE_INDEX[f"upperarm_{toucher}"]]
            L2 = perf.length[_BONE_INDEX[f"forearm_{toucher}"]]
            dist = np.linalg.norm(wrist - S, axis=-1)
            bad = np.maximum(bad, np.maximum(dist - (L1 + L2 - 0.02), abs(L1 - L2) + 0.02 - dist))
        bad = np.maximum(bad, 0.0)
        ok = np.flatnonzero(bad == 0.0)
        if len(ok):
            return (toucher,) + grid[ok[0]]
        if best is None or bad.min() < best[0]:
            best = (bad.min(), (toucher,) + grid[int(np.argmin(bad))])
    return best[1]  # nothing reaches with a margin: the closest (ik_miss reports any shortfall)


def _touch_clip(perf: Performer, profile: str, point: str, fps: float, plan=None) -> _Clip:
    """Approach, hold still on the true surface point, retreat (one `touch` segment = the hold)."""
    side = _point_side(point)
    torso = point in sl.TORSO_POINTS
    fingers = "grip" if profile == "minimal" else "point"
    t_app, t_hold = 0.45, 0.6
    na, nh = max(int(round(t_app * fps)), 2), max(int(round(t_hold * fps)), 3)
    n = 2 * na + nh
    bone, local, nrm = perf.surface_points[point]
    toucher, *chosen = plan or _touch_plan(perf, profile, [point])
    by = _by(profile, torso, toucher)
    eff_bone, eff_local = _effector(perf, profile, by)
    # The body holds still during a touch: pose it once, then only the touching arm moves.
    clip = _posture(perf, 1, chosen[0], fingers=fingers, twist=chosen[1])
    _touched_limb(perf, clip, point, side)
    G, Hd = _fk(perf, clip.root_pos, clip.root_rot, clip.local)
    tgt = _point(G, Hd, bone, local)
    nw = _world_dir(G, bone, nrm)
    R = _touch_hand_rot(perf, G, Hd, toucher, tgt, nw, torso and profile == "full", eff_local,
                        floor=point.startswith("sole_") and profile == "full")
    clip = _Clip(n, np.repeat(clip.root_pos, n, 0), np.repeat(clip.root_rot, n, 0),
                 {k: np.repeat(v, n, 0) for k, v in clip.local.items()}, np.ones((n, 2), bool))
    # The approach path: along the surface normal, 8 cm away, easing in and out; on the floor from
    # 15 cm straight above (the hand never dips below the floor between touches).
    w = np.concatenate([1 - _smooth(np.linspace(0, 1, na)), np.zeros(nh), _smooth(np.linspace(0, 1, na))])
    away = np.array([0.0, 0.0, 0.15]) if point.startswith("sole_") else 0.08 * nw
    _arm_ik(perf, clip, toucher, tgt + away * w[:, None], np.repeat(R, n, 0), eff_local, exact=w == 0.0,
            fk=(G, Hd))
    clip.segments.append(("touch", na, na + nh - 1, point, by))
    clip.touches.append((point, bone, local, na, na + nh - 1))
    return clip


def _by(profile: str, torso: bool, toucher: str) -> str:
    if profile == "minimal":
        return f"controller_tip_{toucher}"
    return f"palm_{toucher}" if torso else f"index_tip_{toucher}"


def _point_side(point: str) -> str | None:
    if point.endswith("_l") or point.endswith("_r"):
        return point[-1]
    return None


def _touch_hand_rot(perf, G, Hd, toucher, tgt, nw, palm: bool, eff_local, floor: bool = False) -> np.ndarray:
    n = len(tgt)
    S = _joints_of(perf, G, Hd, f"shoulder_{toucher}")
    up = np.broadcast_to(np.array([0.0, 0.0, 1.0]), (n, 3))
    if palm:
        # Palm flat on the surface: palm normal (+z) into it, fingers toward the other side and up.
        hint = normalize(np.array([-SIDE_SIGN[toucher] * 1.0, 0.0, 0.6]))
        hint = np.where(np.abs((nw * hint).sum(-1, keepdims=True)) > 0.9, up, hint)
        return _orient(np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0]), -nw, hint)
    # Pointing: the effector's direction from the wrist goes into the surface, away from the shoulder.
    away = normalize(tgt - S)
    a = normalize(-0.5 * nw + away)
    if floor:
        # On the floor (sole outline): the hand flat, palm up, coming in horizontally, so the
        # fingertip LED (nail side) touches the floor and the finger stays above it.
        flat = np.array([1.0, 1.0, 0.0])
        a = normalize(normalize(-nw * flat) + 0.5 * normalize(away * flat))
        return _orient(normalize(eff_local * flat), np.array([0.0, 0.0, 1.0]), a, up)
    down = np.broadcast_to(np.array([0.0, 0.0, -1.0]), (n, 3))
    b = np.where(np.abs((a * down).sum(-1, keepdims=True)) > 0.9,
                 np.broadcast_to(np.array([0.0, -1.0, 0.0]), (n, 3)), down)
    return _orient(normalize(eff_local), np.array([0.0, 0.0, 1.0]), a, b)


def _touched_limb(perf: Performer, clip: _Clip, point: str, side: str | None) -> None:
    """Hold the touched hand or elbow where the other hand can reach it."""
    if side is None:
        return
    n = clip.n
    s = perf.height / 1.75
    ss = SIDE_SIGN[side]
    on_hand = point.startswith(("wrist_", "mcp_", "palm_"))
    if on_hand:
        G, Hd = _fk(perf, clip.root_pos, clip.root_rot, clip.local)
        S = _joints_of(perf, G, Hd, f"shoulder_{side}")
        wrist = S + np.array([-ss * 0.10, -0.30, -0.22]) * s
        palm_up = point.startswith(("wrist_bottom", "palm_"))
        fingers = normalize(np.array([-ss * 0.5, -1.0, 0.0]))
        z = np.array([0.0, 0.0, 1.0 if palm_up else -1.0])
        R = _orient(np.array([0.0, 1.0, 0.0]), np.array([0.0, 0.0, 1.0]), fingers, z)
        for f in sk.FINGERS:  # fingers extended so that MCP and palm points are free
            for k in range(3):
                clip.local[f"{f}_{k + 1}_{side}"] = _const(np.eye(3), n)
        _arm_ik(perf, clip, side, wrist, np.broadcast_to(R, (n, 3, 3)), np.zeros(3))
    elif point.startswith("elbow_"):
        d = normalize(np.array([ss * 0.05, -0.6, -1.0]))
        up = _frame(np.array([-1.0, 0.0, 0.0]), d)
        clip.local[f"upperarm_{side}"] = _const(perf.rest_rot[_BONE_INDEX[f"upperarm_{side}"]].T @ up, n)
        clip.local[f"forearm_{side}"] = _const(_rx(1.5), n)


def _tpose_clip(perf: Performer, n: int, profile: str) -> _Clip:
    clip = _posture(perf, n, 0.0, fingers="grip" if profile == "minimal" else "extended", arms="t")
    return clip


def _palms_together_clip(perf: Performer, n: int, fps: float) -> _Clip:
    """Palms pressed together in front of the chest, fingers extended; the right hand slides and
    turns a little in the palm plane so the LED midpoints span the plane (DESIGN.md §3, Hands)."""
    s = perf.height / 1.75
    clip = _posture(perf, n, 0.0, fingers="extended")
    t = np.arange(n) / fps
    c0 = np.array([0.0, -0.28 * s, perf.rest["shoulder_l"][2] - 0.25 * s])
    # Left: palm normal -X, fingers up and a little forward.
    up = normalize(np.array([0.0, -0.3, 1.0]))
    Rl = _orient(np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0]), np.array([-1.0, 0.0, 0.0]), up)
    slide = np.stack([np.zeros(n), 0.02 * np.sin(2 * np.pi * 0.5 * t), 0.02 * np.sin(2 * np.pi * 0.31 * t + 1)], -1)
    turn = _rot(np.array([1.0, 0.0, 0.0]), 0.2 * np.sin(2 * np.pi * 0.23 * t))
    Rr0 = _orient(np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0]), up)
    Rr = turn @ Rr0
    pc_l = perf.hand["l"]["palm_centre"]
    pc_r = perf.hand["r"]["palm_centre"]
    _arm_ik(perf, clip, "l", np.broadcast_to(c0, (n, 3)), np.broadcast_to(Rl, (n, 3, 3)), pc_l)
    _arm_ik(perf, clip, "r", c0 + slide, Rr, pc_r)
    clip.segments.append(("palms_together", 0, n - 1, None, None))
    return clip


def _flex_clip(perf: Performer, n: int, fps: float, step: str) -> _Clip:
    side = step[-1]
    ss = SIDE_SIGN[side]
    t = np.arange(n) / fps
    phase = 0.5 - 0.5 * np.cos(2 * np.pi * 0.45 * t)
    clip = _posture(perf, n, 0.0)
    if step.startswith("flex_elbow"):
        d = normalize(np.array([ss * 0.3, -0.35, -1.0]))
        up = _frame(np.array([-1.0, 0.0, 0.0]), d)
        wob = _rot(np.array([0.0, 1.0, 0.0]), 0.08 * np.sin(2 * np.pi * 0.2 * t)) @ up
        clip.local[f"upperarm_{side}"] = np.swapaxes(perf.rest_rot[_BONE_INDEX[f"upperarm_{side}"]], -1, -2) @ wob
        clip.local[f"forearm_{side}"] = _rx(0.2 + 2.0 * phase)
    else:
        clip.local[f"thigh_{side}"] = _rx(-0.7 + 0.1 * np.sin(2 * np.pi * 0.2 * t))
        clip.local[f"shin_{side}"] = _rx(0.15 + 1.6 * phase)
        clip.local[f"foot_{side}"] = _const(np.eye(3), n)
        clip.planted[:, 0 if side == "l" else 1] = False
    clip.segments.append((step, 0, n - 1, None, None))
    return clip


def _swing_clip(perf: Performer, n: int, fps: float, step: str) -> _Clip:
    side = step[-1]
    ss = SIDE_SIGN[side]
    t = np.arange(n) / fps
    clip = _posture(perf, n, 0.0)
    if step.startswith("swing_shoulder"):
        theta = np.radians(50 + 30 * np.sin(2 * np.pi * 0.37 * t))  # from straight down; below horizontal
        phi = np.radians(55 + 95 * np.sin(2 * np.pi * 0.23 * t + 0.5))  # forward -> lateral -> back
        bone = f"upperarm_{side}"
        twist = 0.5 * np.sin(2 * np.pi * 0.29 * t)
        clip.local[f"forearm_{side}"] = _const(_rx(0.3), n)
    else:
        theta = np.radians(22 + 16 * np.sin(2 * np.pi * 0.41 * t))
        phi = np.radians(70 + 110 * np.sin(2 * np.pi * 0.19 * t + 0.3))
        bone = f"thigh_{side}"
        twist = 0.25 * np.sin(2 * np.pi * 0.31 * t)
        clip.local[f"shin_{side}"] = _const(_rx(0.3), n)
        clip.local[f"foot_{side}"] = _const(np.eye(3), n)
        clip.planted[:, 0 if side == "l" else 1] = False
    d = np.stack([ss * np.sin(theta) * np.sin(phi), -np.sin(theta) * np.cos(phi), -np.cos(theta)], -1)
    i = _BONE_INDEX[bone]
    rest_y = perf.rest_rot[i][:, 1]
    hang = _rot(np.array([0.0, 1.0, 0.0]), ss * math.radians(90)) if bone.startswith("upperarm") else np.eye(3)
    W = _rot(d, twist) @ _between(hang @ rest_y, d) @ hang
    clip.local[bone] = perf.rest_rot[i].T @ W @ perf.rest_rot[i]
    clip.segments.append((step, 0, n - 1, None, None))
    return clip


# --- motions -----------------------------------------------------------------------------------------

def _motion_clip(perf: Performer, motion: str, fps: float, profile: str) -> _Clip:
    s = perf.height / 1.75
    fingers = "grip" if profile == "minimal" else "relaxed"

    def frames(sec):
        return max(int(round(sec * fps)), 4)

    if motion == "squat":
        n = frames(6.0)
        t = np.arange(n) / fps
        ph = 0.5 - 0.5 * np.cos(2 * np.pi * t / 3.0)
        clip = _posture(perf, n, 0.0, fingers=fingers)
        clip.root_pos = clip.root_pos + np.stack([0 * ph, 0.10 * s * ph, -0.32 * s * ph], -1)
        for v in range(1, sk.SPINE_COUNT + 1):
            clip.local[f"spine_{v:02d}"] = _rx(0.35 * ph / sk.SPINE_COUNT)
        for side, ss in SIDE_SIGN.items():
            W = _rot(np.array([1.0, 0.0, 0.0]), -1.3 * ph) @ _rot(np.array([0.0, 1.0, 0.0]), ss * math.radians(80))
            clip.local[f"upperarm_{side}"] = _rest_local(perf, f"upperarm_{side}", W)
        _plant_feet(perf, clip)
    elif motion == "arm_raise":
        n = frames(6.0)
        t = np.arange(n) / fps
        side_raise = _smooth(np.clip(t / 1.5, 0, 1)) - _smooth(np.clip((t - 1.5) / 1.5, 0, 1))
        front_raise = _smooth(np.clip((t - 3.0) / 1.5, 0, 1)) - _smooth(np.clip((t - 4.5) / 1.5, 0, 1))
        clip = _posture(perf, n, 0.0, fingers=fingers)
        for side, ss in SIDE_SIGN.items():
            W = _rot(np.array([1.0, 0.0, 0.0]), -2.6 * front_raise) @ \
                _rot(np.array([0.0, 1.0, 0.0]), ss * (math.radians(80) - 2.6 * side_raise))
            clip.local[f"upperarm_{side}"] = _rest_local(perf, f"upperarm_{side}", W)
    elif motion == "clap":
        n = frames(5.0)
        t = np.arange(n) / fps
        clip = _posture(perf, n, 0.0, fingers="extended" if profile == "full" else fingers)
        c0 = np.array([0.0, -0.32 * s, perf.rest["shoulder_l"][2] - 0.22 * s])
        period = 0.6
        tc = np.mod(t - 0.5, period)
        hold = 0.12
        gap = np.where(tc < hold, 0.0, 0.25 * s * np.sin(np.pi * np.clip((tc - hold) / (period - hold), 0, 1)))
        env = _smooth(np.clip(t / 0.5, 0, 1)) * _smooth(np.clip((t[-1] - t) / 0.5, 0, 1))
        gap = np.where(env < 1.0, np.maximum(gap, 0.25 * s * (1 - env)), gap)
        gap = np.where((t >= 0.5) & (t <= t[-1] - 0.5), gap, 0.25 * s * (1 - env) + gap * env)
        up = normalize(np.array([0.0, -1.0, 0.8]))
        Rl = _orient(np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0]), np.array([-1.0, 0.0, 0.0]), up)
        Rr = _orient(np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0]), up)
        el, pl = _effector(perf, profile, "palm_l")
        er, pr = _effector(perf, profile, "palm_r")
        xg = np.stack([gap / 2, np.zeros(n), np.zeros(n)], -1)
        _arm_ik(perf, clip, "l", c0 + xg, np.broadcast_to(Rl, (n, 3, 3)), pl)
        _arm_ik(perf, clip, "r", c0 - xg, np.broadcast_to(Rr, (n, 3, 3)), pr)
        clip.contacts.append(("clap", "palm_r", (er, pr), "mesh:palm_l/palm_centre", (el, pl), gap == 0.0))
    elif motion in ("hand_on_belly", "hand_on_head"):
        n = frames(6.0 if motion == "hand_on_belly" else 5.0)
        t = np.arange(n) / fps
        clip = _posture(perf, n, 0.0, fingers=fingers)
        sway = 0.12 * np.sin(2 * np.pi * 0.25 * t)
        for v in range(1, sk.SPINE_COUNT + 1):
            clip.local[f"spine_{v:02d}"] = _rx(sway / sk.SPINE_COUNT) @ \
                _rot(np.array([0.0, 1.0, 0.0]), 0.5 * sway / sk.SPINE_COUNT)
        point = "belly_c2" if motion == "hand_on_belly" else "skull_top"
        target_id = f"mesh:torso/{point}" if motion == "hand_on_belly" else f"sphere:skull/{point}"
        bone, local, nrm = perf.surface_points[point]
        G, Hd = _fk(perf, clip.root_pos, clip.root_rot, clip.local)
        tgt = _point(G, Hd, bone, local)
        nw = _world_dir(G, bone, nrm)
        eb, el_ = _effector(perf, profile, "palm_r")
        if motion == "hand_on_head":
            R = _orient(np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0]), -nw,
                        np.broadcast_to(np.array([1.0, -0.3, 0.0]), (n, 3)))
        else:
            R = _touch_hand_rot(perf, G, Hd, "r", tgt, nw, True, el_)
        w = np.clip(1 - _smooth(t / 1.0), 0, 1) + np.clip(_smooth((t - (t[-1] - 1.0)) / 1.0), 0, 1)
        _arm_ik(perf, clip, "r", tgt + nw * (0.12 * w)[:, None], R, el_, exact=w == 0.0)
        clip.contacts.append((motion, "palm_r", (eb, el_), target_id, (bone, local), w == 0.0))
    elif motion == "hands_on_thighs":
        n = frames(5.0)
        t = np.arange(n) / fps
        clip = _posture(perf, n, _thigh_reach(perf, profile, fingers), fingers=fingers)
        w = np.clip(1 - _smooth(t / 1.0), 0, 1) + np.clip(_smooth((t - (t[-1] - 1.0)) / 1.0), 0, 1)
        G, Hd = _fk(perf, clip.root_pos, clip.root_rot, clip.local)
        for side in sk.SIDES:
            bone, local, nrm = perf.surface_points[f"thigh_front_{side}"]
            tgt = _point(G, Hd, bone, local)
            nw = _world_dir(G, bone, nrm)
            eb, el_ = _effector(perf, profile, f"palm_{side}")
            R = _orient(np.array([0.0, 0.0, 1.0]), np.array([0.0, 1.0, 0.0]), -nw,
                        np.broadcast_to(np.array([0.0, 0.0, -1.0]), (n, 3)))
            _arm_ik(perf, clip, side, tgt + nw * (0.10 * w)[:, None], R, el_, exact=w == 0.0)
            clip.contacts.append((motion, f"palm_{side}", (eb, el_), f"capsule:thigh_{side}/front", (bone, local),
                                  w == 0.0))
    elif motion == "walk_in_place":
        n = frames(6.0)
        t = np.arange(n) / fps
        clip = _posture(perf, n, 0.0, fingers=fingers)
        period = 1.2
        ankle = {}
        for side, off in (("l", 0.0), ("r", 0.5)):
            ph = np.mod(t / period - off, 1.0)
            lift = np.where(ph < 0.45, np.sin(np.pi * ph / 0.45), 0.0)
            lift = lift * _smooth(np.clip(t / 0.6, 0, 1)) * _smooth(np.clip((t[-1] - t) / 0.6, 0, 1))
            ankle[side] = perf.rest[f"ankle_{side}"] + np.stack([0 * lift, -0.06 * s * lift, 0.16 * s * lift], -1)
            clip.planted[:, 0 if side == "l" else 1] = lift == 0.0
            ss = SIDE_SIGN[side]
            swing = 0.35 * np.sin(2 * np.pi * (t / period - off))
            W = _rot(np.array([1.0, 0.0, 0.0]), swing) @ _rot(np.array([0.0, 1.0, 0.0]), ss * math.radians(80))
            clip.local[f"upperarm_{side}"] = _rest_local(perf, f"upperarm_{side}", W)
        clip.root_pos = clip.root_pos + np.stack([0.015 * s * np.sin(2 * np.pi * t / period), 0 * t,
                                                  -0.01 * s * (0.5 - 0.5 * np.cos(4 * np.pi * t / period))], -1)
        _plant_feet(perf, clip, ankle=ankle)
    else:
        raise BodyCalError(f"unknown motion '{motion}'", field="motions", hint=f"use {', '.join(MOTIONS)}")
    clip.segments.append(("motion", 0, clip.n - 1, motion, None))
    return clip


def _thigh_reach(perf: Performer, profile: str, fingers: str) -> float:
    """The least crouch from which both palms reach the front of the thighs with a margin."""
    ks = np.linspace(0.2, 0.9, 15)
    clip = _posture(perf, len(ks), ks, fingers=fingers)
    G, Hd = _fk(perf, clip.root_pos, clip.root_rot, clip.local)
    ok = np.ones(len(ks), bool)
    for side in sk.SIDES:
        bone, local, nrm = perf.surface_points[f"thigh_front_{side}"]
        _, el = _effector(perf, profile, f"palm_{side}")
        wrist_dist = np.linalg.norm(_point(G, Hd, bone, local) - _joints_of(perf, G, Hd, f"shoulder_{side}"), axis=-1)
        reach = perf.length[_BONE_INDEX[f"upperarm_{side}"]] + perf.length[_BONE_INDEX[f"forearm_{side}"]]
        ok &= wrist_dist < reach - 0.03  # the wrist sits above the target, closer to the shoulder
    return float(ks[np.argmax(ok)]) if ok.any() else float(ks[-1])


def _transition(perf: Performer, a: _Clip, b: _Clip, n: int) -> _Clip:
    """Ease from a's last frame to b's first frame (rotations interpolated per bone, all bones at
    once: a @ exp(w log(a^T b)))."""
    w = _smooth(np.linspace(0, 1, n + 2)[1:-1])
    root = a.root_pos[-1] + (b.root_pos[0] - a.root_pos[-1]) * w[:, None]
    names = sorted(set(a.local) | set(b.local))
    qa = np.stack([a.root_rot[-1]] + [a.local[k][-1] if k in a.local else np.eye(3) for k in names])
    qb = np.stack([b.root_rot[0]] + [b.local[k][0] if k in b.local else np.eye(3) for k in names])
    q = matrix_to_quat(np.swapaxes(qa, -1, -2) @ qb)
    ang = 2 * np.arctan2(np.linalg.norm(q[:, 1:], axis=-1), q[:, 0])
    axis = np.where(ang[:, None] > 1e-12, q[:, 1:], np.array([1.0, 0.0, 0.0]))
    mats = qa[None] @ _rot(np.broadcast_to(axis, (n,) + axis.shape), w[:, None] * ang[None])
    rr = mats[:, 0].copy()
    loc = {k: mats[:, i + 1].copy() for i, k in enumerate(names)}
    planted = np.broadcast_to(a.planted[-1] & b.planted[0], (n, 2)).copy()
    clip = _Clip(n, root, rr, loc, planted)
    # Feet planted at both ends stay planted in between (leg IK on the interpolated body).
    _plant_feet(perf, clip, sides=[s for i, s in enumerate(sk.SIDES) if planted[0, i]])
    _keep_hands_above_floor(perf, clip)
    return clip


_HAND_JOINTS = {s: np.array([sk.JOINT_INDEX[j] for j in sk.JOINTS
                             if j == f"wrist_{s}" or (j.endswith(f"_{s}") and j.split("_")[0] in sk.FINGER_JOINTS)])
                for s in sk.SIDES}


def _keep_hands_above_floor(perf: Performer, clip: _Clip) -> None:
    """Interpolating between two crouched reaching poses can sweep a hand through the floor: lift
    the hand (same orientation, same elbow swivel) by what it dips, smoothly, with arm IK."""
    G, Hd = _fk(perf, clip.root_pos, clip.root_rot, clip.local)
    J = _joints(perf, G, Hd)
    for side in sk.SIDES:
        dip = np.maximum(-J[:, _HAND_JOINTS[side], 2].min(1) + 0.005, 0.0)
        dip[[0, -1]] = 0.0
        if dip.max() <= 0.005:
            continue
        k = max(clip.n // 6, 1)
        pad = np.pad(dip, k, mode="edge")
        env = np.max(np.lib.stride_tricks.sliding_window_view(pad, 2 * k + 1), axis=1)
        env = np.convolve(np.pad(env, k, mode="edge"), np.ones(2 * k + 1) / (2 * k + 1), mode="valid")
        env *= np.sin(np.linspace(0.0, np.pi, clip.n)) ** 0.5  # zero at both ends: continuous
        wrist = J[:, sk.JOINT_INDEX[f"wrist_{side}"]]
        elbow = J[:, sk.JOINT_INDEX[f"elbow_{side}"]]
        shoulder = J[:, sk.JOINT_INDEX[f"shoulder_{side}"]]
        lift = np.stack([0 * env, 0 * env, env], -1)
        _arm_ik(perf, clip, side, wrist + lift, G[:, _BONE_INDEX[f"hand_{side}"]], np.zeros(3),
                pole=elbow - shoulder, fk=(G, Hd))


# --- the session ---------------------------------------------------------------------------------------

def calibration_touch_points(profile: str = "full") -> list[str]:
    """Every touch point of FORMATS.md §2.4 the profile performs, in protocol order."""
    pts = []
    for s in sk.SIDES:
        pts += [f"wrist_top_{s}", f"wrist_bottom_{s}"]
        if profile == "full":
            pts += [f"mcp_{f}_{s}" for f in sk.FINGERS] + sl.palm_points(len(_PALM_UY), s)
    for s in sk.SIDES:
        pts += [f"elbow_in_{s}", f"elbow_out_{s}", f"shoulder_front_{s}", f"shoulder_back_{s}"]
    for s in sk.SIDES:
        pts += [f"hip_front_{s}", f"hip_back_{s}", f"knee_in_{s}", f"knee_out_{s}", f"ankle_in_{s}",
                f"ankle_out_{s}"] + sl.sole_points(4, s)
    pts += list(sl.JAW_POINTS) + list(sl.SKULL_POINTS) + ["skull_base_l", "skull_base_r"]
    pts += list(sl.TORSO_POINTS)
    return pts


@dataclass
class _ClipResult:
    n: int
    joints: np.ndarray  # (n, J, 3)
    pos: np.ndarray  # (n, D, 3) true device poses
    quat: np.ndarray  # (n, D, 4)
    markers: np.ndarray  # (n, M, 3) true markers
    planted: np.ndarray
    segments: list
    contacts: list  # (motion, effector, target, eff (n,3), tgt (n,3), mask)
    miss: float
    touches: list  # (point, f0, f1, world (k, 3))


def _evaluate(perf: Performer, clip: _Clip, profile: str, roles, marker_names) -> _ClipResult:
    G, Hd = _fk(perf, clip.root_pos, clip.root_rot, clip.local)
    n = clip.n
    joints = _joints(perf, G, Hd)
    pos = np.empty((n, len(roles), 3))
    rot = np.empty((n, len(roles), 3, 3))
    for d, role in enumerate(roles):
        if role.startswith("hand_"):
            side = role[-1]
            hb = _BONE_INDEX[role]
            if profile == "full":
                leds = perf.hand[side]["leds"]
                pos[:, d] = Hd[:, hb] + _mv(G[:, hb], leds.mean(0))
                rot[:, d] = G[:, hb] @ np.diag([-1.0, 1.0, -1.0])  # the LED rule's frame (see docstring)
            else:
                p, R = perf.controller[side]
                pos[:, d] = Hd[:, hb] + _mv(G[:, hb], p)
                rot[:, d] = G[:, hb] @ R
        else:
            bone, p, R = perf.mounts[role]
            i = _BONE_INDEX[bone]
            pos[:, d] = Hd[:, i] + _mv(G[:, i], p)
            rot[:, d] = G[:, i] @ R
    markers = np.empty((n, len(marker_names), 3))
    for m, name in enumerate(marker_names):
        side = name[-1]
        if name.startswith("hand_led"):
            k = int(name[8]) - 1
            markers[:, m] = _point(G, Hd, f"hand_{side}", perf.hand[side]["leds"][k])
        elif name.startswith("controller_tip_"):
            p, R = perf.controller[side]
            markers[:, m] = _point(G, Hd, f"hand_{side}", p + R @ CONTROLLER_TIP_LOCAL)
        else:
            f = name.split("_")[0]
            bone = f"{f}_3_{side}"
            L = perf.length[_BONE_INDEX[bone]]
            markers[:, m] = _point(G, Hd, bone, np.array([0.0, L, -perf.radius[f"finger_{f}_{side}"]]))
    contacts = []
    for motion, eff, (eb, el), target, (tb, tl), mask in clip.contacts:
        contacts.append((motion, eff, target, _point(G, Hd, eb, el), _point(G, Hd, tb, tl), mask))
    touches = [(p, f0, f1, _point(G[f0:f1 + 1], Hd[f0:f1 + 1], b, lc)) for p, b, lc, f0, f1 in clip.touches]
    return _ClipResult(n, joints, pos, matrix_to_quat(rot), markers, clip.planted, clip.segments, contacts,
                       clip.miss, touches)


def record_session(performer: Performer, profile: str = "full", motions=MOTIONS, calibration=True, fps: float = 90.0,
                   noise_mm: float = 1.0, wobble_mm: float = 2.0, dropout_rate: float = 0.0,
                   outlier_rate: float = 0.0, seed: int = 0, motion_seconds: float | None = None,
                   touch_points=None, pace: float = 1.0):
    """Perform the calibration protocol (FORMATS.md §2.4) and the motions; returns
    (Recording in the internal frame, GroundTruth). `calibration` may be True, False or a list of
    step names to perform; `touch_points` restricts the touches (default: every one the profile
    allows, see calibration_touch_points). `motion_seconds` repeats the motion list (whole motions,
    each 5-6 s, with 0.5 s transitions) until at least that much motion time is recorded; None
    performs each motion once.
    `pace` < 1 performs the calibration steps faster (a compact demo file); 1 is the protocol's
    natural pace (touches hold 0.6 s, flex / swing steps last 4.5-5 s)."""
    if profile not in PROFILES:
        raise BodyCalError(f"unknown profile '{profile}'", field="profile", hint="use 'full' or 'minimal'")
    if not fps > 0:
        raise BodyCalError("fps must be positive", field="fps")
    for name, value, lo, hi in (("noise_mm", noise_mm, 0.0, 50.0), ("wobble_mm", wobble_mm, 0.0, 50.0),
                                ("dropout_rate", dropout_rate, 0.0, 0.5), ("outlier_rate", outlier_rate, 0.0, 0.5)):
        if not lo <= value <= hi:
            raise BodyCalError(f"{name} must be within {lo:g}-{hi:g}, got {value!r}", field=name)
    if motion_seconds is not None and not motion_seconds >= 0:
        raise BodyCalError(f"motion_seconds must be >= 0, got {motion_seconds!r}", field="motion_seconds")
    perf = performer
    roles = FULL_ROLES if profile == "full" else MINIMAL_ROLES
    if profile == "full":
        marker_names = [f"hand_led{k}_{s}" for s in sk.SIDES for k in (1, 2, 3)] + \
            [f"{f}_tip_{s}" for s in sk.SIDES for f in sk.FINGERS]
    else:
        marker_names = [f"controller_tip_{s}" for s in sk.SIDES]

    steps = _calibration_steps(profile, calibration)
    clips: list = []  # _Clip or cached key
    cache: dict = {}

    def add(key, make):
        if key not in cache:
            cache[key] = make()
        clips.append(key)

    if not 0.2 <= pace <= 5.0:
        raise BodyCalError(f"pace {pace} is outside 0.2-5", field="pace")
    cf = fps * pace  # calibration clips are built at this rate and played at fps
    n_trans = max(int(round(0.5 * cf)), 2)
    add("stand0", lambda: _posture(perf, max(int(round(0.6 * cf)), 2), 0.0, fingers="relaxed"))
    if "tpose" in steps:
        def make_tpose():
            c = _tpose_clip(perf, max(int(round(2.0 * cf)), 5), profile)
            c.segments.append(("tpose", 0, c.n - 1, None, None))
            return c
        add("tpose", make_tpose)
    if "stand" in steps:
        def make_stand():
            c = _posture(perf, max(int(round(1.5 * cf)), 5), 0.0, fingers="grip" if profile == "minimal"
                         else "relaxed")
            c.segments.append(("stand", 0, c.n - 1, None, None))
            return c
        add("stand", make_stand)
    if "palms_together" in steps:
        add("palms", lambda: _palms_together_clip(perf, max(int(round(2.0 * cf)), 20), cf))
    min_steps = 160 if pace >= 1.0 else 40  # circle / sphere fits want 150+ frames; a brisk demo fewer
    for step in ("flex_elbow_l", "flex_elbow_r", "flex_knee_l", "flex_knee_r"):
        if step in steps:
            add(step, lambda step=step: _flex_clip(perf, max(int(round(4.5 * cf)), min_steps), cf, step))
    for step in ("swing_shoulder_l", "swing_shoulder_r", "swing_hip_l", "swing_hip_r"):
        if step in steps:
            add(step, lambda step=step: _swing_clip(perf, max(int(round(5.0 * cf)), min_steps), cf, step))
    if "touch" in steps:
        allowed = calibration_touch_points(profile)
        chosen = allowed if touch_points is None else list(touch_points)
        plans = {}
        for side in sk.SIDES:  # a foot's sole outline is touched from one posture, with one hand
            soles = [p for p in chosen if p.startswith("sole_") and p.endswith(side)]
            if soles:
                plan = _touch_plan(perf, profile, soles)
                plans.update({p: plan for p in soles})
        for p in chosen:
            if p not in perf.surface_points or p not in allowed:
                raise BodyCalError(f"unknown touch point '{p}' for the {profile} profile", field="touch_points")
            add(("touch", p), lambda p=p: _touch_clip(perf, profile, p, cf, plans.get(p)))
    motion_list = list(motions or ())
    if motion_list:
        for m in motion_list:
            if m not in MOTIONS:
                raise BodyCalError(f"unknown motion '{m}'", field="motions", hint=f"use {', '.join(MOTIONS)}")
        for m in motion_list:
            cache.setdefault(("motion", m), _motion_clip(perf, m, fps, profile))
        total = 0
        target = None if motion_seconds is None else int(round(motion_seconds * fps))
        i = 0
        while True:
            m = motion_list[i % len(motion_list)]
            clips.append(("motion", m))
            total += cache[("motion", m)].n + n_trans
            i += 1
            if target is None and i >= len(motion_list):
                break
            if target is not None and total >= target:
                break
    add("stand_end", lambda: _posture(perf, max(int(round(0.6 * cf)), 2), 0.0, fingers="relaxed"))

    # Evaluate each distinct clip and transition once; repeats share the arrays.
    results: dict = {}
    seq: list = []
    for i, key in enumerate(clips):
        if i > 0:
            tkey = ("trans", clips[i - 1], key)
            if tkey not in results:
                results[tkey] = _evaluate(perf, _transition(perf, cache[clips[i - 1]], cache[key], n_trans), profile,
                                          roles, marker_names)
            seq.append(tkey)
        if key not in results:
            results[key] = _evaluate(perf, cache[key], profile, roles, marker_names)
        seq.append(key)
    gen = dict(profile=profile, motions=list(motion_list), calibration=calibration, fps=fps, noise_mm=noise_mm,
               wobble_mm=wobble_mm, dropout_rate=dropout_rate, outlier_rate=outlier_rate, seed=seed,
               motion_seconds=motion_seconds, touch_points=None if touch_points is None else list(touch_points),
               pace=pace)
    return _assemble(perf, profile, roles, marker_names, results, seq, cache["tpose"], fps, noise_mm, wobble_mm,
                     dropout_rate, outlier_rate, seed, gen)


def _calibration_steps(profile: str, calibration) -> set[str]:
    every = {"tpose", "stand", "palms_together", "touch", "flex_elbow_l", "flex_elbow_r", "flex_knee_l",
             "flex_knee_r", "swing_shoulder_l", "swing_shoulder_r", "swing_hip_l", "swing_hip_r"}
    if profile == "minimal":  # no gloves, no limb trackers: the AvatarGo steps and touches only
        every = {"tpose", "stand", "touch"}
    if calibration is True:
        return every
    if not calibration:
        return {"tpose"}  # the reference time always exists
    chosen = set(calibration)
    unknown = chosen - every
    if unknown:
        raise BodyCalError(f"steps {sorted(unknown)} are not available in the {profile} profile", field="calibration")
    return chosen | {"tpose"}


def _smooth_noise(rng, n: int, fps: float, dims: int, rms: float) -> np.ndarray:
    """A smooth random signal (n, dims): a few sinusoids of 0.2-1.5 Hz per dimension, with a 3D
    RMS magnitude of `rms` when dims = 3."""
    if rms <= 0 or n == 0:
        return np.zeros((n, dims))
    t = np.arange(n) / fps
    k = 4
    freq = rng.uniform(0.2, 1.5, (k, dims))
    phase = rng.uniform(0, 2 * np.pi, (k, dims))
    amp = rng.uniform(0.5, 1.0, (k, dims))
    sig = np.zeros((n, dims))
    for i in range(k):
        sig += amp[i] * np.sin(2 * np.pi * freq[i] * t[:, None] + phase[i])
    # Each sinusoid's mean square is amp^2 / 2: scale to the requested RMS (per dims as a whole).
    ms = (amp ** 2 / 2).sum(0).sum()
    return sig * (rms / math.sqrt(ms))


def _assemble(perf, profile, roles, marker_names, results, seq, tpose_clip, fps, noise_mm, wobble_mm, dropout_rate,
              outlier_rate, seed, gen):
    parts = [results[k] for k in seq]
    offs = np.cumsum([0] + [p.n for p in parts])
    F = int(offs[-1])
    time = np.arange(F) / fps
    joints = np.concatenate([p.joints for p in parts])
    pos_true = np.concatenate([p.pos for p in parts])
    q_true = np.concatenate([p.quat for p in parts])
    mk_true = np.concatenate([p.markers for p in parts])
    planted_arr = np.concatenate([p.planted for p in parts])
    segments, contacts = [], []
    eff_tracks: dict = {}
    touch_tracks: dict = {}
    ref = None
    miss = max(p.miss for p in parts)
    for o, p in zip(offs[:-1], parts, strict=True):
        for step, f0, f1, point, by in p.segments:
            segments.append(Segment(step, float(time[o + f0]), float(time[o + f1]), point, by))
            if step == "tpose" and ref is None:
                ref = int(o + (f0 + f1) // 2)
        for point, f0, f1, world in p.touches:
            touch_tracks[point] = (np.arange(o + f0, o + f1 + 1), world)
        for motion, eff, target, e, tg, mask in p.contacts:
            frames = np.zeros(F, bool)
            frames[o:o + p.n] = mask
            key = (eff, target)
            if key not in eff_tracks:
                eff_tracks[key] = (np.full((F, 3), np.nan), np.full((F, 3), np.nan))
            eff_tracks[key][0][o:o + p.n] = e
            eff_tracks[key][1][o:o + p.n] = tg
            idx = np.flatnonzero(mask)
            contacts.append({"motion": motion, "effector": eff, "target": target,
                             "start": float(time[o + idx[0]]) if len(idx) else float(time[o]),
                             "end": float(time[o + idx[-1]]) if len(idx) else float(time[o]), "frames": frames})
    # The reference time is the middle frame of the T-pose (FORMATS.md §3); its bone frames are
    # kept for the exact body model.
    mid = (tpose_clip.n - 1) // 2
    sl_ = slice(mid, mid + 1)
    G_ref, H_ref = _fk(perf, tpose_clip.root_pos[sl_], tpose_clip.root_rot[sl_],
                       {k: v[sl_] for k, v in tpose_clip.local.items()})
    del parts
    results.clear()  # the per-clip arrays are all copied by now: free them before the noise stage
    rng = np.random.default_rng([int(seed), 104729])

    # Devices, one at a time (memory stays ~ a few (F, 3, 3) arrays): wobble in the device's own
    # frame, white noise, outliers; gloves are rebuilt from their noisy LEDs.
    D = len(roles)
    pos = np.empty((F, D, 3))
    quat = np.empty((F, D, 4))
    valid = np.ones((F, D), bool)
    markers = mk_true.copy()
    wob_m, noise_m = wobble_mm / 1000.0, noise_mm / 1000.0

    def small_rot(vec):
        ang = np.linalg.norm(vec, axis=-1)
        return _rot(np.where(ang[:, None] > 0, vec, [1.0, 0.0, 0.0]), ang)

    for d, role in enumerate(roles):
        R = quat_to_matrix(q_true[:, d])
        w = _smooth_noise(rng, F, fps, 3, wob_m)
        Rw = small_rot(_smooth_noise(rng, F, fps, 3, wob_m / 0.1))
        if profile == "full" and role.startswith("hand_"):
            # The glove is a rigid LED body: wobble moves its three LEDs together.
            side, origin = role[-1], pos_true[:, d]
            idx = [marker_names.index(f"hand_led{k}_{side}") for k in (1, 2, 3)]
            for m in idx:
                local = _mv(np.swapaxes(R, -1, -2), mk_true[:, m] - origin)
                markers[:, m] = origin + _mv(R, _mv(Rw, local) + w)
                if noise_m > 0:
                    markers[:, m] += rng.normal(0.0, noise_m, (F, 3))
            p, Rn = _led_frame(*(markers[:, m] for m in idx))
        else:
            p = pos_true[:, d] + _mv(R, w)
            Rn = R @ Rw
            if noise_m > 0:
                p = p + rng.normal(0.0, noise_m, (F, 3))
                Rn = Rn @ small_rot(rng.normal(0.0, noise_m / 0.1, (F, 3)))
        if outlier_rate > 0:
            hit = rng.random(F) < outlier_rate
            hit[ref] = False
            k = int(hit.sum())
            p[hit] += normalize(rng.normal(size=(k, 3))) * rng.uniform(0.03, 0.08, (k, 1))
            Rn[hit] = Rn[hit] @ _rot(normalize(rng.normal(size=(k, 3))), rng.uniform(0.05, 0.2, k))
        pos[:, d] = p
        quat[:, d] = matrix_to_quat(Rn)
    fingertips = [m for m, name in enumerate(marker_names) if not name.startswith("hand_led")]
    if noise_m > 0 and fingertips:
        markers[:, fingertips] += rng.normal(0.0, noise_m, (F, len(fingertips), 3))
    mvalid = np.ones((F, len(marker_names)), bool)
    if dropout_rate > 0:
        valid = _dropouts(rng, F, D, dropout_rate, ref)
        mvalid = _dropouts(rng, F, len(marker_names), dropout_rate, ref)
        pos = _hold(pos, valid)
        quat = _hold(quat, valid)
        markers = _hold(markers, mvalid)
    rec = Recording(
        name=f"synthetic-{perf.build}-{profile}-{seed}", time=time,
        devices=[_device(role, profile) for role in roles], positions=pos,
        rotations=quat, valid=valid, marker_names=list(marker_names), markers=markers,
        marker_valid=mvalid, segments=segments, source="synthetic",
        notes=[f"synthetic performer {perf.build}, {perf.height:.2f} m, seed {perf.seed}"])
    planted = {"foot_l": planted_arr[:, 0].copy(), "foot_r": planted_arr[:, 1].copy()}
    truth = GroundTruth(perf, profile, list(roles), list(marker_names), time, ref, joints, pos_true, q_true,
                        mk_true, contacts, planted, segments, eff_tracks, float(miss), gen, touch_tracks, G_ref[0],
                        H_ref[0])
    return rec, truth


def _led_frame(l1, l2, l3):
    """The hand frame from three LEDs (synthetic API): origin = mean, Y = l2 - l1,
    Z = (l2 - l1) x (l3 - l1) re-orthogonalised to Y, X = Y x Z."""
    y = normalize(l2 - l1)
    z = np.cross(l2 - l1, l3 - l1)
    z = normalize(z - (z * y).sum(-1, keepdims=True) * y)
    x = np.cross(y, z)
    return (l1 + l2 + l3) / 3.0, np.stack([x, y, z], -1)


def _dropouts(rng, F, D, rate, ref):
    """Runs of 3-30 invalid frames covering about `rate` of the frames, per device."""
    valid = np.ones((F, D), bool)
    mean_len = 16.5
    for d in range(D):
        k = rng.poisson(rate * F / mean_len)
        if k == 0:
            continue
        starts = rng.integers(0, F, k)
        lens = rng.integers(3, 31, k)
        idx = (starts[:, None] + np.arange(30)[None, :])
        keep = np.arange(30)[None, :] < lens[:, None]
        idx = idx[keep & (idx < F)]
        valid[idx, d] = False
    valid[ref] = True
    valid[0] = True
    return valid


def _hold(arr, valid):
    """Untracked frames repeat the last tracked value (never NaN)."""
    F = len(valid)
    idx = np.where(valid, np.arange(F)[:, None], 0)
    idx = np.maximum.accumulate(idx, axis=0)
    cols = np.arange(valid.shape[1])[None, :]
    return arr[idx, cols]


def _device(role: str, profile: str) -> Device:
    if role == "head":
        return Device("hmd", "hmd", role)
    if role.startswith("hand_"):
        if profile == "full":
            return Device(f"glove_{role[-1]}", "rigid_body", role)
        return Device(f"controller_{role[-1]}", "controller", role)
    return Device(f"tracker_{role}", "tracker", role)


# --- ground truth ------------------------------------------------------------------------------------

@dataclass
class GroundTruth:
    performer: Performer
    profile: str
    roles: list[str]
    marker_names: list[str]
    time: np.ndarray
    ref_frame: int
    joints: np.ndarray  # (F, J, 3) in sk.JOINTS order
    device_positions: np.ndarray  # (F, D, 3) noise-free, wobble-free
    device_rotations: np.ndarray  # (F, D, 4) quaternions w, x, y, z
    markers: np.ndarray  # (F, M, 3) noise-free
    contacts: list[dict]
    planted: dict[str, np.ndarray]
    segments: list[Segment]
    contact_tracks: dict  # (effector, target) -> (effector (F, 3), target (F, 3)), NaN outside their motion
    ik_miss: float  # the largest IK reach shortfall (m); 0 when every pose was reachable
    generator: dict
    touch_tracks: dict  # point -> (frames (k,), true world position of the point (k, 3)) over its touch
    ref_bone_rot: np.ndarray  # (B, 3, 3) bone frames at the reference time (sk.BONES order)
    ref_bone_head: np.ndarray  # (B, 3)

    @property
    def reference_time(self) -> float:
        return float(self.time[self.ref_frame])

    @property
    def joint_tracks(self) -> dict[str, np.ndarray]:
        return {name: self.joints[:, i] for i, name in enumerate(sk.JOINTS)}

    @property
    def joints_world(self) -> dict[str, np.ndarray]:
        return {name: self.joints[self.ref_frame, i].copy() for i, name in enumerate(sk.JOINTS)}

    def device_pose(self, role: str, frame: int | None = None) -> tuple[np.ndarray, np.ndarray]:
        """True (position, rotation matrix) of a device at a frame (default the reference)."""
        f = self.ref_frame if frame is None else frame
        d = self.roles.index(role)
        return self.device_positions[f, d], quat_to_matrix(self.device_rotations[f, d])

    def touch_world(self, point: str) -> np.ndarray:
        """True world position of a surface / touch point at the reference time."""
        bone, local, _ = self.performer.surface_points[point]
        i = _BONE_INDEX[bone]
        return self.ref_bone_head[i] + self.ref_bone_rot[i] @ local

    def body_model(self, name: str | None = None) -> BodyModel:
        """The exact user body model (bodymodel.py contract) at the reference time."""
        return _body_model(self, name or f"truth-{self.performer.build}-{self.profile}")

    def to_dict(self) -> dict:
        def ranges(mask):
            m = np.concatenate([[False], np.asarray(mask, bool), [False]])
            d = np.flatnonzero(np.diff(m.astype(np.int8)))
            return [[int(a), int(b) - 1] for a, b in zip(d[::2], d[1::2], strict=True)]

        return {
            "format": "bodycal-synthetic-truth", "version": 1,
            "performer": self.performer.to_dict(), "profile": self.profile, "generator": self.generator,
            "reference_time": self.reference_time, "reference_frame": self.ref_frame,
            "fps": float(self.generator.get("fps", 0.0)), "frame_count": int(len(self.time)),
            "joints_world": {k: [round(float(x), 7) for x in v] for k, v in self.joints_world.items()},
            "body_model": self.body_model().to_dict(),
            "contacts": [{k: (ranges(v) if k == "frames" else v) for k, v in c.items()} for c in self.contacts],
            "planted": {k: ranges(v) for k, v in self.planted.items()},
            "definitions": {
                "palm_centre": "the hand device frame's origin projected onto the palm plane",
                "fingertip_led": "on the nail side of the fingertip, one finger radius from the tip joint",
                "controller_tip_local": CONTROLLER_TIP_LOCAL.tolist(),
                "frames": "contacts/planted frames are inclusive [first, last] index ranges",
                "joint_tracks": "not stored: regenerate with the generator parameters and the performer seed",
            },
        }

    def save(self, path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(self.to_dict(), indent=1, allow_nan=False))
        return path


def _body_model(truth: GroundTruth, name: str) -> BodyModel:
    perf = truth.performer
    f = truth.ref_frame
    J = truth.joints[f]
    jw = {n: J[i] for i, n in enumerate(sk.JOINTS)}
    roles = set(truth.roles)
    G, Hd = truth.ref_bone_rot, truth.ref_bone_head

    def local_in(role, p):
        pos, R = truth.device_pose(role)
        return R.T @ (p - pos)

    def frames_for(joint):
        s = joint[-1] if joint[-2:] in ("_l", "_r") else None
        base = joint[:-2] if s else joint
        out = []
        if base in ("wrist",) or base.split("_")[0] in sk.FINGER_JOINTS:
            out = [f"hand_{s}"]
        elif base == "elbow":
            out = [f"forearm_{s}" if f"forearm_{s}" in roles else f"hand_{s}", f"upperarm_{s}"]
        elif base == "shoulder":
            out = [f"upperarm_{s}", "chest" if "chest" in roles else "pelvis"]
        elif base == "knee":
            out = [f"shin_{s}" if f"shin_{s}" in roles else f"foot_{s}", f"thigh_{s}"]
        elif base == "hip":
            out = [f"thigh_{s}", "pelvis"]
        elif base in ("ankle", "toe"):
            out = [f"foot_{s}"]
        elif base in ("pelvis", "spine_root"):
            out = ["pelvis"]
        elif base in ("skull_base", "head"):
            out = ["head"]
        return [r for r in out if r in roles]

    hand_ext = {}
    for s in sk.SIDES:  # extended-finger joints in the hand device frame (rest geometry of the hand)
        hb = _BONE_INDEX[f"hand_{s}"]
        Rr, hr = perf.rest_rot[hb], perf.rest_head[hb]
        for fg in sk.FINGERS:
            for jn in sk.FINGER_JOINTS:
                nm = f"{jn}_{fg}_{s}"
                hand_ext[nm] = Hd[hb] + G[hb] @ (Rr.T @ (perf.rest[nm] - hr))
    joints = {}
    for jn in sk.JOINTS:
        fr = frames_for(jn)
        frames = {r: local_in(r, hand_ext.get(jn, jw[jn])) for r in fr}
        joints[jn] = Joint(jw[jn].copy(), fr[0] if fr else None, frames[fr[0]] if fr else None, frames)
    bones = {}
    for i, b in enumerate(sk.BONES):
        radii = perf.bone_radii(b.name)
        extra = {}
        if b.name.startswith(("forearm_", "shin_")):
            s = b.name[-1]
            role = (f"forearm_{s}" if f"forearm_{s}" in roles else f"hand_{s}") if b.name.startswith("forearm") \
                else (f"shin_{s}" if f"shin_{s}" in roles else f"foot_{s}")
            if role in roles:
                _, R = truth.device_pose(role)
                extra = {"right_local": [round(float(x), 7) for x in R.T @ G[i][:, 0]], "right_frame": role}
        bones[b.name] = BoneInfo(b.head, b.tail, float(perf.length[i]), G[i][:, 0].copy(),
                                 radii[0] if radii else None, radii[1] if radii else None, extra)
    surface = [SurfaceElement(f"capsule:{b}", "capsule", b) for b in sl.CAPSULE_BONES]
    surface.append(SurfaceElement("sphere:skull", "sphere", "head", perf.skull_center.copy(), perf.skull_radius))
    sp = perf.surface_points
    surface.append(SurfaceElement("mesh:torso", "mesh", "spine_*",
                                  points={k: SurfacePoint(sp[k][0], sp[k][1].copy()) for k in sl.TORSO_POINTS},
                                  triangles=list(sl.TORSO_TRIANGLES)))
    surface.append(SurfaceElement("mesh:jaw", "mesh", "head",
                                  points={k: SurfacePoint("head", sp[k][1].copy()) for k in sl.JAW_POINTS},
                                  triangles=list(sl.JAW_TRIANGLES)))
    for part in ("palm", "sole"):
        for s in sk.SIDES:
            names = (sl.palm_points if part == "palm" else sl.sole_points)(4, s)
            bone = f"{'hand' if part == 'palm' else 'foot'}_{s}"
            surface.append(SurfaceElement(f"mesh:{part}_{s}", "mesh", bone,
                                          points={k: SurfacePoint(bone, sp[k][1].copy()) for k in names},
                                          triangles=sl.fan_triangles(names)))
    extra = {"tpose": {}, "eye_height": float((Hd[_BONE_INDEX["head"]] + G[_BONE_INDEX["head"]] @ perf.eye_local)[2]),
             "palm_planes": {}}
    for role in truth.roles:
        p, R = truth.device_pose(role)
        extra["tpose"][role] = [round(float(x), 7) for x in np.concatenate([p, matrix_to_quat(R)])]
    for s in sk.SIDES:
        role = f"hand_{s}"
        if role not in roles:
            continue
        hb = _BONE_INDEX[role]
        p, R = truth.device_pose(role)
        g = perf.hand[s]
        pt_world = Hd[hb] + G[hb] @ np.array([0.0, 0.0, g["zp"]])
        n_world = G[hb][:, 2]
        pt = R.T @ (pt_world - p)
        nrm = R.T @ n_world
        pt = (pt @ nrm) * nrm  # the device origin projected onto the plane: the palm centre
        extra["palm_planes"][role] = {"point": [round(float(x), 7) for x in pt],
                                      "normal": [round(float(x), 7) for x in nrm]}
    model = BodyModel("user", name, joints, bones, surface, truth.reference_time, {},
                      {"steps_used": ["synthetic ground truth"], "defaulted": {}, "missing": [], "quality": {}}, extra)
    return model


def write_session(directory, name: str, rec: Recording, truth: GroundTruth) -> tuple[Path, Path]:
    """Write `<name>.bcrec.json` (FORMATS.md §2.1, via recording/io) and `<name>.truth.json`."""
    from bodycal_addon.recording import io as recording_io

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    rec_path = directory / f"{name}.bcrec.json"
    truth_path = directory / f"{name}.truth.json"
    recording_io.save_recording(rec, rec_path)
    truth.save(truth_path)
    return rec_path, truth_path
