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
"""

from __future__ import annotations

import numpy as np

from .. import skeleton as sk
from ..geometry import fit_circle, fit_sphere
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
    right = hinge_right_sign(kept, fit.center, fit.normal)
    centre = fit.center
    t_in, t_out = touches.get(f"{joint}_in_{side}"), touches.get(f"{joint}_out_{side}")
    q = fit.quality()
    if t_in and t_out and t_in.role == frame_role and t_out.role == frame_role:
        mid = 0.5 * (t_in.local + t_out.local)
        pos = centre + ((mid - centre) @ right) * right  # along the axis, from the touches
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
    state.set_local(f"{joint}_{side}", limb_role, fit.center)
    state.set_local(f"{joint}_{side}", root, session.carry(fit.center, limb_role, root, used))
    q = fit.quality()
    front, back = touches.get(f"{joint}_front_{side}"), touches.get(f"{joint}_back_{side}")
    if front and back:
        state.radii[f"{joint}_{side}"] = 0.5 * float(np.linalg.norm(front.local - back.local))
        q["radius_mm"] = round(state.radii[f"{joint}_{side}"] * 1000, 1)
    session.use(step, q)


def limbs(session: Session, state: State) -> None:
    touches = T.collect(session, state, ("elbow_", "knee_", "shoulder_", "hip_"))
    for s in sk.SIDES:
        for j in HINGES:
            hinge(session, state, s, j, touches)
        for j in ANCHORS:
            anchor(session, state, s, j, touches)
