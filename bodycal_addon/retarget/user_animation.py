"""Step 1 of the pipeline (DESIGN.md §1, §6; Delahaye 2023, appendix D): the user's canonical skeleton
animated from the trackers, vectorised over frames.

- Limbs: every joint from its calibrated locals in each tracker it is known in
  (`Joint.frames`); the intermediate joint (elbow, knee) is the mean of its positions from both
  adjacent trackers; the effector (wrist, ankle) only from its own frame; the anchored and
  intermediate bones then simply join these points (they are "scaled to meet") and keep the hinge's
  local right (`bones[hinge].extra["right_local"]` in `right_frame`), so they never twist.
- Fingers: from the fingertip markers (`<finger>_tip_<s>`) with the flexion equation and the
  yaw/pitch realignment (`fingers.pose_finger`); without markers the fingers stay as calibrated.
- Trunk: sacrum rigid on the pelvis tracker, its lateral direction and origin averaged with the hip
  line (appendix D "Trunk animation"); spine aimed at the skull base carried by the HMD
  (`ik.spine`); clavicles from vertebra 5 to the shoulders; head rigid on the HMD.
- Dropouts: a device's invalid frames hold its last valid pose (forward fill; leading gaps take
  the first valid pose) and `UserPose.valid` says which frames had every device.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..body import skeleton as sk
from ..body.bodymodel import BodyModel
from ..body.rest_frames import complete_joints, model_rest_frames
from ..body.skeleton import BONE_INDEX as BI
from ..body.skeleton import BONES, JOINTS, SPINE_BONES, SPINE_JOINTS
from ..body.skeleton import JOINT_INDEX as JI
from ..calibration.coverage import ANIMATED_ROLES
from ..core.errors import BodyCalError
from ..core.geometry import two_bone_mid
from ..core.transforms import (
    frame_from_axes,
    normalize,
    quat_between,
    quat_normalize,
    quat_to_matrix,
    stack_apply,
    stack_mul,
)
from ..recording.model import ROLES_LIST, Recording
from . import fingers, ik

LIMB_SEGMENTS = {  # side-less limb: (anchor, intermediate, effector, anchored bone, intermediate bone)
    "arm": ("shoulder", "elbow", "wrist", "upperarm", "forearm"),
    "leg": ("hip", "knee", "ankle", "thigh", "shin"),
}


@dataclass
class UserPose:
    time: np.ndarray  # (F,)
    joints: np.ndarray  # (F, J, 3) canonical joints (skeleton.JOINTS order), world
    frames: np.ndarray  # (F, B, 3, 3) canonical bone frames (skeleton.BONES order), world
    valid: np.ndarray  # (F,) every device used was tracked this frame
    notes: list[str] = field(default_factory=list)
    # (F, B, 3, 3) the frames the body's surface rides on, when not `frames` (an animated
    # character's vertebrae: rigid on its spine bones, pose_source.AnimationSource)
    surface_frames: np.ndarray | None = None

    def joint(self, name: str) -> np.ndarray:
        return self.joints[:, JI[name]]

    def take(self, start: int, stop: int) -> UserPose:
        s = slice(start, stop)
        return UserPose(self.time[s], self.joints[s], self.frames[s], self.valid[s], self.notes)


def forward_fill(valid: np.ndarray) -> np.ndarray:
    """(F,) index of the frame whose value to use: the last valid one (leading gaps: the first)."""
    f = len(valid)
    idx = np.where(valid, np.arange(f), -1)
    idx = np.maximum.accumulate(idx)
    first = int(np.argmax(valid)) if valid.any() else 0
    return np.where(idx < 0, first, idx)


@dataclass
class Trackers:
    pos: dict[str, np.ndarray]  # role -> (F, 3)
    rot: dict[str, np.ndarray]  # role -> (F, 3, 3)
    ref_rot: dict[str, np.ndarray]  # role -> (3, 3) at the reference time
    valid: np.ndarray  # (F,)
    notes: list[str]


def read_trackers(recording: Recording, model: BodyModel, start: int = 0, stop: int | None = None) -> Trackers:
    """The tracked devices of frames [start, stop) by role: positions, rotations, their rotations at
    the reference (T-pose) time, which frames every device tracked, and notes on devices never or
    partly tracked (their untracked frames hold the last valid pose)."""
    stop = recording.frame_count if stop is None else stop
    pos, rot, ref_rot, notes = {}, {}, {}, []
    valid_all = np.ones(stop - start, bool)
    tpose = model.extra.get("tpose") or {}
    ref_frame = None
    if model.reference_time is not None and recording.frame_count:
        ref_frame = int(np.clip(np.searchsorted(recording.time, model.reference_time), 0, recording.frame_count - 1))
    for d_i, dev in enumerate(recording.devices):
        role = dev.role
        if role is None or role in pos:
            continue
        v_full = recording.valid[:, d_i]
        if not v_full.any():
            notes.append(f"{role}: never tracked, ignored")
            continue
        idx_full = forward_fill(v_full)
        idx = idx_full[start:stop]
        v = v_full[start:stop]
        p = recording.positions[idx, d_i]
        q = quat_normalize(recording.rotations[idx, d_i])
        pos[role], rot[role] = p, quat_to_matrix(q)
        valid_all &= v
        if (~v).any():
            notes.append(f"{role}: {int((~v).sum())} frames without tracking held at the last valid pose")
        if role in tpose:
            ref_rot[role] = quat_to_matrix(quat_normalize(np.asarray(tpose[role][3:7], float)))
        elif ref_frame is not None:
            ref_rot[role] = quat_to_matrix(quat_normalize(recording.rotations[idx_full[ref_frame], d_i]))
    return Trackers(pos, rot, ref_rot, valid_all, notes)


def joint_from_trackers(model: BodyModel, tr: Trackers, joint: str, roles: list[str] | None = None):
    """Mean position of `joint` over the trackers it is known in (restricted to `roles`)."""
    j = model.joints.get(joint)
    if j is None:
        return None
    ests = [tr.pos[r] + stack_apply(tr.rot[r], np.asarray(loc, float)) for r, loc in j.frames.items()
            if r in tr.pos and (roles is None or r in roles)]
    if not ests:
        return None
    return ests[0] if len(ests) == 1 else np.mean(ests, axis=0)


def _own_frame(model: BodyModel, joint: str, tr: Trackers):
    """Position of an effector joint from its own (first) tracker only."""
    j = model.joints.get(joint)
    if j is None:
        return None
    for r in j.frames:
        if r in tr.pos:
            return joint_from_trackers(model, tr, joint, [r])
    return None


def _rigid(tr: Trackers, role: str, frame0: np.ndarray):
    """A bone frame rigid on a tracker: R_T(t) R_T0^-1 C0."""
    return stack_mul(tr.rot[role], tr.ref_rot[role].T @ frame0)


def _hinge_right(model: BodyModel, tr: Trackers, bone: str, fallback: np.ndarray) -> np.ndarray:
    info = model.bones.get(bone)
    ex = info.extra if info is not None else {}
    role = ex.get("right_frame")
    if role in tr.rot and ex.get("right_local") is not None:
        return stack_apply(tr.rot[role], normalize(np.asarray(ex["right_local"], float)))
    for r in ("forearm", "shin", "hand", "foot"):  # the rest right carried by the intermediate tracker
        role = f"{r}_{bone.rsplit('_', 1)[-1]}"
        if role in tr.rot and role in tr.ref_rot and info is not None and info.right is not None:
            return stack_apply(tr.rot[role], tr.ref_rot[role].T @ info.right)
    return fallback


@dataclass
class _Animating:
    """What the passes of `animate_user` share: the recording's frames [start, stop), the user
    model and its trackers, its rest joints and rest bone frames `C0` (B, 3, 3), and what the passes
    fill: joint positions `P` (name -> (F, 3)) and bone frames `Fr` (F, B, 3, 3)."""

    recording: Recording
    model: BodyModel
    tr: Trackers
    rest_pos: dict[str, np.ndarray]
    C0: np.ndarray
    start: int
    stop: int
    Fr: np.ndarray
    P: dict[str, np.ndarray] = field(default_factory=dict)

    def need(self, joint: str, value):
        """`value`, or one error when no tracked device knows `joint`."""
        if value is None:
            raise BodyCalError(f"joint '{joint}' is not known in any tracked device", source=self.model.name,
                               field=f"joints.{joint}.frames", hint="calibrate the user with these trackers")
        return value


def animate_user(recording: Recording, user_model: BodyModel, start: int = 0, stop: int | None = None, *,
                 rest: tuple[dict, np.ndarray] | None = None) -> UserPose:
    """Animate the user's canonical skeleton over frames [start, stop) of `recording`. `rest`: the
    model's (complete_joints, model_rest_frames), when the caller animates it chunk by chunk."""
    if user_model.kind != "user":
        raise BodyCalError(f"expected a user body model, got kind '{user_model.kind}'", source=user_model.name)
    stop = recording.frame_count if stop is None else stop
    tr = read_trackers(recording, user_model, start, stop)
    src = recording.source or recording.name
    _check_trackers(tr, src, user_model)
    if rest is None:
        rest_pos = complete_joints(user_model)
        rest = rest_pos, model_rest_frames(user_model, rest_pos)
    rest_pos, C0 = rest
    an = _Animating(recording, user_model, tr, rest_pos, C0, start, stop, np.empty((stop - start, len(BONES), 3, 3)))
    sacrum, pelvis_rigid = _animate_head(an)
    _animate_limbs(an)
    _animate_trunk(an, sacrum, pelvis_rigid)
    _animate_hands(an)
    pos = np.stack([an.P[j] for j in JOINTS], axis=1)
    _shortcut_frames(an)
    if not np.all(np.isfinite(pos)) or not np.all(np.isfinite(an.Fr)):
        raise BodyCalError("the user animation has non-finite values", source=src,
                           hint="check the recording for broken device poses")
    return UserPose(recording.time[start:stop], pos, an.Fr, tr.valid, tr.notes)


