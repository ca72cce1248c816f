"""`LiveWizard`: the calibration steps (FORMATS.md §2.4) run with a performer, live (DESIGN.md
"Live calibration wizard"). numpy only, no bpy: the Blender Live panel and `bodycal record
--wizard` drive the same object.

The wizard lists the steps the devices (by role) and the markers allow, in protocol order, each
with an instruction the operator reads aloud. `begin` opens the current step's segment on the
recorder (`LiveRecorder.mark_segment_start`); `update`, called at any rate, reads the frames
recorded since the step began (`LiveRecorder.frames_since`: only those, thinned to a fixed count
for the long steps, so a call costs the same early and late in a session) and measures progress
toward what the offline fit needs:

- tpose, stand: every device held still for `HOLD_S`;
- palms_together: the palms together (paired glove markers within `PALMS_GAP_M`) for `HOLD_S`;
- flex_*: the arc the hinge swept, from the two devices' relative rotations (the calibration's
  own axis fit, `geometry.fit_rotation_axis`);
- swing_*: the swing's extent along and across its main direction, and how well it fixes the
  joint's centre (`centre_spread_mm`), then the sphere check the calibration runs;
- touch: the touching marker held still relative to the touched part's device (and the room) for
  the calibration's `STILL_MIN_S`.

With `auto`, a step whose progress is done ends by itself; a hold step then keeps only the still
stretch (its middle is the reference pose, calibration/common.py). The next step begins only
when the consumer calls `begin`, or by itself `auto_begin_s` seconds (recording clock) after the
previous ended when that is given: the operator must have time to read the instruction.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ...core import transforms as tf
from ...core.errors import BodyCalError
from ...core.geometry import MIN_ARC_DEG, MIN_SWING_DEG, MIN_SWING_MINOR_DEG, fit_rotation_axis, fit_sphere
from ..model import Segment
from .recorder import LiveRecorder, RecentFrames
from .vmc import check_segment

# --- what the offline calibration needs (thresholds; DESIGN.md "Live calibration wizard") ----------
STILL_SPEED = 0.05  # m/s, calibration/touches.py STILL_SPEED: slower than this counts as still
STILL_MIN_S = 0.2  # s, calibration/touches.py STILL_MIN_S: a touch held this long is usable
MEDIAN_S = 0.15  # s, calibration/touches.py MEDIAN_S: positions are median-filtered over this before speeds
MIN_STEP_FRAMES = 20  # calibration/common.py MIN_STEP_FRAMES: a flex / swing needs this many frames
HOLD_S = 0.5  # s a reference pose is held still: the calibration averages +-0.1 s around its middle
PALMS_GAP_M = 0.10  # m: paired glove LEDs closer than this on average = palms together (DESIGN.md)
MARGIN = 1.5  # the wizard asks this much more motion than the fits refuse below (see DESIGN.md)
FLEX_TARGET_DEG = MARGIN * MIN_ARC_DEG  # 60 deg
SWING_TARGET_DEG = MARGIN * MIN_SWING_DEG  # 60 deg main swing
SWING_ACROSS_TARGET_DEG = MARGIN * MIN_SWING_MINOR_DEG  # 22.5 deg across it
SWING_CENTRE_MM = 3.0  # a swing is done once it fixes the joint centre to this (centre_spread_mm)
NOISE_MM = 3.0  # tracker noise and soft-tissue wobble per frame assumed by centre_spread_mm
INDEPENDENT_HZ = 20.0  # frames closer than 1/20 s share their wobble: they count as one
MAX_FIT_FRAMES = 600  # a flex / swing window is thinned to this many frames (update() stays cheap)
HOLD_WINDOW_S = 2.0 * HOLD_S  # a hold or touch reads only the last this many seconds
PREROLL_S = 2.0 * MEDIAN_S  # frames read from before the step began, so its first frames have a speed

TRUNK = ("chest", "pelvis", "head")
SIDES = ("l", "r")
SIDE_WORD = {"l": "left", "r": "right"}
HEAD_POINTS = ("ear_l", "ear_r", "upper_lip", "chin", "jaw_l", "jaw_r", "skull_top", "skull_left", "skull_right",
               "skull_back", "skull_base_l", "skull_base_r")  # calibration/touches.py HEAD_POINTS
TORSO_LOW = ("belly_ll", "belly_lr", "belly_c3", "belly_c4", "back_low")  # calibration/touches.py TORSO_LOW
FINGERS = ("thumb", "index", "middle", "ring", "pinky")


def _touch_protocol() -> tuple[tuple[str, str], ...]:
    """(point, toucher) in the protocol's order (the sample take's, FORMATS.md §2.4): each hand by
    the other index tip, the arms, the legs, the head, then the torso by a palm."""
    out = []
    for s, o in (("l", "r"), ("r", "l")):
        out += [(f"wrist_top_{s}", f"index_tip_{o}"), (f"wrist_bottom_{s}", f"index_tip_{o}")]
        out += [(f"mcp_{f}_{s}", f"index_tip_{o}") for f in FINGERS]
        out += [(f"palm_{k}_{s}", f"index_tip_{o}") for k in range(1, 5)]
    for s, o in (("l", "r"), ("r", "l")):
        out += [(f"{p}_{s}", f"index_tip_{o}") for p in ("elbow_in", "elbow_out", "shoulder_front", "shoulder_back")]
    for s, o in (("l", "r"), ("r", "l")):
        out += [(f"{p}_{s}", f"index_tip_{o}") for p in ("hip_front", "hip_back", "knee_in", "knee_out", "ankle_in",
                                                         "ankle_out", "sole_1", "sole_2", "sole_3", "sole_4")]
    out += [(p, "index_tip_l" if p.endswith("_r") else "index_tip_r") for p in HEAD_POINTS]
    out += [(p, "palm_l" if p == "chest_r" else "palm_r") for p in
            ("sternum", "chest_l", "chest_r", "belly_ul", "belly_ur", "belly_ll", "belly_lr", "belly_c1", "belly_c2",
             "belly_c3", "belly_c4", "back_ul", "back_ur", "back_low")]
    return tuple(out)


TOUCH_PROTOCOL = _touch_protocol()
MOTION_STEPS = ("flex_elbow_l", "flex_elbow_r", "flex_knee_l", "flex_knee_r", "swing_shoulder_l", "swing_shoulder_r",
                "swing_hip_l", "swing_hip_r")


@dataclass(frozen=True)
class WizardStep:
    step: str  # FORMATS §2.4 step name
    point: str | None  # touch: the body point
    by: str | None  # touch: the touching marker / device tip
    title: str  # short, e.g. "Flex the left elbow"
    instruction: str  # one or two sentences the operator reads aloud to the performer

    @property
    def label(self) -> str:
        return ":".join(p for p in (self.step, self.point, self.by) if p)


@dataclass(frozen=True)
class StepProgress:
    fraction: float  # 0..1 toward automatic completion
    figure: str  # one line: "elbow bent through 34 of 60°", "hold still 0.3 of 0.5 s"
    done: bool  # enough data is in
    still_from: float | None = None  # hold steps: when the still stretch began (recording clock)

    def with_figure(self, what: str) -> StepProgress:
        """The same progress with the figure's first words (`hold still`) replaced."""
        return StepProgress(self.fraction, self.figure.replace("hold still", what, 1), self.done, self.still_from)


