"""Limbs (paper 000, appendix B, "Limb calibration"; DESIGN.md §3).

Hinge joints (`flex_elbow_<s>`, `flex_knee_<s>`): the anchored bone's tracker (upper arm / thigh)
recorded in the intermediate bone's frame (forearm / shin tracker, else the hand / foot frame)
lies on a circle about the hinge axis. The circle's plane normal is the axis; its sign comes from
the articular limit (Figure 6): the joint never exceeds 180°, so the mean recorded point lies on
one side of the half-plane through the tracker and the centre, and we pick the normal that makes
flexion a positive rotation about +X in Blender's right-handed frames (no Unity sign flip). The
joint's place along the axis comes from the `<joint>_in` / `_out` touches (mean, projected on the
axis); the limb radius at the joint is half their distance.

Anchor joints (`swing_shoulder_<s>`, `swing_hip_<s>`): the root tracker (chest, else pelvis, for
shoulders; pelvis for hips) recorded in the limb tracker's frame lies on a sphere whose centre is
the joint (2-sigma pass in geometry.fit_sphere). The anchored limb's radius comes from the
diametric `<joint>_front` / `_back` touches.

**Decision** (DESIGN.md §3, anchor joints): the sphere fit is kept as the paper's check (its
residual, range and the distance of its centre are reported), but the joint centre comes from
`geometry.fit_rigid_point`, the point fixed in both trackers' frames, which also uses the two
trackers' rotations. With soft-tissue wobble the sphere of a 60-90° hip swing trades its centre
against its radius (a 5 cm error on one hip of the average synthetic performer); the rigid-point
fit stays within 2-4 mm (test_calibration.test_anchor_rigid_point_beats_the_sphere_under_wobble,
benchmarks/bench_calibration.py).

**Decision** (hinge axis): the circle's plane normal (paper 000) wobbles by several degrees with
the trackers' soft-tissue motion over the 20-30 cm lever; the axis is taken from the two trackers'
relative rotations instead (geometry.fit_rotation_axis), typically within 1° (the angle between
the two is reported as `circle_axis_deg`; test_calibration.test_hinge_axis_from_rotations_...).

**Decision** (hinge position): with both `<joint>_in` / `_out` touches the joint is their mean
(paper 000: "calibrate its position as the average position between both points"); the circle
gives the axis, and the distance of the touches' mean from it is reported (`touch_off_axis_mm`) as
a consistency check. Without the touches the circle centre is used and the default is reported.
"""

from __future__ import annotations

import numpy as np

from .. import skeleton as sk
from .. import transforms as tf
from ..geometry import fit_circle, fit_rigid_point, fit_rotation_axis, fit_sphere
from . import touches as T
from .common import Session, State

HINGES = {"elbow": ("forearm", "hand", "upperarm", "forearm"), "knee": ("shin", "foot", "thigh", "shin")}
ANCHORS = {"shoulder": ("upperarm",), "hip": ("thigh",)}


def hinge_right_sign(points: np.ndarray, centre: np.ndarray, normal: np.ndarray) -> np.ndarray:
    """The hinge axis (local right) among ±normal that makes flexion positive.

    In the intermediate bone's frame (origin = its tracker), the bone runs from the joint toward
    the tracker: Y = -(c - t)/|c - t| projected in the circle's plane. Flexing by θ about +X turns
    the anchored bone, seen from the intermediate one, toward Z = X × Y; the recorded points
    (which never pass 180°) therefore have a positive mean along Z."""
    d = np.asarray(centre, float)  # tracker (the frame's origin) -> centre
    d = d - (d @ normal) * normal
    if np.linalg.norm(d) < 1e-9:
        d = points.mean(axis=0) - centre
        d = d - (d @ normal) * normal
    y = -d / max(np.linalg.norm(d), 1e-12)
    m = points.mean(axis=0) - centre
    return normal if m @ np.cross(normal, y) > 0 else -normal


def hinge(session: Session, state: State, side: str, joint: str, touches: dict) -> None:
    inter, effector, anchored, bone = HINGES[joint]
    step = f"flex_{joint}_{side}"
    segs = session.rec.segments_of(step)
    if not segs:
        return
    frame_role = f"{inter}_{side}" if session.has(f"{inter}_{side}") else f"{effector}_{side}"
    anch_role = f"{anchored}_{side}"
    idx = session.frames(segs)
    pts, used = session.relative_track(step, frame_role, anch_role, idx)
    fit = fit_circle(pts, name=step, robust=session.robust)
    kept = pts[fit.inliers]
    # Decision (module docstring): the axis from the trackers' relative rotations, on the frames
    # the circle's 2-sigma passes kept; the circle still gives the side of the articular limit.
    _, fq, _ = session.pose(frame_role)
    _, aq, _ = session.pose(anch_role)
    rel = tf.quat_to_matrix(tf.quat_mul(tf.quat_conj(fq[used]), aq[used]))[fit.inliers]
    axis, _ = fit_rotation_axis(rel, name=step)
    right = hinge_right_sign(kept, fit.center, axis)
    centre = fit.center
    t_in, t_out = touches.get(f"{joint}_in_{side}"), touches.get(f"{joint}_out_{side}")
    q = fit.quality()
    q["circle_axis_deg"] = round(float(np.degrees(np.arccos(min(1.0, abs(float(fit.normal @ axis)))))), 2)
    if t_in and t_out and t_in.role == frame_role and t_out.role == frame_role and t_in.rigid:
        mid = 0.5 * (t_in.local + t_out.local)
        pos = mid
        state.radii[f"{joint}_{side}"] = 0.5 * float(np.linalg.norm(t_in.local - t_out.local))
        q["radius_mm"] = round(state.radii[f"{joint}_{side}"] * 1000, 1)
        q["touch_off_axis_mm"] = round(float(np.linalg.norm((mid - centre) - ((mid - centre) @ right) * right))
                                       * 1000, 1)
    else:
        pos = centre
        session.default(f"{joint}_{side} along the hinge axis",
                        f"circle plane of the {anch_role} tracker (no {joint}_in/out_{side} touches)")
    state.set_local(f"{joint}_{side}", frame_role, pos)
    state.set_local(f"{joint}_{side}", anch_role, session.carry(pos, frame_role, anch_role, used))
    state.hinge_right[f"{bone}_{side}"] = (frame_role, right)
    session.use(step, q)


def anchor(session: Session, state: State, side: str, joint: str, touches: dict) -> None:
    (limb,) = ANCHORS[joint]
    step = f"swing_{joint}_{side}"
    segs = session.rec.segments_of(step)
    if not segs:
        return
    if joint == "shoulder":
        root = "chest" if session.has("chest") else "pelvis"
    else:
        root = "pelvis"
    limb_role = f"{limb}_{side}"
    idx = session.frames(segs)
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


def limbs(session: Session, state: State) -> None:
    touches = T.collect(session, state, ("elbow_", "knee_", "shoulder_", "hip_"))
    for s in sk.SIDES:
        for j in HINGES:
            hinge(session, state, s, j, touches)
        for j in ANCHORS:
            anchor(session, state, s, j, touches)
        for j in (*HINGES, *ANCHORS):
            touch_only(session, state, s, j, touches)
