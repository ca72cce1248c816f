"""`calibrate_user`: the user body calibration, every step in the paper's order (see the package
docstring)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..body import skeleton as sk
from ..body import surface_layout as sl
from ..body.bodymodel import BodyModel, BoneInfo, Joint, SurfaceElement, SurfacePoint
from ..core import transforms as tf
from ..core.errors import BodyCalError
from ..core.transforms import EPS
from ..recording.model import ROLES_LIST, Recording
from . import defaults, effectors, estimated_devices, feet, hands, head, limbs, touches, tpose, trunk
from .common import Session, State
from .unused_devices import warning_lines as unused_device_lines

UP = np.array([0.0, 0.0, 1.0])
CALIBRATION_STEPS = ("tpose", "stand", "palms_together", "flex_elbow_l", "flex_elbow_r", "flex_knee_l", "flex_knee_r",
                     "swing_shoulder_l", "swing_shoulder_r", "swing_hip_l", "swing_hip_r")

def natural_roles(joint: str, has) -> list[str]:
    """Tracker roles a joint is carried by (bodymodel.py contract), the primary first; only the
    roles the recording has. An elbow or knee is carried only by the limb's own trackers: the hand
    and the foot bend at the wrist and the ankle, so without limb trackers the animation places
    it from the two bone lengths (user_animation)."""
    s = joint[-1]
    if joint.startswith(("wrist_", "mcp_", "pip_", "dip_", "tip_")):
        cands = [f"hand_{s}"]
    elif joint.startswith("elbow_"):
        cands = [f"forearm_{s}", f"upperarm_{s}"]
    elif joint.startswith("shoulder_"):
        cands = [f"upperarm_{s}", "chest" if has("chest") else "pelvis"]
    elif joint.startswith("knee_"):
        cands = [f"shin_{s}", f"thigh_{s}"]
    elif joint.startswith("hip_"):
        cands = [f"thigh_{s}", "pelvis"]
    elif joint.startswith(("ankle_", "toe_")):
        cands = [f"foot_{s}"]
    elif joint in ("pelvis", "spine_root"):
        cands = ["pelvis"]
    elif joint in ("skull_base", "head"):
        cands = ["head"]
    else:
        cands = []
    return [r for r in cands if has(r)]


def _run(step_name: str, fn, *args):
    try:
        fn(*args)
    except BodyCalError:
        raise
    except (ValueError, FloatingPointError, np.linalg.LinAlgError) as exc:
        raise BodyCalError(f"could not be computed ({exc})", field=step_name,
                           hint="record the step again") from None


def calibrate_user(recording: Recording, *, robust: bool = True, despike: bool = True, anchor: str = "rigid",
                   name: str | None = None) -> BodyModel:
    """The user's body model from a calibration recording (FORMATS.md §3, kind "user").

    For the benchmark's comparisons: `robust=False` skips the 2-sigma passes, `despike=False` keeps
    tracking-glitch frames, `anchor="sphere"` takes the anchor joints from the paper's sphere fit."""
    if recording.frame_count == 0:
        raise BodyCalError("the recording has no frames", source=recording.source or recording.name)
    session = Session(recording, robust=robust, despike=despike, anchor=anchor)
    state = State()
    tpose.identify_roles(session)
    if not session.has("head"):
        raise BodyCalError("the recording has no HMD (role 'head'): the eye height and the head cannot be "
                           "calibrated", source=session.source,
                           hint=f"assign the role 'head' to the HMD device ({ROLES_LIST})")
    estimated_devices.attach(session)
    # Delahaye 2023, appendix B: extremities (hands, feet, head), then the limbs, then the trunk.
    _run("controller tips", touches.controller_tips, session, state)
    _run("palms_together", hands.palms_together, session, state)
    _run("hand touches", hands.hand_touches, session, state)
    _run("feet", feet.feet, session, state)
    _run("head", head.head, session, state)
    _run("limbs", limbs.limbs, session, state)
    _run("wrists and ankles", effectors.effectors, session, state)
    _run("limbs", limbs.straighten, session, state)
    _run("digits", hands.digits, session, state)
    _run("trunk", trunk.sacrum, session, state)
    _run("torso", trunk.torso_touches, session, state)
    if session.reference_step == "tpose":
        session.use("tpose")
    for step in CALIBRATION_STEPS:
        if not recording.segments_of(step) and step not in session.missing:
            session.missing.append(step)
    model = assemble(session, state, name or recording.name)
    model.calibration["warnings"] += unused_device_lines(recording, model.calibration["defaulted"], session.has)
    return model


