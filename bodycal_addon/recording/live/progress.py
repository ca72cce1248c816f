"""How far a calibration step is, live (recording/live/wizard.py; DESIGN.md "Live calibration
wizard"): numpy measures on the frames recorded since the step began (`RecentFrames`), each against
what the offline fit of the step needs (calibration/, core/geometry.py), as a `StepProgress`.

- holds (tpose, stand): every tracked device slower than `STILL_SPEED` for `HOLD_S`;
- palms_together: the palms together (paired glove markers within `PALMS_GAP_M`) for `HOLD_S`;
- touches: the toucher still relative to the touched part's device (or the room) for `STILL_MIN_S`;
- flexes: the arc about the hinge axis fitted from the two devices' relative rotations;
- swings: the extent of the relative rotation along and across its main direction, how well the
  frames pin the joint's centre (`centre_spread_mm`), then the sphere check the calibration runs;
- pivots: the controller's turns about its tip, how well they pin the tip, then the pivot fit.

Holds, palms and touches count a trailing run: how long the condition has held up to the newest
frame; the run's start (`StepProgress.still_from`) lets the wizard keep only that stretch.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ...core import transforms as tf
from ...core.errors import BodyCalError
from ...core.geometry import (
    MIN_ARC_DEG,
    MIN_SWING_DEG,
    MIN_SWING_MINOR_DEG,
    fit_rigid_point,
    fit_rotation_axis,
    fit_sphere,
    fixed_point_spread,
    running_median,
)

if TYPE_CHECKING:  # the recorder imports python-osc; the measures need numpy only
    from .recorder import RecentFrames

# --- what the offline calibration needs (thresholds; DESIGN.md "Live calibration wizard") ----------
STILL_SPEED = 0.05  # m/s, calibration/touches.py STILL_SPEED: slower than this counts as still
STILL_MIN_S = 0.2  # s, calibration/touches.py STILL_MIN_S: a touch held this long is usable
MEDIAN_S = 0.15  # s, calibration/touches.py MEDIAN_S: positions are median-filtered over this before speeds
MIN_STEP_FRAMES = 20  # calibration/common.py MIN_STEP_FRAMES: a flex / swing needs this many frames
STEP_FRAMES = 30  # the wizard asks this many: the calibration drops glitch frames before it counts
HOLD_S = 0.5  # s a reference pose is held still: the calibration averages +-0.1 s around its middle
PALMS_GAP_M = 0.10  # m: paired glove LEDs closer than this on average = palms together (DESIGN.md)
MARGIN = 1.5  # the wizard asks this much more motion than the fits refuse below (see DESIGN.md)
FLEX_TARGET_DEG = MARGIN * MIN_ARC_DEG  # 60 deg
SWING_TARGET_DEG = MARGIN * MIN_SWING_DEG  # 60 deg main swing
SWING_ACROSS_TARGET_DEG = MARGIN * MIN_SWING_MINOR_DEG  # 22.5 deg across it
SWING_CENTRE_MM = 3.0  # a swing is done once it fixes the joint centre to this (centre_spread_mm)
NOISE_MM = 3.0  # tracker noise and soft-tissue wobble per frame assumed by centre_spread_mm
INDEPENDENT_HZ = 20.0  # frames closer than 1/20 s share their wobble: they count as one
MAX_FIT_FRAMES = 600  # a flex / swing / pivot window is thinned to this many frames (update() stays cheap)
PIVOT_NOISE_MM = 2.0  # the tip's slip on its spot and the tracking, per frame (evaluation/: misfit 1.5-1.8 mm)
PIVOT_TIP_MM = 1.0  # a pivot is done once it fixes the tip to this: calibration/touches.PIVOT_MAX_SE_MM / 2
PIVOT_TURN_DEG = 30.0  # ... and the controller turned this much about two directions
PIVOT_MAX_RMS_MM = 5.0  # the tip's misfit above this: it left its spot
HOLD_WINDOW_S = 2.0 * HOLD_S  # a hold or touch reads only the last this many seconds
PREROLL_S = 2.0 * MEDIAN_S  # frames read from before the step began, so its first frames have a speed


@dataclass(frozen=True)
class StepProgress:
    fraction: float  # 0..1 toward automatic completion
    figure: str  # one line: "elbow bent through 34 of 60°", "hold still 0.30 of 0.50 s"
    done: bool  # enough data is in
    still_from: float | None = None  # hold steps: when the still stretch began (recording clock)

    def with_figure(self, what: str) -> StepProgress:
        """The same progress with the figure's first words (`hold still`) replaced."""
        return StepProgress(self.fraction, self.figure.replace("hold still", what, 1), self.done, self.still_from)