# --- which steps the devices allow --------------------------------------------------------------------


def _first(have, names) -> str | None:
    return next((n for n in names if n in have), None)


def motion_pair(step: str, have) -> tuple[str, str] | None:
    """(frame role, point role): the device whose origin a flex / swing step's fit follows in the
    other's frame, as the calibration fits it (calibration/limbs.py): the limb's own trackers, else
    the end device (hand / foot) in the trunk's frame; None when the roles present cannot give it."""
    kind, joint, s = step.split("_")
    if kind == "flex" and joint == "elbow":
        if f"forearm_{s}" in have:
            other = f"upperarm_{s}" if f"upperarm_{s}" in have else _first(have, TRUNK)
            return (f"forearm_{s}", other) if other else None
        trunk = _first(have, TRUNK)
        return (trunk, f"hand_{s}") if trunk and f"hand_{s}" in have else None
    if kind == "flex":  # knee
        if f"shin_{s}" in have:
            other = f"thigh_{s}" if f"thigh_{s}" in have else _first(have, ("pelvis",))
            return (f"shin_{s}", other) if other else None
        return ("pelvis", f"foot_{s}") if "pelvis" in have and f"foot_{s}" in have else None
    if joint == "shoulder":
        if f"upperarm_{s}" in have:
            root = _first(have, ("chest", "pelvis"))
            return (f"upperarm_{s}", root) if root else None
        trunk = _first(have, TRUNK)
        return (trunk, f"hand_{s}") if trunk and f"hand_{s}" in have else None
    if f"thigh_{s}" in have:  # hip
        return (f"thigh_{s}", "pelvis") if "pelvis" in have else None
    return ("pelvis", f"foot_{s}") if "pelvis" in have and f"foot_{s}" in have else None