# --- assembly -----------------------------------------------------------------------------------


def _measured_world(session: Session, state: State) -> None:
    for joint, frames in state.local.items():
        state.world[joint] = np.mean([session.to_world(r, v) for r, v in frames.items()], axis=0)


def _soles_toe(session: Session, state: State) -> None:
    """Toe joint (ball of the foot): in the sole outline's direction from the ankle, at the
    anthropometric distance, just above the floor, in the foot tracker's frame."""
    for s in sk.SIDES:
        pts = state.sole_points.get(s)
        if not pts or f"ankle_{s}" not in state.world:
            continue
        w = np.array([session.to_world(f"foot_{s}", v) for v in pts.values()])
        ank = state.world[f"ankle_{s}"]
        fwd = w.mean(axis=0) - ank
        fwd[2] = 0.0
        fwd /= max(np.linalg.norm(fwd), 1e-9)
        stature = float(session.ref_pose("head")[0][2]) / defaults.EYE_TO_STATURE
        toe = ank + fwd * defaults.R["toe_forward"] * stature
        toe[2] = defaults.R["toe_height"] * stature
        state.world[f"toe_{s}"] = toe
        state.set_local(f"toe_{s}", f"foot_{s}", session.to_local(f"foot_{s}", toe))
        session.default(f"toe_{s}", f"{defaults.R['toe_forward']} H from the ankle toward the sole's front, "
                        f"{defaults.R['toe_height']} H high")


def _bone_rights(session: Session, state: State, body: defaults.BodyFrame, w: dict) -> dict[str, np.ndarray]:
    """World `right` of every bone at the reference time (bodymodel.py: the flexion axis for
    hinges; for the other bones a documented convention: the performer's left for the trunk, the
    hinge axis of the limb for the upper arm / thigh, Y x palm normal for hand and fingers)."""
    rights = {}
    left, fwd = body.left, body.forward
    for s in sk.SIDES:
        for bone, flex_dir in ((f"forearm_{s}", fwd), (f"shin_{s}", -fwd)):
            if bone in state.hinge_right:
                role, local = state.hinge_right[bone]
                r = tf.rotate(session.ref_pose(role)[1], local)
            else:
                b = sk.BONE_BY_NAME[bone]
                y = w[b.tail] - w[b.head]
                r = np.cross(y, flex_dir - (flex_dir @ y) / max(y @ y, EPS) * y)
                session.default(f"{bone} hinge axis", "flexion toward the front (elbow) / back (knee) at the "
                                "reference pose")
            rights[bone] = r / max(np.linalg.norm(r), EPS)
        rights[f"upperarm_{s}"] = rights[f"forearm_{s}"]
        rights[f"thigh_{s}"] = rights[f"shin_{s}"]
        rights[f"foot_{s}"] = left
        along, n, _ = defaults.hand_axes(session, state, body, s, w)
        for b in sk.BONES:
            if b.name.endswith(f"_{s}") and (b.name.startswith(("hand_", "metacarpal_")) or
                                             any(b.name.startswith(f + "_") for f in sk.FINGERS)):
                y = w[b.tail] - w[b.head]
                r = np.cross(y, n)
                rights[b.name] = r / max(np.linalg.norm(r), EPS)
        rights[f"clavicle_{s}"] = fwd
        rights[f"hip_{s}"] = fwd
    for b in sk.BONES:
        rights.setdefault(b.name, left)
    return rights


