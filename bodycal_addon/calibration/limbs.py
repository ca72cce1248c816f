"""Limbs (Delahaye 2023, appendix B, "Limb calibration"; DESIGN.md §3).

Anchor joints (`swing_shoulder_<s>`, `swing_hip_<s>`) are fitted first, then the hinges, whose
place along their axis comes from the anchor (see below).

Anchor joints: the root tracker (chest, else pelvis, for shoulders; pelvis for hips) recorded in
the limb tracker's frame lies on a sphere whose centre is the joint (2-sigma pass in
geometry.fit_sphere). The anchored limb's radius comes from the diametric `<joint>_front` /
`_back` touches. Without the limb tracker (AvatarGo's six devices) the step is fitted from the
device at the end of the limb, the swing being done with the limb straight: the controller about
the shoulder in the chest, pelvis or HMD frame, the foot tracker about the hip in the pelvis frame;
the frame whose sphere fits best is kept and the quality report names it (`frames`).

Hinge joints (`flex_elbow_<s>`, `flex_knee_<s>`): the anchored bone's tracker (upper arm / thigh)
recorded in the intermediate bone's frame (forearm / shin tracker, else the hand / foot frame)
lies on a circle about the hinge axis. Without the upper arm / thigh tracker the trunk's tracker
stands in for it (the upper arm / thigh is held still against the trunk while the joint flexes).
The axis's sign comes from the articular limit (Figure 6): the joint never exceeds 180°, so the
mean recorded point lies on one side of the half-plane through the tracker and the centre, and we
pick the normal that makes flexion a positive rotation about +X in Blender's right-handed frames
(no Unity sign flip). Radius at the joint from the `<joint>_in` / `_out` touches.

**Decision** (DESIGN.md §3, anchor joints): the sphere fit is kept as the paper's check (its
residual, range and the distance of its centre are reported), but the joint centre comes from
`geometry.fit_rigid_point`, the point fixed in both trackers' frames, which also uses the two
trackers' rotations. With soft-tissue wobble the sphere of a 60-90° hip swing trades its centre
against its radius (a 5 cm error on one hip of the average synthetic performer); the rigid-point
fit stays within 2-4 mm (test_calibration.test_anchor_rigid_point_beats_the_sphere_under_wobble,
benchmarks/bench_calibration.py).

**Decision** (hinge axis): the circle's plane normal (Delahaye 2023) wobbles by several degrees with
the trackers' soft-tissue motion over the 20-30 cm lever; the axis is taken from the two trackers'
relative rotations instead (geometry.fit_rotation_axis), typically within 1° (the angle between
the two is reported as `circle_axis_deg`; test_calibration.test_hinge_axis_from_rotations_...).

**Decision** (hinge position along its axis): with both `<joint>_in` / `_out` touches the joint is
their mean (Delahaye 2023). Without them, the circle's centre is where the axis meets the plane of the
anchored TRACKER's circle, which sits wherever it was strapped (47-50 mm off on real captures);
instead the joint is put where the limb is straight with the joint straightened (`straighten`):
the anchor (shoulder / hip) and the effector (wrist / ankle, fitted from the motion in the same
intermediate tracker's frame, effectors.py) make equal angles with the axis, so the joint is where
the axis meets the anchor-effector line once the anchor is turned about the axis into the
effector's half-plane. Without a measured effector the joint is where the axis meets the anchor's
flexion plane (the plane through the anchor perpendicular to the axis: the two agree when the
axis is square to the bones). A hinge axis is not always square: CMU subject 5's elbows and right
knee turn 3-4.4° off it, and the flexion plane alone put them 15-27 mm along the axis from the
truth (evaluation/, 05_06), the straight limb within 6 mm. Only without an anchor is the
circle's centre kept (reported as a default).

A step whose data cannot be used (too little motion, a device missing, points that fit no circle
or sphere) is reported in `calibration.warnings`, left out, and what it would have given is
defaulted: it never aborts the calibration.
"""

from __future__ import annotations

import numpy as np

from ..body import skeleton as sk
from ..core import transforms as tf
from ..core.errors import BodyCalError
from ..core.geometry import fit_circle, fit_rigid_point, fit_rotation_axis, fit_sphere, fit_sphere_moving_point
from ..core.transforms import EPS
from . import touches as T
from .common import Session, State

