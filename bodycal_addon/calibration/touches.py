"""Touch segments (FORMATS.md §2.4): where the `by` fingertip (or palm centre, or controller tip)
rested on a body point, expressed in the touched body part's tracker frame (Delahaye 2023,
appendix B, Figure 5: every calibration point is stored first, computed later).

A touch is the `by` point's position while it holds still relative to the touched part: the
longest stretch of the segment where the running-median-filtered position moves slower than
`STILL_SPEED` for at least `STILL_MIN_S`, each still sample counting one frame interval (so the
times' rounding in a file cannot turn a touch held exactly that long into one held a nanosecond
short: the first and last samples' times no longer decide it). A touch that never stops
moving is not used: `extract` raises an error saying what to redo, and `collect` reports it as a
warning and leaves the point to its default rather than giving a wrong body or aborting.

A controller touches with its tip (`controller_tip_<s>`): a marker of that name when the recording
has one, else the point its `pivot_tip_<s>` step found (`controller_tips`), else an assumed one,
reported among the defaults.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core import transforms as tf
from ..core.errors import BodyCalError
from ..core.geometry import fit_rigid_point, fixed_point_spread, robust_mean, running_median
from ..recording.model import ROLES_LIST, Segment
from .common import Session, State, other, side_of

STILL_SPEED = 0.05  # m/s: slower than this (after a 0.15 s running median) counts as holding still
STILL_MIN_S = 0.2  # the touch must hold still this long (or half the segment, if shorter)
MEDIAN_S = 0.15
# `controller_tip_<s>` when the recording has no marker of that name and no `pivot_tip_<s>` step:
# the point 9 cm along the controller's +Y (the convention of synthetic.CONTROLLER_TIP_LOCAL), which
# no real controller need follow (the report says it was assumed); a recording that knows its
# controller's tip records it as a marker, which always wins.
CONTROLLER_TIP_LOCAL = np.array([0.0, 0.09, 0.0])
PIVOT_MAX_SE_MM = 2.0  # the pivot must fix the tip to this (standard error) or it is not used
PIVOT_INDEPENDENT_HZ = 20.0  # frames closer than this share their slip and wobble (progress.INDEPENDENT_HZ)
PIVOT_MAX_TIP_M = 0.35  # a tip farther than this from the controller's origin is not a controller's
PIVOT_HINT = "keep the tip on one spot and circle the controller around it, tilting it every way, for a few seconds"

TORSO_LOW = ("belly_ll", "belly_lr", "belly_c3", "belly_c4", "back_low")
HEAD_POINTS = ("ear_l", "ear_r", "upper_lip", "chin", "jaw_l", "jaw_r", "skull_top", "skull_left", "skull_right",
               "skull_back", "skull_base_l", "skull_base_r")


@dataclass
class Touch:
    point: str
    by: str
    role: str  # tracker frame the position is expressed in
    local: np.ndarray  # (3,)
    world: np.ndarray  # (3,) mean world position while still
    frames: np.ndarray  # frame indices used
    spread_mm: float
    segment: Segment
    rigid: bool = True  # False: `role` is a fallback frame the point does not ride on rigidly


def is_rigid(point: str, role: str) -> bool:
    """Whether a touched point is fixed in `role`'s frame (its own bone's tracker, or the pelvis
    for the hips); otherwise only distances between touches (radii) are meaningful."""
    s = side_of(point)
    natural = {"elbow_": f"forearm_{s}", "knee_": f"shin_{s}", "shoulder_": f"upperarm_{s}", "hip_": f"thigh_{s}"}
    for prefix, own in natural.items():
        if point.startswith(prefix):
            return role == own or (prefix == "hip_" and role == "pelvis")
    return True


def touched_role(session: Session, point: str) -> str:
    """The tracker frame a touched point rides on."""
    s = side_of(point)
    has = session.has
    if point.startswith(("wrist_", "mcp_", "palm_")):
        return f"hand_{s}"
    if point.startswith(("sole_", "ankle_")):
        return f"foot_{s}"
    if point.startswith("elbow_"):
        return f"forearm_{s}" if has(f"forearm_{s}") else f"hand_{s}"
    if point.startswith("knee_"):
        return f"shin_{s}" if has(f"shin_{s}") else f"foot_{s}"
    if point.startswith("shoulder_"):
        return f"upperarm_{s}" if has(f"upperarm_{s}") else ("chest" if has("chest") else "pelvis")
    if point.startswith("hip_"):
        return f"thigh_{s}" if has(f"thigh_{s}") else "pelvis"
    if point in HEAD_POINTS:
        return "head"
    if point in TORSO_LOW:
        return "pelvis" if has("pelvis") else "chest"
    return "chest" if has("chest") else "pelvis"


def default_by(session: Session, point: str) -> str:
    """FORMATS.md §2.4: the opposite index tip, or the controller tip with controllers only."""
    s = side_of(point)
    sides = (other(s),) if s else ("r", "l")
    names = session.rec.marker_names
    for t in sides:
        if f"index_tip_{t}" in names:
            return f"index_tip_{t}"
    return f"controller_tip_{sides[0]}"


def by_track(session: Session, state: State, by: str) -> tuple[np.ndarray, np.ndarray]:
    """World positions (F, 3) and validity (F,) of the touching point."""
    rec = session.rec
    if by in rec.marker_names:
        return rec.marker(by)
    if by.startswith("palm_") and by[-2:] in ("_l", "_r"):
        s = by[-1]
        centre = state.extra.get("palm_centre", {}).get(s)
        if centre is None:
            raise BodyCalError(f"'{by}' touches need the {s} palm calibrated first", source=session.source,
                               hint="record palms_together (and palm_*_{s} touches) or touch with a fingertip")
        p, q, v = session.pose(f"hand_{s}")
        return tf.transform_points(p, q, centre), v
    if by.startswith("controller_tip_"):
        s = by[-1]
        p, q, v = session.pose(f"hand_{s}")
        tip = state.extra.get("controller_tip_local", {}).get(s)
        if tip is None:
            tip = CONTROLLER_TIP_LOCAL
            session.default(by, f"{CONTROLLER_TIP_LOCAL[1] * 100:.0f} cm along the controller's +Y (no pivot_tip_{s} "
                            "step, no marker)")
        return tf.transform_points(p, q, tip), v
    for d in rec.devices:
        if by in (d.name, d.role):
            p, _, v = rec.pose(by)
            return p, v
    raise BodyCalError(f"the recording has no marker or device '{by}' to touch with", source=session.source,
                       field="segments.by", hint="name a fingertip marker (index_tip_r) or palm_<s>")


def controller_tips(session: Session, state: State) -> None:
    """The tip each controller touches with (`controller_tip_<s>`), from its `pivot_tip_<s>` step:
    the tip held on one spot of the room while the controller turns about it is the point fixed
    both in the controller's frame and in the room (`geometry.fit_rigid_point` with the room as
    the second frame: pivot calibration, as for a tracked stylus). **Decision** (DESIGN.md §3,
    "Touches with six devices"): measured, not assumed at a known offset from the controller's
    origin: where that origin and its axes sit differs between controllers and runtimes (OpenXR's
    grip pose is the fist's centre, its axes the runtime's), and a touch inherits the tip's whole
    error. A controller whose recording has a `controller_tip_<s>` marker keeps it."""
    for s in ("l", "r"):
        step = f"pivot_tip_{s}"
        segs = session.rec.segments_of(step)
        if not segs or f"controller_tip_{s}" in session.rec.marker_names:
            continue
        _pivot(session, state, s, step, segs)


def _pivot(session: Session, state: State, s: str, step: str, segs) -> None:
    role = f"hand_{s}"
    try:
        if not session.has(role):
            raise BodyCalError(f"needs the '{role}' controller", source=session.source, field=step,
                               hint=f"assign the role '{role}' to the controller ({ROLES_LIST})")
        p, q, v = session.pose(role)
        idx = session.frames(segs)
        idx = idx[v[idx]]
        rot = tf.quat_to_matrix(q[idx])
        room = np.broadcast_to(np.eye(3), rot.shape)
        try:
            fit = fit_rigid_point(rot, p[idx], room, np.zeros((len(idx), 3)), name=step, robust=session.robust)
        except BodyCalError as exc:  # its hint speaks of limbs
            raise BodyCalError(exc.message, source=session.source, field=step, hint=PIVOT_HINT) from None
        t = session.rec.time[idx[fit.inliers]]
        count = min(len(t), max(float(t[-1] - t[0]), 1e-9) * PIVOT_INDEPENDENT_HZ)
        se_mm = fixed_point_spread(rot[fit.inliers], fit.rms * 1000.0, count)
        if se_mm > PIVOT_MAX_SE_MM:
            raise BodyCalError(f"the controller turned too little about its tip to fix it (±{se_mm:.1f} mm, at most "
                               f"±{PIVOT_MAX_SE_MM:g} mm)", source=session.source, field=step, hint=PIVOT_HINT)
        if np.linalg.norm(fit.local_a) > PIVOT_MAX_TIP_M:
            raise BodyCalError(f"the point the controller turned about is {np.linalg.norm(fit.local_a):.2f} m from "
                               "it: the tip left its spot", source=session.source, field=step,
                               hint="keep the tip on one spot while the controller turns")
    except BodyCalError as exc:
        session.warn(f"{step} not used: {exc.message}" + (f" ({exc.hint})" if exc.hint else ""))
        if step not in session.missing:
            session.missing.append(step)
        return
    state.extra.setdefault("controller_tip_local", {})[s] = fit.local_a
    session.use(step, {"rms_mm": round(fit.rms * 1000, 3), "kept": fit.kept, "of": fit.of,
                       "range_deg": round(fit.range_deg, 1),
                       "tip_mm": round(float(np.linalg.norm(fit.local_a)) * 1000, 1), "tip_se_mm": round(se_mm, 2)})


def _speed(track: np.ndarray, t: np.ndarray, w: int) -> np.ndarray:
    """Speed (m/s) of the running-median-filtered track, per frame."""
    smooth = running_median(track, w)
    k = max(1, w // 2)
    if len(t) <= 2 * k:
        return np.full(len(t), np.linalg.norm(smooth[-1] - smooth[0]) / max(t[-1] - t[0], 1e-9))
    speed = np.empty(len(t))
    speed[k:-k] = np.linalg.norm(smooth[2 * k:] - smooth[:-2 * k], axis=1) / np.maximum(t[2 * k:] - t[:-2 * k], 1e-9)
    speed[:k], speed[-k:] = speed[k], speed[-k - 1]
    return speed


def _longest_run(mask: np.ndarray) -> tuple[int, int]:
    if not mask.any():
        return 0, 0
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    starts, ends = np.nonzero(d == 1)[0], np.nonzero(d == -1)[0]
    k = int(np.argmax(ends - starts))
    return int(starts[k]), int(ends[k])


def extract(session: Session, state: State, seg: Segment, role: str | None = None) -> Touch:
    """The touch of one segment, in `role`'s frame (default: the touched body part's)."""
    point = seg.point
    by = seg.by or default_by(session, point)
    role = role or touched_role(session, point)
    label = f"touch {point} by {by} ({seg.start:.2f}-{seg.end:.2f} s)"
    if not session.has(role):
        raise BodyCalError(f"needs the '{role}' tracker the point rides on, the recording has none",
                           source=session.source, field=label,
                           hint=f"assign the role '{role}' to a device ({ROLES_LIST}) or drop this touch")
    bp, bv = by_track(session, state, by)
    fp, fq, fv = session.pose(role)
    idx = session.rec.frames(seg.start, seg.end)
    idx = idx[bv[idx] & fv[idx]]
    if len(idx) < 3:
        raise BodyCalError(f"'{by}' and '{role}' are tracked together in only {len(idx)} frames",
                           source=session.source, field=label, hint="record the touch again with both visible")
    local = tf.inverse_transform_points(fp[idx], fq[idx], bp[idx])
    rigid = is_rigid(point, role)
    t = session.rec.time[idx]
    fps = max((len(t) - 1) / max(t[-1] - t[0], 1e-9), 1.0)
    w = max(3, int(round(MEDIAN_S * fps)) | 1)
    # Still relative to the touched part or to the room, whichever is slower: the tracker's
    # soft-tissue wobble turns the part's frame by a degree or so, which over a long lever (a
    # sternum seen from the pelvis tracker) looks like motion although the finger rests.
    speed = np.minimum(_speed(local, t, w), _speed(bp[idx], t, w))
    a, b = _longest_run(speed < STILL_SPEED)
    need = min(STILL_MIN_S, 0.5 * (seg.end - seg.start))
    held = (b - a) / fps  # each sample stands for one frame interval
    if b - a < 3 or held < need - 1e-6:
        slowest = float(np.min(speed)) if np.isfinite(speed).any() else float("nan")
        raise BodyCalError(f"the touch never stopped moving (slowest {slowest * 1000:.0f} mm/s; it must stay "
                           f"under {STILL_SPEED * 1000:.0f} mm/s for {need:.2f} s)", source=session.source,
                           field=label, hint=f"hold {by} still on {point} for half a second and record the touch again")
    sel = np.arange(a, b)
    mean, keep = robust_mean(local[sel], name=label)
    used = idx[sel][keep]
    world = robust_mean(bp[used], name=label)[0]
    spread = float(np.sqrt(np.mean(np.sum((local[sel][keep] - mean) ** 2, axis=1))) * 1000.0)
    return Touch(point, by, role, mean, world, used, spread, seg, rigid)


def collect(session: Session, state: State, prefix: tuple[str, ...] | None = None) -> dict[str, Touch]:
    """Every usable touch segment (optionally only points starting with one of `prefix`), by point
    name; a point touched twice keeps its last usable touch. A touch that cannot be used (it never
    settled, its tracker is missing) is reported in the session's warnings and left out."""
    out = {}
    for seg in session.rec.segments_of("touch"):
        if not seg.point or (prefix and not seg.point.startswith(prefix)):
            continue
        try:
            out[seg.point] = extract(session, state, seg)
        except BodyCalError as exc:
            what = exc.field or f"touch {seg.point}"
            session.warn(f"{what} not used: {exc.message}" + (f" ({exc.hint})" if exc.hint else ""))
    return out