def _order_outline(names: list[str], world: dict[str, np.ndarray], out_normal: np.ndarray) -> list[str]:
    """Outline order around the centroid, wound so the fan's normal points along `out_normal`."""
    pts = np.array([world[k] for k in names])
    c = pts.mean(axis=0)
    u = pts[0] - c
    u -= (u @ out_normal) * out_normal
    u /= max(np.linalg.norm(u), EPS)
    v = np.cross(out_normal, u)
    ang = np.arctan2((pts - c) @ v, (pts - c) @ u)
    return [names[i] for i in np.argsort(ang)]  # counter-clockwise about out_normal


def assemble(session: Session, state: State, name: str) -> BodyModel:
    """The user's BodyModel from the steps' results in `state`: every joint (measured, else
    defaulted), bone, surface element and AvatarGo offset; what was defaulted goes to
    `calibration["defaulted"]` in the order it was decided."""
    body = _complete_joints(session, state)
    estimated = {r: estimated_devices.WHAT[r] for r in session.estimated}
    joints = _joints(session, state)
    rights = _bone_rights(session, state, body, state.world)
    bones, frames_world = _bones(session, state, rights)
    parts = _Surfaces(session, state, body, frames_world)
    surface = [SurfaceElement(f"capsule:{b}", "capsule", b) for b in sl.CAPSULE_BONES]
    surface.append(_skull(parts))
    surface.append(_torso(parts))
    surface.append(_jaw(parts))
    palm_planes = {}
    for s in sk.SIDES:  # palm then sole, side by side: the surface's order
        along, n, thumb = defaults.hand_axes(session, state, body, s, state.world)
        surface.append(_palm(parts, s, n, thumb))
        surface.append(_sole(parts, s))
        plane = _palm_plane(parts, s, n)
        if plane is not None:
            palm_planes[f"hand_{s}"] = plane
    offs = _avatargo_offsets(session, joints, frames_world)
    model = BodyModel("user", name, joints, bones, surface, session.reference_time, offs)
    _record(model, session, state, body, palm_planes, estimated)
    return model


def _complete_joints(session: Session, state: State) -> defaults.BodyFrame:
    """Joints pass: `state.world` gets every canonical joint (measured from the trackers' frames,
    the toes from the soles, the rest defaulted, then the spine) and `state.radii` every radius.
    Returns the body frame the defaults were placed in."""
    _measured_world(session, state)
    _soles_toe(session, state)
    body = defaults.BodyFrame(session, state)
    w = state.world
    w.update(defaults.default_joints(session, state, body))
    if "spine_root" not in w:
        w["spine_root"] = w["pelvis"] + trunk.SPINE_ROOT_UP * UP - trunk.SPINE_ROOT_BACK * body.forward
        session.default("spine_root", "0.10 m above and 0.05 m behind the defaulted pelvis")
    trunk.spine(w)
    defaults.default_radii(state, body, session)
    return body


def _joints(session: Session, state: State) -> dict[str, Joint]:
    """Each joint's world position and every tracker frame it is known in (defaulted joints too, so
    the animation can carry them); the primary frame is its first natural role that has it."""
    w, has = state.world, session.has
    joints = {}
    for jn in sk.JOINTS:
        frames = dict(state.local.get(jn, {}))
        for role in natural_roles(jn, has):
            if role not in frames:
                frames[role] = session.to_local(role, w[jn])
        roles = natural_roles(jn, has)
        primary = next((r for r in roles if r in frames), next(iter(frames), None))
        joints[jn] = Joint(np.asarray(w[jn], float), primary, None if primary is None else frames[primary],
                           {r: frames[r] for r in ([primary] if primary else []) + [r for r in frames if r != primary]})
    return joints