def _check_trackers(tr: Trackers, src: str, user_model: BodyModel) -> None:
    """Refuses a recording without the six devices every method needs, or a model without their
    reference poses."""
    for role in ANIMATED_ROLES:
        if role not in tr.pos:
            raise BodyCalError(f"no tracked device with role '{role}'", source=src, field="devices",
                               hint=f"assign device roles ({ROLES_LIST}) or record with the HMD, both hands, "
                                    "pelvis and both feet")
        if role not in tr.ref_rot:
            raise BodyCalError(f"no reference pose for '{role}' (body model extra.tpose)", source=user_model.name,
                               field="extra.tpose", hint="calibrate the user from this recording")


def _animate_head(an: _Animating) -> tuple[np.ndarray, np.ndarray]:
    """Head pass: skull base, head and the head frame rigid on the HMD. Returns the sacrum frame
    rigid on the pelvis tracker and the pelvis joint from that tracker, for `_animate_trunk`."""
    for j in ("skull_base", "head"):
        an.P[j] = an.need(j, joint_from_trackers(an.model, an.tr, j, ["head"]))
    an.Fr[:, BI["head"]] = _rigid(an.tr, "head", an.C0[BI["head"]])
    sac = _rigid(an.tr, "pelvis", an.C0[BI["sacrum"]])
    pel_rigid = an.need("pelvis", joint_from_trackers(an.model, an.tr, "pelvis", ["pelvis"]))
    return sac, pel_rigid