# hinge: (intermediate tracker, effector device, anchored tracker, intermediate bone)
HINGES = {"elbow": ("forearm", "hand", "upperarm", "forearm"), "knee": ("shin", "foot", "thigh", "shin")}
ANCHORS = {"shoulder": ("upperarm",), "hip": ("thigh",)}
ANCHOR_OF = {"elbow": "shoulder", "knee": "hip"}
END_DEVICE = {"shoulder": "hand", "hip": "foot"}  # the device at the far end of the limb
END_JOINT = {"elbow": "wrist", "knee": "ankle"}
SWING_POINT = {"shoulder": "wrist", "hip": "ankle"}  # the joint the end device wanders about in a swing
UPPER_FROM_CIRCLE = ("elbow",)  # hinges whose end-device circle gives the upper bone's length (see below)
TRUNK_FRAMES = {"shoulder": ("chest", "pelvis", "head"), "hip": ("pelvis",), "elbow": ("chest", "pelvis", "head"),
                "knee": ("pelvis",)}


def hinge_right_sign(points: np.ndarray, centre: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """The hinge axis (local right) among ±normal that makes flexion positive.

    In the intermediate bone's frame (origin = its tracker), the bone runs from the joint toward
    the tracker: Y = -(c - t)/|c - t| projected in the circle's plane. Flexing by θ about +X turns
    the anchored bone, seen from the intermediate one, toward Z = X × Y; points on the anchored
    bone (its tracker, or the anchor joint), which never pass 180°, therefore have a positive mean
    along Z."""
    d = np.asarray(centre, float)  # tracker (the frame's origin) -> centre
    d = d - (d @ normal) * normal
    if np.linalg.norm(d) < 1e-9:
        d = points.mean(axis=0) - centre
        d = d - (d @ normal) * normal
    y = -d / max(np.linalg.norm(d), EPS)
    m = points.mean(axis=0) - centre
    return normal if m @ np.cross(normal, y) > 0 else -normal


def _try(session: Session, step: str, fn, *args):
    """Run one step; a step whose data cannot be used is reported and left out, never fatal."""
    try:
        return fn(*args)
    except BodyCalError as exc:
        session.warn(f"{step} not used: {exc.message}" + (f" ({exc.hint})" if exc.hint else ""))
        if step not in session.missing:
            session.missing.append(step)
        return None


def _best_fit(session: Session, step: str, candidates: list[str], other: str, idx: np.ndarray, fit, *,
              point_is_frame: bool = False, prefer=None):
    """Fit the origin of one tracker seen from another, for each candidate tracker, and keep the
    one that fits best (smallest residual for its size; a candidate `prefer` accepts wins unless
    its residual is over twice the best). By default the candidates are the frames and `other`'s
    origin the point; with `point_is_frame`, `other` is the frame and each candidate the point.
    Raises the last error when none works. Returns (score, candidate, fit, points, used)."""
    results, last = [], None
    for cand in candidates:
        if not session.has(cand) or cand == other:
            continue
        try:
            frame, point = (other, cand) if point_is_frame else (cand, other)
            pts, used = session.relative_track(step, frame, point, idx)
            f = fit(pts)
        except BodyCalError as exc:
            last = exc
            continue
        results.append((f.rms / max(getattr(f, "radius", 1.0), 1e-6), cand, f, pts, used))
    if not results:
        raise last or BodyCalError(f"needs one of the trackers {', '.join(candidates)}", source=session.source,
                                   field=step, hint="record the step with those devices tracked")
    best = min(results, key=lambda r: r[0])
    if prefer is not None:
        liked = [r for r in results if prefer(r[1]) and r[0] <= 2.0 * best[0]]
        if liked:
            best = min(liked, key=lambda r: r[0])
    return best


def anchor(session: Session, state: State, side: str, joint: str, touches: dict) -> None:
    (limb,) = ANCHORS[joint]
    step = f"swing_{joint}_{side}"
    segs = session.rec.segments_of(step)
    if not segs:
        return
    limb_role = f"{limb}_{side}"
    idx = session.frames(segs)
    if not session.has(limb_role):
        _try(session, step, _anchor_from_end_device, session, state, side, joint, step, idx)
        return
    root = ("chest" if session.has("chest") else "pelvis") if joint == "shoulder" else "pelvis"
    pts, used = session.relative_track(step, limb_role, root, idx)
    fit = fit_sphere(pts, name=step, robust=session.robust)
    q = fit.quality()
    lp, lq, _ = session.pose(limb_role)
    rp, rq, _ = session.pose(root)
    rigid = fit_rigid_point(tf.quat_to_matrix(lq[used]), lp[used], tf.quat_to_matrix(rq[used]), rp[used],
                            name=step, robust=session.robust)
    if session.anchor == "sphere":
        state.set_local(f"{joint}_{side}", limb_role, fit.center)
        state.set_local(f"{joint}_{side}", root, session.carry(fit.center, limb_role, root, used))
    else:
        state.set_local(f"{joint}_{side}", limb_role, rigid.local_a)
        state.set_local(f"{joint}_{side}", root, rigid.local_b)
    q.update({"rigid_rms_mm": round(rigid.rms * 1000, 3), "rigid_kept": rigid.kept,
              "sphere_centre_mm": round(float(np.linalg.norm(fit.center - rigid.local_a)) * 1000, 1)})
    front, back = touches.get(f"{joint}_front_{side}"), touches.get(f"{joint}_back_{side}")
    if front and back:
        state.radii[f"{joint}_{side}"] = 0.5 * float(np.linalg.norm(front.local - back.local))
        q["radius_mm"] = round(state.radii[f"{joint}_{side}"] * 1000, 1)
    session.use(step, q)


def _anchor_from_end_device(session: Session, state: State, side: str, joint: str, step: str, idx) -> None:
    """No limb tracker: the straight limb's end device (controller / foot tracker) swings on a
    sphere about the anchor joint, seen from the trunk's trackers; the point of the device that
    keeps its distance (the wrist / ankle the device wanders about) is fitted with the centre
    (`geometry.fit_sphere_moving_point`)."""
    device = f"{END_DEVICE[joint]}_{side}"
    if not session.has(device):
        raise BodyCalError(f"needs the '{ANCHORS[joint][0]}_{side}' tracker or the '{device}' device",
                           source=session.source, field=step, hint="record the step with those devices tracked")
    _, frame, fit, pts, used = _best_fit(session, step, list(TRUNK_FRAMES[joint]), device, idx,
                                         lambda p: fit_sphere(p, name=step, robust=session.robust))
    _, fq, _ = session.pose(frame)
    _, dq, _ = session.pose(device)
    rel = tf.quat_to_matrix(tf.quat_mul(tf.quat_conj(fq[used]), dq[used]))  # the device seen from the frame
    moving = fit_sphere_moving_point(pts, rel, name=step, robust=session.robust)
    name = f"{joint}_{side}"
    _place_anchor(session, state, name, frame, moving.center, used)
    # The point the swing found (the wrist / ankle the device wanders about), in the device's
    # frame, with the limb's direction there (toward the anchor): defaults.py weighs it across
    # the limb with the anatomical default (the swing cannot see it along the limb).
    toward = np.einsum("nji,nj->i", rel[moving.inliers], moving.center - pts[moving.inliers]
                       - np.einsum("nij,j->ni", rel[moving.inliers], moving.local))
    state.extra.setdefault("swing_points", {})[f"{SWING_POINT[joint]}_{side}"] = (
        device, moving.local, toward / max(float(np.linalg.norm(toward)), EPS))
    q = fit.quality()
    q.update({"frames": f"{device} in {frame}", "reach_mm": round(moving.radius * 1000, 1),
              "moving_point_rms_mm": round(moving.rms * 1000, 3),
              "moving_point_shift_mm": round(float(np.linalg.norm(moving.center - fit.center)) * 1000, 1)})
    session.use(step, q)


def _place_anchor(session: Session, state: State, name: str, frame: str, centre, used) -> None:
    state.set_local(name, frame, centre)
    # The animation carries the anchor on the trunk tracker nearest to it.
    for other in (("chest", "pelvis") if name.startswith("shoulder") else ("pelvis",)):
        if other != frame and session.has(other):
            state.set_local(name, other, session.carry(centre, frame, other, used))


def hinge(session: Session, state: State, side: str, joint: str, touches: dict) -> None:
    inter, effector, anchored, bone = HINGES[joint]
    step = f"flex_{joint}_{side}"
    segs = session.rec.segments_of(step)
    if not segs:
        return
    idx = session.frames(segs)
    anchor_joint = f"{ANCHOR_OF[joint]}_{side}"
    frame_role = f"{inter}_{side}"
    if not session.has(frame_role):
        _hinge_from_end_device(session, state, side, joint, step, idx)
        return
    anch_frames = [f"{anchored}_{side}"] if session.has(f"{anchored}_{side}") else list(TRUNK_FRAMES[joint])
    _, anch_role, fit, pts, used = _best_fit(session, step, anch_frames, frame_role, idx,
                                             lambda p: fit_circle(p, name=step, robust=session.robust),
                                             point_is_frame=True)
    kept = pts[fit.inliers]
    # Decision (module docstring): the axis from the trackers' relative rotations, on the frames
    # the circle's 2-sigma passes kept; the circle still gives the side of the articular limit.
    _, fq, _ = session.pose(frame_role)
    _, aq, _ = session.pose(anch_role)
    rel = tf.quat_to_matrix(tf.quat_mul(tf.quat_conj(fq[used]), aq[used]))[fit.inliers]
    axis, _ = fit_rotation_axis(rel, name=step)
    # The sign's half-plane argument needs points ON the anchored bone: a trunk tracker standing in
    # for the upper arm / thigh tracker can sit anywhere around the hinge, the anchor joint cannot.
    on_bone = kept if anch_role == f"{anchored}_{side}" else _carried_track(session, state, anchor_joint, frame_role,
                                                                            used[fit.inliers])
    right = hinge_right_sign(kept if on_bone is None else on_bone, fit.center, axis)
    centre = fit.center
    t_in, t_out = touches.get(f"{joint}_in_{side}"), touches.get(f"{joint}_out_{side}")
    q = fit.quality()
    q["circle_axis_deg"] = round(float(np.degrees(np.arccos(min(1.0, abs(float(fit.normal @ axis)))))), 2)
    if anch_role != f"{anchored}_{side}":
        q["frames"] = f"{anch_role} in {frame_role}"
    if t_in and t_out and t_in.role == frame_role and t_out.role == frame_role and t_in.rigid:
        mid = 0.5 * (t_in.local + t_out.local)
        pos = mid
        state.radii[f"{joint}_{side}"] = 0.5 * float(np.linalg.norm(t_in.local - t_out.local))
        q["radius_mm"] = round(state.radii[f"{joint}_{side}"] * 1000, 1)
        q["touch_off_axis_mm"] = round(float(np.linalg.norm((mid - centre) - ((mid - centre) @ right) * right))
                                       * 1000, 1)
    else:
        pos = _along_axis(session, state, joint, side, anchor_joint, frame_role, used, centre, right, q,
                          f"circle plane of the {anch_role} tracker")
        if "along_axis" in q:  # `straighten` may move it once the wrist / ankle is known
            state.extra.setdefault("hinge_lines", {})[f"{joint}_{side}"] = (frame_role, centre, right, used, anch_role)
    name = f"{joint}_{side}"
    state.set_local(name, frame_role, pos)
    if anch_role == f"{anchored}_{side}":
        state.set_local(name, anch_role, session.carry(pos, frame_role, anch_role, used))
    state.hinge_right[f"{bone}_{side}"] = (frame_role, right)
    session.use(step, q)


def _along_axis(session, state, joint, side, anchor_joint, frame_role, used, centre, right, q, fallback: str):
    """The hinge's place on its axis (module docstring): where the anchor's flexion plane meets it."""
    plane = _flexion_plane(session, state, anchor_joint, frame_role, used)
    if plane is None:
        session.default(f"{joint}_{side} along the hinge axis",
                        f"{fallback} (no {joint}_in/out_{side} touches, no {anchor_joint} calibrated)")
        return centre
    q["along_axis"] = f"{anchor_joint} flexion plane"
    q["axis_shift_mm"] = round(float(abs((plane - centre) @ right)) * 1000, 1)
    return centre + ((plane - centre) @ right) * right


def straighten(session: Session, state: State) -> None:
    """Each hinge placed by the anchor's flexion plane (`_along_axis`) whose effector (wrist /
    ankle) was fitted from the motion in the same tracker's frame moves along its axis to where
    the limb would be straight with the joint straightened (module docstring, Decision): the
    anchor S and the effector W make equal angles with the axis, so with h the coordinates along
    it and r the distances from it, the joint is at (h_S r_W + h_W r_S) / (r_S + r_W)."""
    for name, (frame, centre, right, used, anch_role) in state.extra.get("hinge_lines", {}).items():
        joint, side = name[:-2], name[-1]
        end = state.extra.get("effector_in_limb", {}).get(f"{END_JOINT[joint]}_{side}")
        anchor_joint = f"{ANCHOR_OF[joint]}_{side}"
        track = _carried_track(session, state, anchor_joint, frame, used)
        if end is None or end[0] != frame or track is None:
            continue
        h_s, r_s = _axial(track, centre, right)
        h_w, r_w = _axial(end[1][None], centre, right)
        if r_s + r_w < EPS:
            continue
        t = (h_s * r_w + h_w * r_s) / (r_s + r_w)
        before = state.local[name][frame]
        pos = centre + t * right
        state.set_local(name, frame, pos)
        if anch_role in state.local[name] and anch_role != frame:
            state.set_local(name, anch_role, session.carry(pos, frame, anch_role, used))
        q = session.quality.get(f"flex_{joint}_{side}", {})
        q["along_axis"] = f"straight {anchor_joint} - {END_JOINT[joint]}_{side}"
        q["axis_shift_mm"] = round(float(abs(t)) * 1000, 1)
        q["straightened_mm"] = round(float(np.linalg.norm(pos - before)) * 1000, 1)


def _axial(points: np.ndarray, centre: np.ndarray, axis: np.ndarray) -> tuple[float, float]:
    """Mean coordinate of `points` along the line (centre, unit axis) and mean distance from it."""
    d = np.asarray(points, float) - centre
    h = d @ axis
    return float(h.mean()), float(np.linalg.norm(d - h[:, None] * axis, axis=1).mean())


def _hinge_from_end_device(session: Session, state: State, side: str, joint: str, step: str, idx) -> None:
    """No tracker on the limb (six devices): with the upper arm / thigh held still against the
    trunk, the hand / foot device circles the hinge in the trunk's frame (the wrist / ankle may
    wander a few degrees: seen from the trunk that moves the device by millimetres, seen from the
    device it would move a trunk tracker half a metre away by centimetres). What it gives is the
    hinge's axis, carried by the device, which sets the limb's bend in the animation.

    **Decision**: not the knee's place. A few degrees of thigh wander move the circle's centre by
    centimetres (the thigh lengths it gave on real clips were off by up to 50 mm), so the knee is
    placed on the anchor-effector line in the anthropometric ratio (defaults.py), which on the same
    clips is within 14 mm (median) of the truth where the measured lengths were within 37. The
    elbow's circle is steadier (a shorter upper arm wandering about a shoulder measured within a
    few millimetres): its distance from the shoulder measures the upper arm (`UPPER_FROM_CIRCLE`;
    defaults.py weighs it with the ratio), within 14 mm of the truth on five CMU clips (median 5),
    where the ratio was up to 22 mm short on subjects 2 and 5."""
    _, effector, anchored, bone = HINGES[joint]
    device = f"{effector}_{side}"
    if not session.has(device):
        raise BodyCalError(f"needs the '{anchored}_{side}' tracker or the '{device}' device", source=session.source,
                           field=step, hint="record the step with those devices tracked")
    anchor_joint = f"{ANCHOR_OF[joint]}_{side}"
    known = state.local.get(anchor_joint, {})
    _, frame, fit, pts, used = _best_fit(session, step, list(TRUNK_FRAMES[joint]), device, idx,
                                         lambda p: fit_circle(p, name=step, robust=session.robust),
                                         prefer=lambda f: f in known)
    _, fq, _ = session.pose(frame)
    _, dq, _ = session.pose(device)
    keep = used[fit.inliers]
    rel = tf.quat_to_matrix(tf.quat_mul(tf.quat_conj(fq[keep]), dq[keep]))  # the device seen from the trunk
    axis, _ = fit_rotation_axis(rel, name=step)
    q = fit.quality()
    q["circle_axis_deg"] = round(float(np.degrees(np.arccos(min(1.0, abs(float(fit.normal @ axis)))))), 2)
    q["frames"] = f"{device} in {frame}"
    # Flexion turns the distal bone (toward the device) about +right away from the proximal one.
    centre = fit.center
    u = centre - known[frame] if frame in known else centre
    v = pts[fit.inliers] - centre
    right = axis if float(np.mean(np.cross(u, v) @ axis)) > 0 else -axis
    right_dev = tf.normalize(np.mean(tf.rotate(tf.quat_conj(dq[keep]), tf.rotate(fq[keep], right)), axis=0))
    state.hinge_right[f"{bone}_{side}"] = (device, right_dev)
    if joint in UPPER_FROM_CIRCLE and frame in known:
        state.extra.setdefault("upper_lengths", {})[f"{joint}_{side}"] = float(np.linalg.norm(u))
        q["upper_mm"] = round(float(np.linalg.norm(u)) * 1000, 1)
    session.use(step, q)


def _carried_track(session: Session, state: State, joint: str, frame_role: str, idx: np.ndarray):
    """(N, 3) a joint known in some tracked frame, seen from `frame_role` over frames `idx`."""
    for role, local in state.local.get(joint, {}).items():
        if session.has(role):
            p, q, _ = session.pose(role)
            fp, fq, _ = session.pose(frame_role)
            return tf.inverse_transform_points(fp[idx], fq[idx], tf.transform_points(p[idx], q[idx], local))
    return None


def _flexion_plane(session: Session, state: State, anchor_joint: str, frame_role: str, used: np.ndarray):
    """A point of the limb's flexion plane in `frame_role`'s frame: the anchor joint carried there
    (its mean over the step; the plane is perpendicular to the hinge axis, so only the component
    along the axis is used), or None when the anchor is not known in any tracked frame."""
    known = state.local.get(anchor_joint, {})
    for role, local in known.items():
        if session.has(role):
            return session.carry(local, role, frame_role, used)
    return None


def touch_only(session: Session, state: State, side: str, joint: str, touches: dict) -> None:
    """A limb joint without its motion step: the diametric touches still give the radius, and
    the joint itself when they were taken in a frame the joint rides on (e.g. the hips in the
    pelvis tracker's frame in a 6-device AvatarGo recording)."""
    if f"{joint}_{side}" in state.local:
        return
    a, b = (("in", "out") if joint in HINGES else ("front", "back"))
    ta, tb = touches.get(f"{joint}_{a}_{side}"), touches.get(f"{joint}_{b}_{side}")
    if not (ta and tb) or ta.role != tb.role:
        return
    if f"{joint}_{side}" not in state.radii:
        state.radii[f"{joint}_{side}"] = 0.5 * float(np.linalg.norm(ta.local - tb.local))
    q = {"radius_mm": round(state.radii[f"{joint}_{side}"] * 1000, 1)}
    if ta.rigid and tb.rigid:
        state.set_local(f"{joint}_{side}", ta.role, 0.5 * (ta.local + tb.local))
        q["frame"] = ta.role
    elif joint == "shoulder":
        # Not rigid in that frame (the spine bends), but the performer stands at the
        # touch as in the reference pose: a better guess than body ratios (defaults.py uses it).
        state.extra.setdefault("touch_estimates", {})[f"{joint}_{side}"] = (ta.role, 0.5 * (ta.local + tb.local))
    session.use(f"{joint}_{side} touches", q)


def level_hips(session: Session, state: State) -> None:
    """Both hips swung on the foot device (no thigh trackers): each at their mean height at the
    reference pose. **Decision**: the foot traces a cap of the hip's sphere no wider than the leg
    swings (40° from hanging on real clips), which fixes the hip in the pelvis frame well across
    the leg and poorly along it: a knee bending a few degrees during the swing moves the fitted
    hip up or down by up to 40 mm (evaluation/, CMU 02_01 and 131_01), while a person standing on
    both feet in the reference pose holds the pelvis level within a few millimetres. A hip fitted
    low also rolled the hip line, which the sacrum turned into a yaw (5-6° on the avatar)."""
    if any(session.quality.get(f"swing_hip_{s}", {}).get("frames") != f"foot_{s} in pelvis" for s in sk.SIDES):
        return
    world = {s: session.to_world("pelvis", state.local[f"hip_{s}"]["pelvis"]) for s in sk.SIDES}
    height = float(np.mean([w[2] for w in world.values()]))
    for s, w in world.items():
        state.set_local(f"hip_{s}", "pelvis", session.to_local("pelvis", np.array([w[0], w[1], height])))
        session.quality[f"swing_hip_{s}"]["levelled_mm"] = round((height - float(w[2])) * 1000, 1)


def limbs(session: Session, state: State) -> None:
    touches = T.collect(session, state, ("elbow_", "knee_", "shoulder_", "hip_"))
    for s in sk.SIDES:
        for j in ANCHORS:
            _try(session, f"swing_{j}_{s}", anchor, session, state, s, j, touches)
        for j in HINGES:
            _try(session, f"flex_{j}_{s}", hinge, session, state, s, j, touches)
        for j in (*HINGES, *ANCHORS):
            touch_only(session, state, s, j, touches)
    level_hips(session, state)