def _bones(session: Session, state: State, rights: dict[str, np.ndarray]
           ) -> tuple[dict[str, BoneInfo], dict[str, np.ndarray]]:
    """Bones pass: each bone's length, right, capsule radii (from `state.radii`) and, for the
    hinges, the right in its tracker's frame; and each bone's world rest frame."""
    w, rad = state.world, state.radii
    bones, frames_world = {}, {}
    for b in sk.BONES:
        head_w, tail_w = w[b.head], w[b.tail]
        info = BoneInfo(b.head, b.tail, float(np.linalg.norm(tail_w - head_w)), rights[b.name])
        s = b.name[-1]
        # Limb capsules taper from the radius measured at one joint to the next: the paper's single
        # radius of the intermediate bone (mean of the joint's and the effector's) is their mean.
        limb = {"upperarm": ("shoulder", "elbow"), "forearm": ("elbow", "wrist"), "thigh": ("hip", "knee"),
                "shin": ("knee", "ankle")}.get(b.name[:-2])
        if limb is not None and b.name[-2:] in ("_l", "_r"):
            info.radius_head, info.radius_tail = rad[f"{limb[0]}_{s}"], rad[f"{limb[1]}_{s}"]
        else:
            for f in sk.FINGERS:
                if b.name.startswith(f + "_") and b.name.endswith(f"_{s}"):
                    info.radius_head = info.radius_tail = rad[f"finger_{f}_{s}"]
        if b.name in ("forearm_l", "forearm_r", "shin_l", "shin_r"):
            if b.name in state.hinge_right:
                role = state.hinge_right[b.name][0]
            else:
                role = (natural_roles(b.head, session.has) or [None])[0]
            if role is not None:
                info.extra["right_local"] = [round(float(x), 7) for x in
                                             tf.rotate(tf.quat_conj(session.ref_pose(role)[1]), rights[b.name])]
                info.extra["right_frame"] = role
        bones[b.name] = info
        frames_world[b.name] = sl.bone_frame(head_w, tail_w, rights[b.name])
    return bones, frames_world


@dataclass
class _Surfaces:
    """What the surface passes share: the session and state after the joints pass, the body frame
    and the bones' world rest frames (to store points in a bone's frame)."""
    session: Session
    state: State
    body: defaults.BodyFrame
    frames_world: dict[str, np.ndarray]

    def local_to_bone(self, bone: str, world_point) -> np.ndarray:
        return self.frames_world[bone].T @ (np.asarray(world_point) - self.state.world[sk.BONE_BY_NAME[bone].head])


def _skull(parts: _Surfaces) -> SurfaceElement:
    """`sphere:skull`, its centre in the head bone's frame: the skull touches' sphere, else the
    stature's ratios above the skull base (a default)."""
    session, state, body = parts.session, parts.state, parts.body
    if state.skull is not None:
        centre_w, radius = session.to_world("head", state.skull[0]), state.skull[1]
    else:
        centre_w = state.world["skull_base"] + UP * defaults.R["skull_up"] * body.stature
        radius = defaults.R["skull_radius"] * body.stature
        session.default("sphere:skull", "skull radius and height ratios of the stature")
    return SurfaceElement("sphere:skull", "sphere", "head", center=parts.local_to_bone("head", centre_w),
                          radius=float(radius))