def touched_role(point: str, have) -> str | None:
    """The device a touched point rides on (mirrors calibration/touches.touched_role, which a test
    keeps in step), or None when it is not present."""
    s = point[-1] if point[-2:] in ("_l", "_r") else None
    if point.startswith(("wrist_", "mcp_", "palm_")):
        role = f"hand_{s}"
    elif point.startswith(("sole_", "ankle_")):
        role = f"foot_{s}"
    elif point.startswith("elbow_"):
        role = f"forearm_{s}" if f"forearm_{s}" in have else f"hand_{s}"
    elif point.startswith("knee_"):
        role = f"shin_{s}" if f"shin_{s}" in have else f"foot_{s}"
    elif point.startswith("shoulder_"):
        role = f"upperarm_{s}" if f"upperarm_{s}" in have else ("chest" if "chest" in have else "pelvis")
    elif point.startswith("hip_"):
        role = f"thigh_{s}" if f"thigh_{s}" in have else "pelvis"
    elif point in HEAD_POINTS:
        role = "head"
    elif point in TORSO_LOW:
        role = "pelvis" if "pelvis" in have else "chest"
    else:
        role = "chest" if "chest" in have else "pelvis"
    return role if role in have else None


def palm_pairs(markers) -> list[str]:
    """The glove markers present on both hands (calibration/hands.py palms_together needs three)."""
    names = [f"hand_led{k}" for k in (1, 2, 3)] + [f"{f}_tip" for f in FINGERS]
    return [n for n in names if f"{n}_l" in markers and f"{n}_r" in markers]


def plan_steps(roles: Sequence[str], markers: Sequence[str] = ()) -> list[WizardStep]:
    """The steps the device roles and markers allow, in protocol order (module docstring)."""
    have, markers = set(roles), set(markers)
    steps = [_step("tpose"), _step("stand")]
    palms = len(palm_pairs(markers)) >= 3 and {"hand_l", "hand_r"} <= have
    if palms:
        steps.append(_step("palms_together"))
    steps += [_step(s) for s in MOTION_STEPS if motion_pair(s, have)]
    for point, by in TOUCH_PROTOCOL:
        if touched_role(point, have) is None:
            continue
        if by.startswith("palm_") and not (palms and f"hand_{by[-1]}" in have):
            continue  # the palm centre comes from palms_together (calibration/touches.by_track)
        if not by.startswith("palm_") and by not in markers:
            continue
        steps.append(_step("touch", point, by))
    return steps


_TITLES = {"tpose": ("T-pose", "Stand straight, arms out to the sides at shoulder height, palms down, and hold "
                     "still."),
           "stand": ("Stand", "Stand relaxed, arms hanging by your sides, feet hip-width apart, and hold still."),
           "palms_together": ("Palms together", "Press your palms flat together in front of your chest, "
                              "fingers straight, and keep them together.")}


def _step(step: str, point: str | None = None, by: str | None = None) -> WizardStep:
    if step in _TITLES:
        return WizardStep(step, None, None, *_TITLES[step])
    if step == "touch":
        where = point.replace("_", " ")
        if by.startswith("palm_"):
            finger = f"the palm of your {SIDE_WORD[by[-1]]} hand"
        elif "_tip_" in by:
            name, side = by.split("_tip_")
            finger = f"your {SIDE_WORD.get(side, side)} {name} fingertip"
        else:
            finger = by.replace("_", " ")
        return WizardStep(step, point, by, f"Touch {where}",
                          f"Put {finger} on your {where} and hold it there for a moment.")
    kind, joint, s = step.split("_")
    side = SIDE_WORD[s]
    if kind == "flex":
        limb = "upper arm" if joint == "elbow" else "thigh"
        text = (f"Keep your {side} {limb} still and bend your {side} {joint} as far as it goes, then straighten it, "
                "two or three times.")
        return WizardStep(step, None, None, f"Flex the {side} {joint}", text)
    limb = "arm" if joint == "shoulder" else "leg"
    text = (f"Keep your {side} {limb} straight and swing it from the {joint} forward and back, then out to the "
            "side and around in a wide circle; keep the rest of the body still.")
    return WizardStep(step, None, None, f"Swing the {side} {joint}", text)