def _animate_limbs(an: _Animating) -> None:
    """Limbs pass, per side: anchor, intermediate and effector joints and the two limb bones' frames
    (they join the joints and keep the hinge's right), the toe, and the hand and foot frames rigid
    on their devices."""
    model, tr, P, Fr, C0, rest_pos = an.model, an.tr, an.P, an.Fr, an.C0, an.rest_pos
    for s in sk.SIDES:
        for limb, (a, m, e, ab, mb) in LIMB_SEGMENTS.items():
            eff_role = "hand" if limb == "arm" else "foot"
            # The anchor rides on its limb's tracker (the root tracker's estimate ignores the
            # clavicle / pelvis-side motion); the root tracker only when the limb has none.
            anchor = joint_from_trackers(model, tr, f"{a}_{s}", [f"{ab}_{s}"])
            P[f"{a}_{s}"] = an.need(f"{a}_{s}", anchor if anchor is not None else
                                    joint_from_trackers(model, tr, f"{a}_{s}"))
            P[f"{e}_{s}"] = an.need(f"{e}_{s}", _own_frame(model, f"{e}_{s}", tr))
            mid = joint_from_trackers(model, tr, f"{m}_{s}")
            right = _hinge_right(model, tr, f"{mb}_{s}",
                                 _rigid(tr, f"{eff_role}_{s}", C0[BI[f"{mb}_{s}"]])[..., :, 0])
            if mid is None:  # no tracker carries it (minimal profile): two-bone from the user's lengths
                mid = _two_bone_mid(P[f"{a}_{s}"], P[f"{e}_{s}"], rest_pos, a, m, e, s, right)
            P[f"{m}_{s}"] = mid
            Fr[:, BI[f"{ab}_{s}"]] = frame_from_axes(P[f"{m}_{s}"] - P[f"{a}_{s}"], right)
            Fr[:, BI[f"{mb}_{s}"]] = frame_from_axes(P[f"{e}_{s}"] - P[f"{m}_{s}"], right)
        P[f"toe_{s}"] = _own_frame(model, f"toe_{s}", tr)
        if P[f"toe_{s}"] is None:
            P[f"toe_{s}"] = P[f"ankle_{s}"] + stack_apply(_rigid(tr, f"foot_{s}", np.eye(3)),
                                                          rest_pos[f"toe_{s}"] - rest_pos[f"ankle_{s}"])
        Fr[:, BI[f"foot_{s}"]] = _rigid(tr, f"foot_{s}", C0[BI[f"foot_{s}"]])
        Fr[:, BI[f"hand_{s}"]] = _rigid(tr, f"hand_{s}", C0[BI[f"hand_{s}"]])