def _torso(parts: _Surfaces) -> SurfaceElement:
    """`mesh:torso`, each point in its nearest vertebra's frame: the touched points (completed by
    `trunk.complete_torso`), the layout's ratios for the rest, then the belly centre points."""
    session, state, body, w = parts.session, parts.state, parts.body, parts.state.world
    trunk.complete_torso(session, state)
    torso_w = dict(state.torso_world)
    spine_pts = np.array([w[sk.spine_joint(k)] for k in range(sk.SPINE_COUNT + 1)])
    for k, (t, lft, fw) in defaults.TORSO_LAYOUT.items():
        if k not in torso_w:
            base = w["spine_root"] + t * (w["skull_base"] - w["spine_root"])
            torso_w[k] = base + body.left * lft * body.stature + body.forward * fw * body.stature
            session.default(f"torso {k}", "torso layout ratios of the stature")
    for k, v in sl.belly_centre_points(*(torso_w[c] for c in ("belly_ul", "belly_ur", "belly_ll", "belly_lr"))).items():
        if k not in torso_w:
            torso_w[k] = v
            session.default(k, "bilinear interpolation of the four belly corners")
    pts = {}
    for k in sl.TORSO_POINTS:
        bone = sl.nearest_vertebra(torso_w[k], spine_pts)
        pts[k] = SurfacePoint(bone, parts.local_to_bone(bone, torso_w[k]))
    return SurfaceElement("mesh:torso", "mesh", "spine_*", points=pts, triangles=list(sl.TORSO_TRIANGLES))


def _jaw(parts: _Surfaces) -> SurfaceElement:
    """`mesh:jaw` in the head bone's frame: the jaw touches, else the layout around the skull base."""
    session, state, body = parts.session, parts.state, parts.body
    if state.jaw:
        jaw_w = {k: session.to_world("head", v) for k, v in state.jaw.items()}
    else:
        jaw_w = {k: state.world["skull_base"] + (body.left * a + body.forward * b + UP * c) * body.stature
                 for k, (a, b, c) in defaults.JAW_LAYOUT.items()}
        session.default("mesh:jaw", "jaw layout ratios of the stature around the skull base")
    return SurfaceElement("mesh:jaw", "mesh", "head",
                          points={k: SurfacePoint("head", parts.local_to_bone("head", v)) for k, v in jaw_w.items()},
                          triangles=list(sl.JAW_TRIANGLES))


def _palm(parts: _Surfaces, s: str, n: np.ndarray, thumb: np.ndarray) -> SurfaceElement:
    """`mesh:palm_<s>` in the hand bone's frame, wound out of the palm (normal `n`): the palm
    touches, else a quad from the index and pinky bases to the wrist (a default)."""
    session, state, w = parts.session, parts.state, parts.state.world
    if s in state.palm_points:
        palm_w = {k: session.to_world(f"hand_{s}", v) for k, v in state.palm_points[s].items()}
    else:
        r = state.radii[f"finger_middle_{s}"]
        wr, mi, mp = w[f"wrist_{s}"], w[f"mcp_index_{s}"], w[f"mcp_pinky_{s}"]
        half = 0.3 * np.linalg.norm(mi - mp)
        palm_w = {f"palm_1_{s}": mi + n * r, f"palm_2_{s}": mp + n * r,
                  f"palm_3_{s}": wr - thumb * half + n * r, f"palm_4_{s}": wr + thumb * half + n * r}
        session.default(f"mesh:palm_{s}", "quad from the index and pinky bases to the wrist")
    order = _order_outline(sorted(palm_w), palm_w, n)
    return SurfaceElement(
        f"mesh:palm_{s}", "mesh", f"hand_{s}",
        points={k: SurfacePoint(f"hand_{s}", parts.local_to_bone(f"hand_{s}", palm_w[k])) for k in order},
        triangles=sl.fan_triangles(order))