# --- progress measures (numpy on the frames since the step began) -------------------------------------


def speeds(track: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Speed (m/s) of each frame of a (F, ..., 3) track after a `MEDIAN_S` running median, over the
    same span as the calibration's (two half windows, calibration/touches.py) but backward, ending
    at the frame: the newest frame has a speed now, which a centred difference would only give
    half a window later; (F, ...), infinite for the first frames (no span before them)."""
    if len(t) < 2:
        return np.full(track.shape[:-1], np.inf)
    fps = (len(t) - 1) / max(t[-1] - t[0], 1e-9)
    w = max(3, int(round(MEDIAN_S * fps)) | 1)
    smooth = running_median(track, w)
    k = 2 * max(1, w // 2)
    out = np.full(track.shape[:-1], np.inf)
    if len(t) > k:
        dt = np.maximum(t[k:] - t[:-k], 1e-9).reshape((-1,) + (1,) * (track.ndim - 2))
        out[k:] = np.linalg.norm(smooth[k:] - smooth[:-k], axis=-1) / dt
    return out


def trailing_run(still: np.ndarray, t: np.ndarray) -> tuple[float, float | None]:
    """How long the frames have been still up to the newest (seconds, each still frame counting
    one frame interval as the calibration counts a touch) and the time the run began."""
    if len(t) == 0 or not still[-1]:
        return 0.0, None
    moving = np.nonzero(~still)[0]
    first = int(moving[-1]) + 1 if len(moving) else 0
    interval = (t[-1] - t[0]) / max(len(t) - 1, 1)
    return float(t[-1] - t[first] + interval), float(t[first])


def hold_figure(held: float, need: float, extra: str = "", still_from: float | None = None) -> StepProgress:
    fig = f"hold still {min(held, need):.2f} of {need:.2f} s" + (f" ({extra})" if extra else "")
    return StepProgress(min(1.0, held / need), fig, held >= need - 1e-9, still_from)


def hold_progress(frames: RecentFrames, slots: list[int], names: list[str], need: float = HOLD_S,
                  begin: float = -np.inf) -> StepProgress:
    """The devices `slots` all tracked and slower than `STILL_SPEED` up to the newest frame (frames
    before `begin` give speeds, not held time)."""
    if not slots or frames.count < 2:
        return hold_figure(0.0, need, "waiting for the devices")
    sp = speeds(frames.positions[:, slots], frames.time)
    ok = frames.valid[:, slots].all(axis=1)
    fastest = np.where(ok[:, None], sp, np.inf)
    still = ok & (fastest.max(axis=1) < STILL_SPEED) & (frames.time >= begin)
    held, since = trailing_run(still, frames.time)
    extra = ""
    if not still[-1]:
        k = int(np.argmax(fastest[-1]))
        v = fastest[-1, k]
        extra = f"{names[k]} moving {v:.2f} m/s" if np.isfinite(v) else f"{names[k]} not tracked"
    return hold_figure(held, need, extra, since)


def palms_progress(frames: RecentFrames, hands: tuple[int, int], pairs: list[tuple[int, int]],
                   begin: float = -np.inf) -> StepProgress:
    """Both hands tracked with the palms together (paired glove markers within `PALMS_GAP_M` on
    average) for `HOLD_S`. **Decision**: not held still: the palm planes are fitted to the pairs'
    midpoints in each hand's frame (calibration/hands.py), which palms sliding on each other keep
    on the plane (the sample take's hands slide at 0.05-0.2 m/s)."""
    if frames.count < 2:
        return hold_figure(0.0, HOLD_S, "waiting for the devices")
    left, right = hands
    ok = frames.valid[:, left] & frames.valid[:, right]
    a, b = [p for p, _ in pairs], [q for _, q in pairs]
    seen = frames.points_valid[:, a] & frames.points_valid[:, b]
    gap = np.linalg.norm(frames.points[:, a] - frames.points[:, b], axis=-1)
    count = seen.sum(axis=1)
    mean_gap = np.where(count > 0, (gap * seen).sum(axis=1) / np.maximum(count, 1), np.inf)
    together = ok & (count >= 3) & (mean_gap < PALMS_GAP_M) & (frames.time >= begin)
    held, since = trailing_run(together, frames.time)
    extra = "" if together[-1] else ("a glove not tracked" if not ok[-1] or count[-1] < 3 else
                                     f"palms {mean_gap[-1] * 100:.0f} cm apart")
    return hold_figure(held, HOLD_S, extra, since).with_figure("palms together")


def touch_progress(frames: RecentFrames, part: int, by_track: np.ndarray, by_valid: np.ndarray,
                   begin: float = -np.inf) -> StepProgress:
    """The touching point still relative to the touched part's device (or to the room, whichever is
    slower, as the calibration reads a touch) for `STILL_MIN_S`."""
    if frames.count < 2:
        return hold_figure(0.0, STILL_MIN_S, "waiting for the devices")
    ok = frames.valid[:, part] & by_valid
    local = tf.inverse_transform_points(frames.positions[:, part], frames.rotations[:, part], by_track)
    speed = np.minimum(speeds(local, frames.time), speeds(by_track, frames.time))
    still = ok & (speed < STILL_SPEED) & (frames.time >= begin)
    held, since = trailing_run(still, frames.time)
    extra = "" if still[-1] else ("not tracked" if not ok[-1] else f"moving {speed[-1]:.2f} m/s")
    return hold_figure(held, STILL_MIN_S, extra, since)


def relative_motion(frames: RecentFrames, frame: int, point: int) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3, 3) the point device's rotation seen from the frame device and (N, 3) its origin in
    that frame, on the frames both are tracked."""
    ok = frames.valid[:, frame] & frames.valid[:, point]
    fp, fq = frames.positions[ok, frame], tf.quat_normalize(frames.rotations[ok, frame])
    q = tf.quat_mul(tf.quat_conj(fq), tf.quat_normalize(frames.rotations[ok, point]))
    return tf.quat_to_matrix(tf.quat_normalize(q)), tf.inverse_transform_points(fp, fq, frames.positions[ok, point])


def flex_progress(rel: np.ndarray, joint: str) -> StepProgress:
    """The arc the hinge swept (degrees about its axis fitted from the relative rotations, as the
    calibration fits it) toward `FLEX_TARGET_DEG`."""
    arc = 0.0
    if len(rel) >= 5:
        try:
            arc = float(fit_rotation_axis(rel, name="flex")[1])
        except BodyCalError:
            arc = 0.0
    done = arc >= FLEX_TARGET_DEG and len(rel) >= STEP_FRAMES
    figure = f"{joint} bent through {arc:.0f} of {FLEX_TARGET_DEG:.0f}°" + _frames_short(len(rel))
    return StepProgress(min(1.0, arc / FLEX_TARGET_DEG), figure, done)


def _frames_short(n: int) -> str:
    return f" ({n} of {STEP_FRAMES} frames)" if n < STEP_FRAMES else ""


def rotation_extent(rel: np.ndarray) -> tuple[float, float]:
    """(main, across) extent in degrees of the rotations `rel` (N, 3, 3): their rotation vectors
    from the mean rotation, 2nd to 98th percentile along the two main directions. A still limb
    gives the trackers' noise (a degree or two) whatever the points do."""
    if len(rel) < 5:
        return 0.0, 0.0
    q = tf.continuous_quaternions(tf.matrix_to_quat(rel))
    mean = tf.quat_normalize(q.mean(axis=0))
    d = tf.quat_mul(tf.quat_conj(mean)[None], q)
    d = np.where(d[:, :1] < 0, -d, d)
    angle = 2.0 * np.arctan2(np.linalg.norm(d[:, 1:], axis=1), d[:, 0])
    vec = d[:, 1:] / np.maximum(np.linalg.norm(d[:, 1:], axis=1, keepdims=True), 1e-12) * angle[:, None]
    _, _, axes = np.linalg.svd(vec - vec.mean(axis=0), full_matrices=False)
    out = []
    for axis in axes[:2]:
        lo, hi = np.percentile(vec @ axis, [2, 98])
        out.append(float(np.degrees(hi - lo)))
    return out[0], out[1]


def centre_spread_mm(rel: np.ndarray, span_s: float) -> float:
    """How well the frames' relative rotations `rel` (N, 3, 3) fix a ball joint's centre: the
    standard error (mm) of the rigid-point fit's joint (geometry.fit_rigid_point, the calibration's
    anchor fit) for `NOISE_MM` of independent noise per frame. Its normal matrix depends on the
    rotations only, [[N I, -S], [-S^T, N I]] with S the sum of `rel`, so the joint's block of its
    inverse is (N (I - C C^T))^-1 with C their mean: infinite for one rotation or a hinge (the
    centre slides along the axis), shrinking as the swing covers two directions. N counts at most
    `INDEPENDENT_HZ` frames per second, so the figure does not depend on the stream's rate."""
    return fixed_point_spread(rel, NOISE_MM, min(len(rel), max(span_s, 1e-9) * INDEPENDENT_HZ))


def pivot_progress(rot: np.ndarray, pos: np.ndarray, span_s: float) -> tuple[StepProgress, np.ndarray | None]:
    """The controller turned about its tip (rotations `rot` (N, 3, 3) and positions `pos` (N, 3) in
    the room) toward what the calibration's pivot fit needs (calibration/touches.controller_tips):
    `PIVOT_TURN_DEG` about two directions and the tip fixed to `PIVOT_TIP_MM` (the fit's standard
    error for `PIVOT_NOISE_MM` per frame, `geometry.fixed_point_spread`), then the fit itself with
    the tip staying on its spot. Returns the progress and, once done, the tip in the controller's
    frame."""
    main, across = rotation_extent(rot)
    spread = fixed_point_spread(rot, PIVOT_NOISE_MM, min(len(rot), max(span_s, 1e-9) * INDEPENDENT_HZ))
    frac = min(main / PIVOT_TURN_DEG, across / PIVOT_TURN_DEG, PIVOT_TIP_MM / spread)
    figure = (f"controller turned {main:.0f} and {across:.0f} of {PIVOT_TURN_DEG:.0f}° about its tip, tip "
              f"±{min(spread, 999):.1f} of {PIVOT_TIP_MM:.1f} mm" + _frames_short(len(rot)))
    done = frac >= 1.0 and len(rot) >= STEP_FRAMES
    tip = None
    if done:  # the fit the calibration runs (only now)
        try:
            fit = fit_rigid_point(rot, pos, np.broadcast_to(np.eye(3), rot.shape), np.zeros_like(pos), name="pivot")
            if fit.rms * 1000.0 > PIVOT_MAX_RMS_MM:
                done, figure = False, f"{figure}; the tip moved {fit.rms * 1000:.0f} mm: keep it on one spot"
            else:
                tip = fit.local_a
        except BodyCalError as exc:
            done, figure = False, f"{figure}; {exc.message}"
    return StepProgress(min(1.0, frac) if done else min(frac, 0.99), figure, done), tip


def swing_progress(rel: np.ndarray, points: np.ndarray, joint: str, span_s: float) -> StepProgress:
    """The swing toward what the anchor fits need (DESIGN.md): the relative rotation swung `MARGIN`
    times the sphere check's main swing and swing across it (`rotation_extent`), the joint centre
    fixed to `SWING_CENTRE_MM` (`centre_spread_mm`), and then the sphere check itself passing as
    the calibration runs it (geometry.fit_sphere on the point device's origin in the frame device)."""
    main, across = rotation_extent(rel)
    spread = centre_spread_mm(rel, span_s)
    frac = min(main / SWING_TARGET_DEG, across / SWING_ACROSS_TARGET_DEG, SWING_CENTRE_MM / spread)
    figure = (f"{joint} swung {main:.0f} of {SWING_TARGET_DEG:.0f}° and {across:.0f} of {SWING_ACROSS_TARGET_DEG:g}° "
              f"across, centre ±{min(spread, 999):.1f} of {SWING_CENTRE_MM:.1f} mm" + _frames_short(len(points)))
    done = frac >= 1.0 and len(points) >= STEP_FRAMES
    if done:  # the sphere check the calibration runs (only now: it costs more than the rest)
        try:
            fit_sphere(points, name="swing", robust=False)
        except BodyCalError as exc:
            done, figure = False, f"{figure}; {exc.message}"
    return StepProgress(min(1.0, frac) if done else min(frac, 0.99), figure, done)