def _animate_trunk(an: _Animating, sac: np.ndarray, pel_rigid: np.ndarray) -> None:
    """Trunk pass (appendix D "Trunk animation"): the sacrum's lateral and origin averaged with the
    hip line, the spine aimed at the skull base with its twist shared hips -> shoulders -> head
    (`ik.spine`), and the clavicles from vertebra 5 to the shoulders. Needs the limbs and head."""
    P, Fr, C0, rest_pos = an.P, an.Fr, an.C0, an.rest_pos
    sac = sacrum_toward_hip_line(sac, P["hip_l"], P["hip_r"])
    hipmid0 = 0.5 * (rest_pos["hip_l"] + rest_pos["hip_r"])
    from_hips = 0.5 * (P["hip_l"] + P["hip_r"]) + stack_apply(sac, C0[BI["sacrum"]].T @ (rest_pos["pelvis"] - hipmid0))
    P["pelvis"] = 0.5 * (pel_rigid + from_hips)
    sac_len = float(np.linalg.norm(rest_pos["spine_root"] - rest_pos["pelvis"]))
    rest_spine = np.stack([rest_pos[j] for j in SPINE_JOINTS])
    res = ik.spine(P["pelvis"], sac, sac_len, None, P["skull_base"],
                   top_right=normalize(P["shoulder_l"] - P["shoulder_r"]), two_pass=False,
                   rest_segments=np.diff(rest_spine, axis=0) @ C0[BI["sacrum"]])
    Fr[:, BI["sacrum"]] = res.sacrum_rot
    for k, j in enumerate(SPINE_JOINTS):
        P[j] = res.joints[:, k]
    for k, b in enumerate(SPINE_BONES):
        Fr[:, BI[b]] = res.rotations[:, k]
    v5 = Fr[:, BI[f"spine_{sk.CLAVICLE_VERTEBRA:02d}"]]
    for s in sk.SIDES:
        P[f"clavicle_{s}"] = P[sk.spine_joint(sk.CLAVICLE_VERTEBRA)]
        Fr[:, BI[f"clavicle_{s}"]] = frame_from_axes(P[f"shoulder_{s}"] - P[f"clavicle_{s}"], v5[..., :, 2])


def _animate_hands(an: _Animating) -> None:
    """Hands pass: finger joints and frames rigid on the hand as calibrated, then each finger with
    a tip marker posed from it (`pose_user_finger`; forward-filled over its dropouts)."""
    recording, P, Fr, C0, rest_pos = an.recording, an.P, an.Fr, an.C0, an.rest_pos
    for s in sk.SIDES:
        hand = Fr[:, BI[f"hand_{s}"]]
        c0h = C0[BI[f"hand_{s}"]]
        for f in sk.FINGERS:
            for jn in sk.FINGER_JOINTS:
                name = f"{jn}_{f}_{s}"
                P[name] = P[f"wrist_{s}"] + stack_apply(hand, c0h.T @ (rest_pos[name] - rest_pos[f"wrist_{s}"]))
            mb = f"metacarpal_{f}_{s}"
            Fr[:, BI[mb]] = stack_mul(hand, c0h.T @ C0[BI[mb]])
            for i in (1, 2, 3):
                b = f"{f}_{i}_{s}"
                Fr[:, BI[b]] = stack_mul(hand, c0h.T @ C0[BI[b]])
            tip_name = f"{f}_tip_{s}"
            if tip_name in recording.marker_names:
                m, mv = recording.marker(tip_name)
                idx = forward_fill(mv)[an.start:an.stop]
                if mv.any():
                    pose_user_finger(P, Fr, f, s, m[idx], rest_pos, C0, hand, an.model.bones)


def _shortcut_frames(an: _Animating) -> None:
    """Shortcut bones (and hips): frames rigid in the sacrum's lateral, for the mapping's kinematic
    paths. Needs the sacrum frame."""
    for b in BONES:
        if b.shortcut:
            an.Fr[:, BI[b.name]] = frame_from_axes(an.P[b.tail] - an.P[b.head], an.Fr[:, BI["sacrum"]][..., :, 0])