def _sole(parts: _Surfaces, s: str) -> SurfaceElement:
    """`mesh:sole_<s>` in the foot bone's frame, wound facing down: the sole touches, else a
    rectangle on the floor from the heel to past the toe (a default)."""
    session, state, body, w = parts.session, parts.state, parts.body, parts.state.world
    if s in state.sole_points:
        sole_w = {k: session.to_world(f"foot_{s}", v) for k, v in state.sole_points[s].items()}
    else:
        a, t = w[f"ankle_{s}"], w[f"toe_{s}"]
        fw = t - a
        fw[2] = 0
        fw /= max(np.linalg.norm(fw), 1e-9)
        side = np.cross(UP, fw)
        hw = 0.5 * defaults.R["foot_width"] * body.stature
        heel = a - fw * defaults.R["heel_back"] * body.stature
        front = t + fw * 0.04 * body.stature
        sole_w = {f"sole_1_{s}": heel + side * hw, f"sole_2_{s}": heel - side * hw,
                  f"sole_3_{s}": front - side * hw, f"sole_4_{s}": front + side * hw}
        sole_w = {k: v * np.array([1, 1, 0]) for k, v in sole_w.items()}
        session.default(f"mesh:sole_{s}", "rectangle from the heel to past the toe, foot width ratio")
    order = _order_outline(sorted(sole_w), sole_w, -UP)
    return SurfaceElement(
        f"mesh:sole_{s}", "mesh", f"foot_{s}",
        points={k: SurfacePoint(f"foot_{s}", parts.local_to_bone(f"foot_{s}", sole_w[k])) for k in order},
        triangles=sl.fan_triangles(order))


def _palm_plane(parts: _Surfaces, s: str, n: np.ndarray) -> dict | None:
    """The palm plane of hand `s` in the hand device's frame (point, normal; for the finger
    animation): as measured, else through the middle finger's base one finger radius out along
    `n`; None without a hand device."""
    session, state = parts.session, parts.state
    if f"hand_{s}" in state.palm_planes:
        point, normal = state.palm_planes[f"hand_{s}"]
        return {"point": [round(float(x), 7) for x in point], "normal": [round(float(x), 7) for x in normal]}
    if session.has(f"hand_{s}"):
        q = session.ref_pose(f"hand_{s}")[1]
        point = session.to_local(f"hand_{s}", state.world[f"mcp_middle_{s}"] + n * state.radii[f"finger_middle_{s}"])
        return {"point": [round(float(x), 7) for x in point],
                "normal": [round(float(x), 7) for x in tf.rotate(tf.quat_conj(q), n)]}
    return None


def _avatargo_offsets(session: Session, joints: dict[str, Joint], frames_world: dict[str, np.ndarray]) -> dict:
    """AvatarGo offsets (AvatarGo §3.3): every tracker to every joint, with the rotation of the bone
    the joint starts (else ends)."""
    bone_quats = {b: tf.matrix_to_quat(m) for b, m in frames_world.items()}
    joint_bone = {}
    for b in sk.BONES:
        if not b.shortcut:
            joint_bone.setdefault(b.head, b.name)
    for b in sk.BONES:
        if not b.shortcut:
            joint_bone.setdefault(b.tail, b.name)
    return tpose.offsets(session, joints, bone_quats, joint_bone)


def _record(model: BodyModel, session: Session, state: State, body: defaults.BodyFrame, palm_planes: dict,
            estimated: dict[str, str]) -> None:
    """Sets the model's calibration record (steps used, defaults, missing steps, warnings, quality,
    what the estimated devices carry) and its extras (T-pose device poses, eye height, palm planes,
    radii, sacrum width, the estimated devices)."""
    rad = state.radii
    model.calibration = {
        "steps_used": list(session.steps_used),
        "defaulted": dict(session.defaulted),
        "missing": list(session.missing),
        "warnings": list(session.warnings),
        "quality": session.quality,
        "reference": session.reference_step,
    }
    if estimated:
        model.calibration["estimated"] = [j for r in estimated for j in estimated_devices.CARRIED[r]]
    model.extra = {
        "tpose": tpose.device_poses(session),
        "eye_height": round(body.eye_height, 6),
        "palm_planes": palm_planes,
        "finger_radii": {k: round(float(v), 6) for k, v in rad.items() if k.startswith("finger_")},
        "joint_radii": {k: round(float(v), 6) for k, v in rad.items() if not k.startswith("finger_")},
    }
    if "sacrum_width" in state.extra:
        model.extra["sacrum_width"] = round(state.extra["sacrum_width"], 6)
    if estimated:
        model.extra["estimated_devices"] = estimated
