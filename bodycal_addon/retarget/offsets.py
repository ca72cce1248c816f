"""The `offsets` method: AvatarGo's exact tracker-to-joint offsets (AvatarGo, §3.3-3.4) + IK.

At the T-pose (the user model's reference time) the avatar, scaled uniformly by the eye-height
ratio and placed in the user's T-pose, gives for every tracked joint J and its tracker T the offset
v0(TJ) = p0(J) - p0(T) and the rotations R0(T), R0(J). Then, per frame:
    p_t(J) = p_t(T) + R_t(T) R_0(T)^-1 v_0(TJ)        (eq. 2)
    R_t(J) = R_t(T) R_0(T)^-1 R_0(J)                  (eq. 3)
for the root (pelvis tracker -> sacrum), the ankles (foot trackers -> feet) and the head (HMD).
Hands (§3.4, "Hands"): "the wrist joint is computed so that the center of the controller always
appears under the palm (keeping an exact offset between the palm and the wrist joint)": the hand
turns by eq. 3 and the wrist is the controller minus the palm's offset in that hand, the
controller's centre being where the finger grip below models it (`controller_capsule`). Not the
T-pose offset of eq. 2: that one carries the avatar's and the user's arm length difference, which
swings the wrist on a lever far longer than the hand at every turn of the controller (it put the
controller beyond a long-armed avatar's fingers). The spine bends by the angle between w0 and w_t (root
to head, eq. 1, 4); limbs reach their effectors by two-bone IK; fingers close on the controller by
gradient descent of the capsule SDF (eq. 5-7). Positions are computed at the user's scale and then
brought back to the avatar's own size (divided by the eye-height ratio) about the floor point
where the user stood at the T-pose (`avatar_pose.root_centre`), so the result moves with the
recording.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..body import skeleton as sk
from ..body.bodymodel import BodyModel
from ..body.rest_frames import complete_joints
from ..body.skeleton import BONE_INDEX as BI
from ..body.skeleton import JOINT_INDEX as JI
from ..body.skeleton import SPINE_BONES
from ..core import one_frame
from ..core.errors import BodyCalError
from ..core.transforms import EPS, normalize, quat_between, quat_to_matrix, stack_apply
from . import pose_kernels
from .avatar_pose import AvatarRig, copy_frames
from .user_animation import axis_angle_matrix

TRACKED = {  # joint -> (tracker role, canonical bone whose rotation follows eq. 3)
    "pelvis": ("pelvis", "sacrum"),
    "skull_base": ("head", "head"),
    "wrist_l": ("hand_l", "hand_l"), "wrist_r": ("hand_r", "hand_r"),
    "ankle_l": ("foot_l", "foot_l"), "ankle_r": ("foot_r", "foot_r"),
}

# Controller as a capsule in the avatar's hand frame (AvatarGo, eq. 5): along the palm's lateral
# axis, under the palm centre. Metres at the avatar's scale are derived from its hand length.
CONTROLLER_RADIUS_OF_HAND = 0.22  # radius / hand length (wrist -> middle base)
CONTROLLER_LENGTH_OF_HAND = 1.0
FINGER_ITERATIONS = 24
FINGER_RATE = 0.5
PENALTY_INSIDE = 4.0


def eye_height(model: BodyModel) -> float:
    eh = model.extra.get("eye_height")
    if eh:
        return float(eh)
    pos = complete_joints(model)
    # eyes ~ 0.6 of the way from the skull base to the top of the head joint
    return float(pos["skull_base"][2] + 0.6 * (pos["head"][2] - pos["skull_base"][2]))


@dataclass
class OffsetsSetup:
    scale: float  # user eye height / avatar eye height
    v0: dict[str, np.ndarray]  # joint -> (3,) world, user scale
    r0_tracker: dict[str, np.ndarray]  # role -> (3, 3)
    r0_joint: dict[str, np.ndarray]  # canonical bone -> (3, 3)
    w0: np.ndarray  # (3,) root -> head at the T-pose (tracker positions)
    spine0: np.ndarray  # (12, 3, 3) vertebra frames at the T-pose
    pelvis0: np.ndarray  # (3,) avatar pelvis at the T-pose (user scale)
    ref_frames: np.ndarray  # (B, 3, 3) the canonical frames copied onto the avatar at the T-pose
    centre: np.ndarray  # (3,) the floor point the user-scale positions are scaled about
    palm: dict[str, np.ndarray]  # wrist -> (3,) the controller's centre from the wrist, canonical hand frame


def setup(user_model: BodyModel, rig: AvatarRig, ref_frames: np.ndarray, tpose: dict[str, tuple],
          centre: np.ndarray) -> OffsetsSetup:
    """Offsets at the T-pose: `ref_frames` (B, 3, 3) the user's canonical frames at the reference
    time (the avatar is posed with them), `tpose` {role: (position (3,), rotation (3, 3))},
    `centre` the floor point the scaling is about."""
    for role, _ in TRACKED.values():
        if role not in tpose:
            raise BodyCalError(f"no T-pose for the '{role}' device", source=user_model.name, field="extra.tpose",
                               hint="calibrate the user from a recording with a tpose step")
    s = eye_height(user_model) / eye_height(rig.model)
    user_pos = complete_joints(user_model)
    # The avatar in the user's T-pose: the user's reference frames, pelvis over the user's pelvis,
    # feet on the floor at the avatar's own scale; then scaled by s about the centre.
    centre = np.asarray(centre, float)
    rest_pel = rig.joint_world[JI["pelvis"]]
    pel = np.array([*(centre[:2] + (user_pos["pelvis"][:2] - centre[:2]) / s), rest_pel[2]])
    ref = copy_frames(ref_frames[None], ref_frames, rig.frames0)[0]  # step 2's copy at the T-pose
    pose = rig.solve(ref[None], pel[None], float64=True)  # the bake's constants: numpy's values
    joints0 = centre + (pose.joints[0] - centre) * s
    frames0 = pose.frames[0]
    v0, r0t, r0j = {}, {}, {}
    for j, (role, bone) in TRACKED.items():
        p_t, r_t = tpose[role]
        v0[j] = joints0[JI[j]] - p_t
        r0t[role] = r_t
        r0j[bone] = frames0[BI[bone]]
    w0 = tpose["head"][0] - tpose["pelvis"][0]
    spine0 = frames0[[BI[b] for b in SPINE_BONES]]
    palm = {f"wrist_{side}": controller_in_hand(rig, side) for side in sk.SIDES}
    return OffsetsSetup(s, v0, r0t, r0j, w0, spine0, joints0[JI["pelvis"]], ref, centre, palm)


def effector_targets(st: OffsetsSetup, trackers):
    """Eq. 2-3 per frame of `trackers` (trackers.Trackers): ({joint: (F, 3) at the AVATAR's
    scale}, {bone: (F, 3, 3)}). One frame: `_effector_targets_one`."""
    pos, rot = trackers.pos, trackers.rot
    if len(next(iter(pos.values()))) == 1 and one_frame.ENABLED and trackers.rotations is not None:
        return _effector_targets_one(st, trackers)
    p, r = {}, {}
    for j, (role, bone) in TRACKED.items():
        rel = rot[role] @ st.r0_tracker[role].T  # R_t(T) R_0(T)^-1
        r[bone] = rel @ st.r0_joint[bone]
        if j in st.palm:  # §3.4 Hands: the controller's centre under the palm
            p[j] = st.centre + (pos[role] - st.centre) / st.scale - stack_apply(r[bone], st.palm[j])
        else:
            p[j] = st.centre + (pos[role] + rel @ st.v0[j] - st.centre) / st.scale
    return p, r


def _one_constants(st: OffsetsSetup) -> dict:
    """`st`'s constants stacked for one frame's kernels, once: the tracked joints, their roles and
    bones (TRACKED's order), R_0(T)^-1 and R_0(J) (6, 3, 3), each joint's lever (6, 3, 1) that
    R_t(T) R_0(T)^-1 turns (v0 / s, or the palm's -R_0(J) palm: eq. 3's hand turns it), the
    centre's part of the scaling c (1 - 1/s), d_sac's right factor, w0 and the T-pose vertebrae."""
    got = st.__dict__.get("_one")
    if got is None:
        inv = 1.0 / st.scale
        lever = [-(st.r0_joint[bone] @ st.palm[j]) if j in st.palm else st.v0[j] * inv
                 for j, (_, bone) in TRACKED.items()]
        n = len(SPINE_BONES)
        got = st.__dict__["_one"] = {
            "joints": list(TRACKED), "roles": [r for r, _ in TRACKED.values()],
            "bones": [b for _, b in TRACKED.values()],
            "r0t_inv": np.stack([st.r0_tracker[r].T for r, _ in TRACKED.values()]),
            "r0j": np.stack([st.r0_joint[b] for _, b in TRACKED.values()]),
            "lever": np.stack(lever)[..., None], "inv": inv, "shift": st.centre * (1.0 - inv),
            "sac_fixed": st.r0_joint["sacrum"].T, "w0": st.w0, "spine0": st.spine0,
            "frac": (np.arange(n) + 1.0) / n, "rows": {}}
    return got


def _effector_targets_one(st: OffsetsSetup, trackers):
    """`effector_targets` of one frame: the six trackers' products stacked (a few numpy calls
    whatever the count, float64: the bake's values to their sums' rounding): the frames
    R_t(T) R_0(T)^-1 R_0(J), the points x / s + c (1 - 1/s) + R_t(T) R_0(T)^-1 lever (eq. 2 scaled
    about the centre; the hands' §3.4 palm offset, -R_t(J) palm, the same product).
    Decision (speed, measured in instructions): the mathutils kernel it replaced made a Matrix of
    each rotation and read six frames back (Matrix <-> numpy, about 5,000 instructions a
    matrix each way): 232,000 instructions a frame against 109,000 here."""
    one = _one_constants(st)
    rows = one["rows"].get(trackers.roles)  # the six trackers' rows among those read, per roles read
    if rows is None:
        rows = one["rows"][trackers.roles] = np.array([trackers.roles.index(r) for r in one["roles"]], int)
    rel = np.matmul(trackers.rotations.take(rows, axis=0)[:, 0], one["r0t_inv"])  # R_t(T) R_0(T)^-1
    R = np.matmul(rel, one["r0j"])[:, None]  # (6, 1, 3, 3)
    P = trackers.positions.take(rows, axis=0) * one["inv"] + one["shift"]  # (6, 1, 3)
    P += np.matmul(rel, one["lever"]).swapaxes(1, 2)
    return dict(zip(one["joints"], P)), dict(zip(one["bones"], R))


def spine_frames(st: OffsetsSetup, pos: dict[str, np.ndarray], sacrum: np.ndarray) -> np.ndarray:
    """Vertebra frames (F, 12, 3, 3): the T-pose spine turned with the sacrum, then bent by the
    angle between w0 and w_t (eq. 4), spread evenly over the vertebrae. One frame: the same in a
    few numpy calls and Python floats (`_spine_frames_one`)."""
    if len(sacrum) == 1 and one_frame.ENABLED:
        return _spine_frames_one(st, pos, sacrum)
    d_sac = sacrum @ st.r0_joint["sacrum"].T
    w0 = np.einsum("fij,j->fi", d_sac, st.w0)
    wt = pos["head"] - pos["pelvis"]
    q = quat_between(w0, wt)
    angle = 2 * np.arctan2(np.linalg.norm(q[..., 1:], axis=-1), q[..., 0])
    axis = normalize(q[..., 1:])
    n = len(SPINE_BONES)
    frac = (np.arange(n) + 1) / n
    half = 0.5 * angle[:, None] * frac  # (F, n): vertebra k turns by (k + 1) / n of the bend
    qk = np.concatenate([np.cos(half)[..., None], np.sin(half)[..., None] * axis[:, None]], -1)
    return quat_to_matrix(qk) @ d_sac[:, None] @ st.spine0


def _spine_frames_one(st: OffsetsSetup, pos: dict[str, np.ndarray], sacrum: np.ndarray) -> np.ndarray:
    """`spine_frames` of one frame, float64: the bend w0 -> w_t as `quat_between`'s shortest turn
    (its half turn for opposite directions) in Python floats, then every vertebra's share a_k of
    it at once, R_k D = D + sin a_k K D + (1 - cos a_k) K^2 D (Rodrigues on the sacrum's turn D; K
    the axis's cross-product matrix): ONE product of the shares' (1, sin, 1 - cos) rows by
    [D, K D, K^2 D], then each by its T-pose frame: the bake's values to their sums' rounding.
    Decision (speed, measured in instructions): the mathutils kernel it replaced read its twelve
    frames back from Matrices (about 10,000 instructions each): 216,000 instructions a frame
    against 133,000 here."""
    one = _one_constants(st)
    D = np.matmul(sacrum[0], one["sac_fixed"])
    head, pel = pos["head"][0].tolist(), pos["pelvis"][0].tolist()
    axis_angle = _turn_between(np.matmul(D, one["w0"]).tolist(), [head[0] - pel[0], head[1] - pel[1], head[2] - pel[2]])
    if axis_angle is None:  # no bend: the sacrum's turn alone
        return pose_kernels.few_matmul(D, one["spine0"], one["spine0"].shape)[None]
    (x, y, z), angle = axis_angle
    (d00, d01, d02), (d10, d11, d12), (d20, d21, d22) = D.tolist()
    k00, k01, k02 = y * d20 - z * d10, y * d21 - z * d11, y * d22 - z * d12  # K D: axis x D's columns
    k10, k11, k12 = z * d00 - x * d20, z * d01 - x * d21, z * d02 - x * d22
    k20, k21, k22 = x * d10 - y * d00, x * d11 - y * d01, x * d12 - y * d02
    terms = np.array([[d00, d01, d02, d10, d11, d12, d20, d21, d22], [k00, k01, k02, k10, k11, k12, k20, k21, k22],
                      [y * k20 - z * k10, y * k21 - z * k11, y * k22 - z * k12,  # K^2 D: axis x (K D)'s columns
                       z * k00 - x * k20, z * k01 - x * k21, z * k02 - x * k22,
                       x * k10 - y * k00, x * k11 - y * k01, x * k12 - y * k02]])
    shares = np.empty((len(one["frac"]), 3))
    shares[:, 0] = 1.0
    a = one["frac"] * angle
    np.sin(a, out=shares[:, 1])
    np.subtract(1.0, np.cos(a), out=shares[:, 2])
    turned = np.matmul(shares, terms).reshape(-1, 3, 3)
    return pose_kernels.few_matmul(turned, one["spine0"], turned.shape)[None]


def _turn_between(a: tuple, b: tuple):
    """`quat_between(a, b)`'s turn as (unit axis, angle), in Python floats (three components each);
    None where it is no turn (a vector without length or parallel ones)."""
    na, nb = math.sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]), math.sqrt(b[0] * b[0] + b[1] * b[1] + b[2] * b[2])
    if na <= EPS or nb <= EPS:
        return None
    a0, a1, a2 = a[0] / na, a[1] / na, a[2] / na
    b0, b1, b2 = b[0] / nb, b[1] / nb, b[2] / nb
    d = a0 * b0 + a1 * b1 + a2 * b2
    if d < -1.0 + 1e-9:  # opposite: a half turn about a perpendicular (quat_between's)
        p = (0.0, a2, -a1)  # a x (1, 0, 0)
        if math.sqrt(p[1] * p[1] + p[2] * p[2]) < 1e-6:
            p = (-a2, 0.0, a0)  # a x (0, 1, 0)
        n = math.sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2])
        return (p[0] / n, p[1] / n, p[2] / n), math.pi
    c0, c1, c2 = a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0
    s = math.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
    if s <= EPS:
        return None
    return (c0 / s, c1 / s, c2 / s), 2.0 * math.atan2(s, 1.0 + d)


def capsule_sdf(p, s, e, r):
    """AvatarGo, eq. 5: |v1 - v2 h| - r, h = clamp(v1.v2 / v2.v2, 0, 1)."""
    v1, v2 = p - s, e - s
    h = np.clip((v1 * v2).sum(-1) / np.maximum((v2 * v2).sum(-1), EPS), 0.0, 1.0)
    return np.linalg.norm(v1 - v2 * h[..., None], axis=-1) - r


def controller_capsule(rig: AvatarRig, side: str) -> tuple[np.ndarray, np.ndarray, float]:
    """The controller held in the avatar's hand at rest (AvatarGo, eq. 5): (centre (3,), half its
    axis (3,), radius), world: across the palm, under it, sized by the hand (wrist -> middle base)."""
    pos = {j: rig.joint_world[JI[j]] for j in (f"wrist_{side}", f"mcp_middle_{side}")}
    f0 = rig.frames0
    wrist = pos[f"wrist_{side}"]
    hand_len = np.linalg.norm(pos[f"mcp_middle_{side}"] - wrist)
    # Palm side: the fingers flex about +X toward +Z of their frames.
    palm_dir = f0[BI[f"middle_1_{side}"]][:, 2]
    r = CONTROLLER_RADIUS_OF_HAND * hand_len
    centre = wrist + 0.6 * (pos[f"mcp_middle_{side}"] - wrist) + palm_dir * (r + 0.02 * hand_len)
    return centre, f0[BI[f"hand_{side}"]][:, 0] * CONTROLLER_LENGTH_OF_HAND * hand_len / 2, float(r)


def controller_in_hand(rig: AvatarRig, side: str) -> np.ndarray:
    """(3,) the controller's centre from the wrist, in the canonical hand frame."""
    centre, _, _ = controller_capsule(rig, side)
    return rig.frames0[BI[f"hand_{side}"]].T @ (centre - rig.joint_world[JI[f"wrist_{side}"]])


def grip_fingers(rig: AvatarRig, side: str) -> dict[str, np.ndarray]:
    """Closed-on-the-controller finger frames in the HAND frame (canonical bone -> (3, 3)),
    by gradient descent on the interpolation factors t in [0, 1] between the open (rest) and the
    closed (90° per joint) finger (AvatarGo, eq. 6-7, numerical gradient, penalty inside). The
    controller is rigid in the hand, so one solve serves every frame."""
    pos = {j: rig.joint_world[JI[j]] for j in sk.JOINTS}
    f0 = rig.frames0
    hand = f0[BI[f"hand_{side}"]]
    hand_len = np.linalg.norm(pos[f"mcp_middle_{side}"] - pos[f"wrist_{side}"])
    centre, lat, r = controller_capsule(rig, side)
    s_, e_ = centre - lat, centre + lat
    fingers = list(sk.FINGERS)
    chains = []
    for f in fingers:
        names = [f"{j}_{f}_{side}" for j in sk.FINGER_JOINTS]
        lens = np.array([np.linalg.norm(pos[names[i + 1]] - pos[names[i]]) for i in range(3)])
        frames = np.stack([f0[BI[f"{f}_{i}_{side}"]] for i in (1, 2, 3)])
        chains.append((pos[names[0]], lens, frames))
    mcp = np.stack([c[0] for c in chains])  # (5, 3)
    lens = np.stack([c[1] for c in chains])  # (5, 3)
    fr = np.stack([c[2] for c in chains])  # (5, 3, 3, 3)

    def finger_points(t):  # t (..., 5, 3) -> joint points (..., 5, 3, 3) and frames
        rot = np.broadcast_to(np.eye(3), t.shape[:-1] + (3, 3))
        p = np.broadcast_to(mcp, t.shape[:-1] + (3,))
        pts, frames = [], []
        for i in range(3):
            axis = fr[:, i, :, 0]
            ang = t[..., i] * (np.pi / 2)
            rot = axis_angle_matrix(np.broadcast_to(axis, ang.shape + (3,)), ang) @ rot
            f_i = rot @ fr[:, i]
            frames.append(f_i)
            p = p + f_i[..., :, 1] * lens[..., i:i + 1]
            pts.append(p)
        return np.stack(pts, -2), np.stack(frames, -3)

    def cost(t):
        pts, _ = finger_points(t)
        d = capsule_sdf(pts, s_, e_, r)
        return np.where(d < 0, -PENALTY_INSIDE * d, d).sum(-1)  # (..., 5)

    t = np.zeros((5, 3))
    eps = 1e-3
    for _ in range(FINGER_ITERATIONS):
        grad = np.empty_like(t)
        base = cost(t)
        for i in range(3):
            tp = t.copy()
            tp[:, i] += eps
            grad[:, i] = (cost(tp) - base) / eps
        t = np.clip(t - FINGER_RATE * grad / max(hand_len, 1e-6), 0.0, 1.0)
    _, frames = finger_points(t)
    out = {}
    for fi, f in enumerate(fingers):
        for i in (1, 2, 3):
            out[f"{f}_{i}_{side}"] = hand.T @ frames[fi, i - 1]  # in the hand frame
    return out