def sacrum_toward_hip_line(sacrum: np.ndarray, hip_l: np.ndarray, hip_r: np.ndarray) -> np.ndarray:
    """The sacrum frame (..., 3, 3) turned so its lateral axis lies half way to the hip line
    (Delahaye 2023, appendix D "Trunk animation"): the pelvis tracker's mounting and the fitted
    hip centres each carry their own error, and their average is never worse than the worse of them."""
    x_rigid = sacrum[..., :, 0]
    fix = quat_to_matrix(quat_between(x_rigid, normalize(x_rigid + normalize(hip_l - hip_r))))
    return fix @ sacrum


def _two_bone_mid(root, eff, rest_pos, a, m, e, s, right):
    """The intermediate joint from the user's two bone lengths, bent about the hinge axis `right`
    the effector's device carries (six devices: no tracker on the limb)."""
    l1 = np.linalg.norm(rest_pos[f"{m}_{s}"] - rest_pos[f"{a}_{s}"])
    l2 = np.linalg.norm(rest_pos[f"{e}_{s}"] - rest_pos[f"{m}_{s}"])
    # A positive turn about the hinge's +X flexes the distal bone toward +Z = X x Y, so the joint
    # itself lies on the other side of the root-effector line: along (effector - root) x right.
    return two_bone_mid(root, eff, l1, l2, np.cross(eff - root, right))


def pose_user_finger(P, Fr, f, s, tip, rest_pos, C0, hand, model_bones):
    """Finger joints and phalanx frames from a fingertip marker (appendix D, eq. 3-4 and the
    yaw/pitch realignment), through `fingers.pose_finger`; a plain equal-flexion stand-in
    (flexion from the distance, then the whole finger turned about the MCP toward the tip) runs
    until it exists."""
    names = [f"{j}_{f}_{s}" for j in sk.FINGER_JOINTS]
    lens = np.array([np.linalg.norm(rest_pos[names[i + 1]] - rest_pos[names[i]]) for i in range(3)])
    mcp = P[names[0]]
    bones = [f"{f}_{i}_{s}" for i in (1, 2, 3)]
    c0h = C0[BI[f"hand_{s}"]]
    rest_frames = [stack_mul(hand, c0h.T @ C0[BI[b]]) for b in bones]
    thumb = f == "thumb"
    pts, frames = pose_finger_chain(mcp, tip, lens, rest_frames, thumb=thumb)
    # The fingertip LED sits on the nail, one finger radius off the tip joint on the back of the
    # distal phalanx (-Z of its frame): once its orientation is known, aim at the joint instead.
    info = model_bones.get(bones[2])
    radius = info.radius_tail if info is not None and info.radius_tail else 0.0
    if radius:
        pts, frames = pose_finger_chain(mcp, tip + radius * frames[2][..., :, 2], lens, rest_frames, thumb=thumb)
    for i, j in enumerate(names[1:]):
        P[j] = pts[:, i + 1]
    for i, b in enumerate(bones):
        Fr[:, BI[b]] = frames[i]


def pose_finger_chain(mcp, tip, lens, rest_frames, thumb: bool = False):
    """`fingers.pose_finger` with the first phalanx's rest frame (moved with the hand) as the
    reference: a finger at rest has zero yaw and pitch, so the anatomical limits bound the motion
    away from the calibrated pose. The thumb's own frame already carries its roll (roll 0).
    Returns (points (F, 4, 3), [3 frames (F, 3, 3)])."""
    fp = fingers.pose_finger(mcp, rest_frames[0], lens[0], lens[1], lens[2], tip, thumb=thumb,
                             roll=0.0 if thumb else None)
    return fp.joints, [fp.rotations[:, i] for i in range(3)]


def axis_angle_matrix(axis, angle):
    """(..., 3, 3) rotation matrices of `angle` (rad) about `axis` (normalised here)."""
    axis = normalize(axis)
    x, y, z = np.moveaxis(axis, -1, 0)
    c, s_ = np.cos(angle), np.sin(angle)
    C = 1 - c
    return np.stack([
        np.stack([c + x * x * C, x * y * C - z * s_, x * z * C + y * s_], -1),
        np.stack([y * x * C + z * s_, c + y * y * C, y * z * C - x * s_], -1),
        np.stack([z * x * C - y * s_, z * y * C + x * s_, c + z * z * C], -1),
    ], -2)