# --- progress measures (numpy on the frames since the step began) -------------------------------------


def _median_filter(x: np.ndarray, w: int) -> np.ndarray:
    from numpy.lib.stride_tricks import sliding_window_view

    if len(x) < w:
        return np.repeat(np.median(x, axis=0, keepdims=True), len(x), axis=0)
    pad = w // 2
    xp = np.concatenate([np.repeat(x[:1], pad, 0), x, np.repeat(x[-1:], pad, 0)])
    return np.median(sliding_window_view(xp, w, axis=0), axis=-1)


def speeds(track: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Speed (m/s) of each frame of a (F, ..., 3) track after a `MEDIAN_S` running median, over the
    same span as the calibration's (two half windows, calibration/touches.py) but backward, ending
    at the frame: the newest frame has a speed now, which a centred difference would only give
    half a window later; (F, ...), infinite for the first frames (no span before them)."""
    if len(t) < 2:
        return np.full(track.shape[:-1], np.inf)
    fps = (len(t) - 1) / max(t[-1] - t[0], 1e-9)
    w = max(3, int(round(MEDIAN_S * fps)) | 1)
    smooth = _median_filter(track, w)
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


def _hold(held: float, need: float, extra: str = "", still_from: float | None = None) -> StepProgress:
    fig = f"hold still {min(held, need):.1f} of {need:.1f} s" + (f" ({extra})" if extra else "")
    return StepProgress(min(1.0, held / need), fig, held >= need - 1e-9, still_from)


def hold_progress(frames: RecentFrames, slots: list[int], names: list[str], need: float = HOLD_S,
                  begin: float = -np.inf) -> StepProgress:
    """The devices `slots` all tracked and slower than `STILL_SPEED` up to the newest frame (frames
    before `begin` give speeds, not held time)."""
    if not slots or frames.count < 2:
        return _hold(0.0, need, "waiting for the devices")
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
    return _hold(held, need, extra, since)


def palms_progress(frames: RecentFrames, hands: tuple[int, int], pairs: list[tuple[int, int]],
                   begin: float = -np.inf) -> StepProgress:
    """Both hands tracked with the palms together (paired glove markers within `PALMS_GAP_M` on
    average) for `HOLD_S`. **Decision**: not held still: the palm planes are fitted to the pairs'
    midpoints in each hand's frame (calibration/hands.py), which palms sliding on each other keep
    on the plane (the sample take's hands slide at 0.05-0.2 m/s)."""
    if frames.count < 2:
        return _hold(0.0, HOLD_S, "waiting for the devices")
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
    return _hold(held, HOLD_S, extra, since).with_figure("palms together")


def touch_progress(frames: RecentFrames, part: int, by_track: np.ndarray, by_valid: np.ndarray,
                   begin: float = -np.inf) -> StepProgress:
    """The touching point still relative to the touched part's device (or to the room, whichever is
    slower, as the calibration reads a touch) for `STILL_MIN_S`."""
    if frames.count < 2:
        return _hold(0.0, STILL_MIN_S, "waiting for the devices")
    ok = frames.valid[:, part] & by_valid
    local = tf.inverse_transform_points(frames.positions[:, part], frames.rotations[:, part], by_track)
    speed = np.minimum(speeds(local, frames.time), speeds(by_track, frames.time))
    still = ok & (speed < STILL_SPEED) & (frames.time >= begin)
    held, since = trailing_run(still, frames.time)
    extra = "" if still[-1] else ("not tracked" if not ok[-1] else f"moving {speed[-1]:.2f} m/s")
    return _hold(held, STILL_MIN_S, extra, since)


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
    done = arc >= FLEX_TARGET_DEG and len(rel) >= MIN_STEP_FRAMES
    figure = f"{joint} bent through {arc:.0f} of {FLEX_TARGET_DEG:.0f}°" + _frames_short(len(rel))
    return StepProgress(min(1.0, arc / FLEX_TARGET_DEG), figure, done)


def _frames_short(n: int) -> str:
    return f" ({n} of {MIN_STEP_FRAMES} frames)" if n < MIN_STEP_FRAMES else ""


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
    if len(rel) < 2:
        return float("inf")
    c = rel.mean(axis=0)
    w = np.linalg.eigvalsh(np.eye(3) - c @ c.T)
    if w[0] <= 1e-12:
        return float("inf")
    n = min(len(rel), max(span_s, 1e-9) * INDEPENDENT_HZ)
    return float(NOISE_MM * np.sqrt(np.sum(1.0 / w) / n))


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
    done = frac >= 1.0 and len(points) >= MIN_STEP_FRAMES
    if done:  # the sphere check the calibration runs (only now: it costs more than the rest)
        try:
            fit_sphere(points, name="swing", robust=False)
        except BodyCalError as exc:
            done, figure = False, f"{figure}; {exc.message}"
    return StepProgress(min(1.0, frac) if done else min(frac, 0.99), figure, done)


# --- the wizard ------------------------------------------------------------------------------------------


class LiveWizard:
    """The calibration steps with a performer (module docstring). `roles`: device name -> role (the
    user's, or what the stream announced); `markers`: the marker names the stream has (touch steps
    and palms_together need them). With `auto`, a step ends by itself once its progress is done;
    with `auto_begin_s`, the next step begins by itself that many seconds after the previous ended
    (recording clock), else when `begin` is called."""

    def __init__(self, recorder: LiveRecorder, roles: dict[str, str], markers: Sequence[str] = (), *,
                 auto: bool = True, auto_begin_s: float | None = None):
        self.recorder = recorder
        self.roles = dict(roles)
        self.device_of = {r: n for n, r in self.roles.items()}
        self.markers = list(markers)
        self.auto = auto
        self.auto_begin_s = auto_begin_s
        self.steps: list[WizardStep] = plan_steps(list(self.device_of), self.markers)
        self.index = 0
        self.active = False
        self.progress: StepProgress | None = None
        self.segments: dict[int, Segment] = {}  # step index -> the segment it kept
        self.completed: dict[int, str] = {}  # step index -> "auto", "ended" or "skipped"
        self._began_at = 0.0
        # with auto_begin_s, the first step waits its pause from now too
        self._ended_at: float | None = recorder.now if auto_begin_s is not None else None

    # --- state ---

    @property
    def current(self) -> WizardStep | None:
        return self.steps[self.index] if self.index < len(self.steps) else None

    @property
    def finished(self) -> bool:
        return self.index >= len(self.steps)

    def replan(self, roles: dict[str, str], markers: Sequence[str] = ()) -> None:
        """New roles or markers (roles found from the T-pose, a device or glove seen late): the steps
        still to come are planned again; those done, skipped or being recorded stay."""
        self.roles = dict(roles)
        self.device_of = {r: n for n, r in self.roles.items()}
        self.markers = list(markers)
        keep = self.index + (1 if self.active else 0)
        done = {s.label for s in self.steps[:keep]}
        self.steps = self.steps[:keep] + [s for s in plan_steps(list(self.device_of), self.markers)
                                          if s.label not in done]

    # --- the operator ---

    def begin(self) -> None:
        """Start recording the current step now (its segment opens on the recorder)."""
        step = self.current
        if step is None:
            raise BodyCalError("the calibration wizard has no step left", hint="save the take or redo a step")
        if self.active:
            return
        self._began_at = self.recorder.mark_segment_start(step.step, step.point, step.by)
        self.active = True
        self.progress = None

    def update(self) -> StepProgress | None:
        """Progress of the current step from the frames since it began; with `auto`, ends it when
        done (and with `auto_begin_s`, begins the next step when its pause is over). None when no
        step is being recorded."""
        if not self.active:
            if (self.auto_begin_s is not None and not self.finished and self._ended_at is not None
                    and self.recorder.now - self._ended_at >= self.auto_begin_s):
                self.begin()
            else:
                return None
        self.progress = self.measure()
        if self.auto and self.progress.done:
            self._finish("auto", trim=self.progress.still_from)
        return self.progress

    def end_step(self) -> None:
        """The operator ends the current step now: its segment is kept as recorded."""
        if not self.active:
            raise BodyCalError("no calibration step is being recorded", hint="begin the step first")
        self._finish("ended")

    def skip_step(self) -> None:
        """Leave the current step out (no segment) and go to the next."""
        if self.finished:
            return
        if self.active:
            self.recorder.cancel_segment()
            self.active = False
        self.completed[self.index] = "skipped"
        self.index += 1
        self._ended_at = self.recorder.now
        self.progress = None

    def redo_step(self) -> None:
        """Drop the current step's recording (when active) or, when none is being recorded, the
        previous step's segment, and make that step current again (it begins as any step does)."""
        if self.active:
            self.recorder.cancel_segment()
            self.active = False
        elif self.index > 0:
            self.index -= 1
            seg = self.segments.pop(self.index, None)
            if seg is not None:
                self.recorder.remove_segment(seg)
        else:
            return
        self.completed.pop(self.index, None)
        self._ended_at = self.recorder.now
        self.progress = None

    def status_line(self) -> str:
        """One line for a status bar / the command line."""
        if self.finished:
            kept = len(self.segments)
            return f"calibration wizard finished: {kept} of {len(self.steps)} steps recorded"
        step = self.current
        head = f"step {self.index + 1}/{len(self.steps)} {step.title}"
        if not self.active:
            return head + ": ready (begin when the performer is)"
        return head + (f": {self.progress.figure}" if self.progress else ": recording")

    # --- internals ---

    def _finish(self, how: str, trim: float | None = None) -> None:
        step = self.current
        if trim is not None and trim > self._began_at and trim < self.recorder.now:
            # a hold keeps its still stretch only: the reference pose is its middle
            self.recorder.cancel_segment()
            seg = self.recorder.add_segment(check_segment(step.step, step.point, step.by, trim, self.recorder.now))
        else:
            seg = self.recorder.mark_segment_end()
        self.segments[self.index] = seg
        self.completed[self.index] = how
        self.active = False
        self.index += 1
        self._ended_at = self.recorder.now

    def _slot(self, frames: RecentFrames, role: str) -> int | None:
        name = self.device_of.get(role)
        return frames.names.index(name) if name in frames.names else None

    def measure(self) -> StepProgress:
        """The current step's progress from the frames since it began (module docstring)."""
        step = self.current
        rec = self.recorder
        if step.step in ("tpose", "stand", "palms_together", "touch"):
            frames = rec.frames_since(max(self._began_at, rec.now - HOLD_WINDOW_S) - PREROLL_S)
        else:
            frames = rec.frames_since(self._began_at, max_frames=MAX_FIT_FRAMES)
        if step.step in ("tpose", "stand"):
            # every device tracked now, with a role or not yet (the T-pose is where roles are found)
            slots = [k for k in range(len(frames.names)) if frames.count and frames.valid[-1, k]]
            return hold_progress(frames, slots, [frames.names[k] for k in slots], begin=self._began_at)
        if step.step == "palms_together":
            hands = (self._slot(frames, "hand_l"), self._slot(frames, "hand_r"))
            pairs = [(frames.marker_names.index(f"{n}_l"), frames.marker_names.index(f"{n}_r"))
                     for n in palm_pairs(frames.marker_names)]
            if None in hands or len(pairs) < 3:
                return _hold(0.0, HOLD_S, "waiting for both gloves")
            return palms_progress(frames, hands, pairs, begin=self._began_at)
        if step.step == "touch":
            part = self._slot(frames, touched_role(step.point, self.device_of) or "")
            track = self._toucher(frames, step.by)
            if part is None or track is None:
                return _hold(0.0, STILL_MIN_S, f"waiting for {step.by}")
            return touch_progress(frames, part, *track, begin=self._began_at)
        frame_role, point_role = motion_pair(step.step, self.device_of)
        a, b = self._slot(frames, frame_role), self._slot(frames, point_role)
        if a is None or b is None:
            rel, pts = np.zeros((0, 3, 3)), np.zeros((0, 3))
        else:
            rel, pts = relative_motion(frames, a, b)
        joint = step.step.split("_")[1]
        if step.step.startswith("flex"):
            return flex_progress(rel, joint)
        return swing_progress(rel, pts, joint, float(frames.time[-1] - frames.time[0]) if frames.count else 0.0)

    def _toucher(self, frames: RecentFrames, by: str) -> tuple[np.ndarray, np.ndarray] | None:
        """World track and validity of the touching point: its marker, or the palm's hand device
        (the palm centre rides on it)."""
        if by in frames.marker_names:
            k = frames.marker_names.index(by)
            return frames.points[:, k], frames.points_valid[:, k]
        if by.startswith("palm_"):
            k = self._slot(frames, f"hand_{by[-1]}")
            return None if k is None else (frames.positions[:, k], frames.valid[:, k])
        return None
