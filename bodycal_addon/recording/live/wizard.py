"""`LiveWizard`: the calibration steps (FORMATS.md §2.4) run with a performer, live (DESIGN.md
"Live calibration wizard"). numpy only, no bpy: the Blender Live panel and `bodycal record
--wizard` drive the same object.

The wizard lists the steps the devices (by role) and the markers allow, in protocol order, each
with an instruction the operator reads aloud. `begin` opens the current step's segment on the
recorder (`LiveRecorder.mark_segment_start`); `update`, called at any rate, reads the frames
recorded since the step began (`LiveRecorder.frames_since`: only those, thinned to a fixed count
for the long steps, so a call costs the same early and late in a session) and measures progress
toward what the offline fit of the step needs (progress.py: holds, palms together, touches held,
the hinge's arc, the swing's extent and how well it pins the joint's centre).

With `auto`, a step whose progress is done ends by itself; a hold step then keeps only the still
stretch (its middle is the reference pose, calibration/common.py). The next step begins only
when the consumer calls `begin`, or by itself `auto_begin_s` seconds (recording clock) after the
previous ended when that is given: the operator must have time to read the instruction.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ...body import surface_layout as sl
from ...body.skeleton import FINGERS
from ...core import transforms as tf
from ...core.errors import BodyCalError
from ...core.geometry import fit_rigid_point
from ..model import Segment
from .progress import (
    HOLD_S,
    HOLD_WINDOW_S,
    MAX_FIT_FRAMES,
    MIN_STEP_FRAMES,
    PREROLL_S,
    STILL_MIN_S,
    StepProgress,
    flex_progress,
    hold_figure,
    hold_progress,
    palms_progress,
    pivot_progress,
    relative_motion,
    swing_progress,
    touch_progress,
)

if TYPE_CHECKING:  # the recorder reads VMC's segments with python-osc; the wizard runs without it
    from .recorder import LiveRecorder, RecentFrames

__all__ = ["LiveWizard", "StepProgress", "WizardStep", "plan_steps"]

TRUNK = ("chest", "pelvis", "head")
CONTROLLER_TIP_LOCAL = np.array([0.0, 0.09, 0.0])  # calibration/touches.py's, for a controller not pivoted
SIDE_WORD = {"l": "left", "r": "right"}
HEAD_POINTS = sl.JAW_POINTS + sl.SKULL_POINTS + ("skull_base_l", "skull_base_r")  # calibration/touches.py's
TORSO_LOW = ("belly_ll", "belly_lr", "belly_c3", "belly_c4", "back_low")  # calibration/touches.py TORSO_LOW


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
    out += [(p, "palm_l" if p == "chest_r" else "palm_r") for p in sl.TORSO_POINTS]
    return tuple(out)


TOUCH_PROTOCOL = _touch_protocol()


def _controller_protocol() -> tuple[tuple[str, str], ...]:
    """(point, toucher) a six-device user touches with a controller's tip (DESIGN.md §3, "Touches
    with six devices"), in the protocol's order: the arms (each by the other hand), then the legs
    with that foot up on a chair (the inner side by the other hand, the outer by the same side's)."""
    out = []
    for s, o in (("l", "r"), ("r", "l")):
        out += [(f"{p}_{s}", f"controller_tip_{o}") for p in ("wrist_top", "wrist_bottom", "elbow_in", "elbow_out")]
    for s, o in (("l", "r"), ("r", "l")):
        out += [(f"knee_in_{s}", f"controller_tip_{o}"), (f"knee_out_{s}", f"controller_tip_{s}"),
                (f"ankle_in_{s}", f"controller_tip_{o}"), (f"ankle_out_{s}", f"controller_tip_{s}")]
    return tuple(out)


CONTROLLER_PROTOCOL = _controller_protocol()


def _standing_protocol() -> tuple[tuple[str, str], ...]:
    """(point, toucher) a kit without a pelvis tracker touches with a controller's tip, standing
    (DESIGN.md §3 "The device ladder": they ride on the estimated pelvis, which the HMD carries
    while the performer stands): each hip's front and back by the other hand, then the torso's
    front by the right hand (the left chest by the left)."""
    out = []
    for s, o in (("l", "r"), ("r", "l")):
        out += [(f"hip_front_{s}", f"controller_tip_{o}"), (f"hip_back_{s}", f"controller_tip_{o}")]
    out += [(p, "controller_tip_l" if p == "chest_r" else "controller_tip_r")
            for p in ("sternum", "chest_l", "chest_r", "belly_ul", "belly_ur", "belly_ll", "belly_lr")]
    return tuple(out)


STANDING_PROTOCOL = _standing_protocol()
STANDING_POINTS = frozenset(p for p, _ in STANDING_PROTOCOL)
# the limb tracker that measures a controller-touched joint better than a touch (from the motion)
MEASURED_BY = {"wrist": "forearm", "elbow": "forearm", "knee": "shin", "ankle": "shin"}
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
    touches = []
    for point, by in TOUCH_PROTOCOL:
        if touched_role(point, have) is None:
            continue
        if by.startswith("palm_") and not (palms and f"hand_{by[-1]}" in have):
            continue  # the palm centre comes from palms_together (calibration/touches.by_track)
        if not by.startswith("palm_") and by not in markers:
            continue
        touches.append((point, by))
    touches += controller_touches(have, markers, {p for p, _ in touches})
    touches += standing_touches(have, markers, {p for p, _ in touches})
    for s in ("l", "r"):  # the tip a controller touches with, found first (calibration/touches.controller_tips)
        if any(by == f"controller_tip_{s}" for _, by in touches) and f"controller_tip_{s}" not in markers:
            steps.append(_step(f"pivot_tip_{s}"))
    steps += [_step("touch", point, by) for point, by in touches]
    return steps


def controller_touches(have, markers, touched=()) -> list[tuple[str, str]]:
    """The controller-tip touches of `CONTROLLER_PROTOCOL` the devices allow: the point's part
    tracked, the joint measured by no limb tracker (`MEASURED_BY`), no fingertip marker on the
    touching hand, the point not touched otherwise (`touched`)."""
    out = []
    for point, by in CONTROLLER_PROTOCOL:
        s, t = point[-1], by[-1]
        if point in touched or touched_role(point, have) is None or f"hand_{t}" not in have:
            continue
        if f"{MEASURED_BY[point.split('_')[0]]}_{s}" in have or f"index_tip_{t}" in markers:
            continue
        out.append((point, by))
    return out


def standing_touches(have, markers, touched=()) -> list[tuple[str, str]]:
    """The touches of `STANDING_PROTOCOL` for a kit whose pelvis is estimated (no pelvis tracker):
    both hands' devices there, no fingertip marker on the touching hand, the point not touched
    otherwise (`touched`)."""
    if "pelvis" in have or not {"head", "hand_l", "hand_r"} <= set(have):
        return []
    return [(p, by) for p, by in STANDING_PROTOCOL if p not in touched and f"index_tip_{by[-1]}" not in markers]


_TITLES = {"tpose": ("T-pose", "Stand straight, arms out to the sides at shoulder height, palms down, and hold "
                     "still."),
           "pivot_tip_l": ("Pivot the left controller's tip", "Put the tip of your left controller on one spot of a "
                           "table and keep it there while you circle the controller around it, tilting it every way, "
                           "for a few seconds."),
           "pivot_tip_r": ("Pivot the right controller's tip", "Put the tip of your right controller on one spot of "
                           "a table and keep it there while you circle the controller around it, tilting it every "
                           "way, for a few seconds."),
           "stand": ("Stand", "Stand relaxed, arms hanging by your sides, feet hip-width apart, and hold still."),
           "palms_together": ("Palms together", "Press your palms flat together in front of your chest, "
                              "fingers straight, and keep them together.")}


# How the operator names a touched point ({side}: the performer's left / right).
_POINT_WORDS = {
    "wrist_top": "the top of your {side} wrist", "wrist_bottom": "the inside of your {side} wrist",
    "elbow_in": "the inner side of your {side} elbow", "elbow_out": "the outer side of your {side} elbow",
    "shoulder_front": "the front of your {side} shoulder", "shoulder_back": "the back of your {side} shoulder",
    "hip_front": "the front of your {side} hip", "hip_back": "the back of your {side} hip",
    "knee_in": "the inner side of your {side} knee", "knee_out": "the outer side of your {side} knee",
    "ankle_in": "your {side} inner ankle bone", "ankle_out": "your {side} outer ankle bone",
    "ear": "your {side} ear", "jaw": "the corner of your {side} jaw", "chest": "the {side} side of your chest",
    "skull_base": "the base of your skull, {side} side", "upper_lip": "your upper lip", "chin": "your chin",
    "skull_top": "the top of your head", "skull_left": "the left side of your head",
    "skull_right": "the right side of your head", "skull_back": "the back of your head", "sternum": "your sternum",
    "belly_ul": "your belly, upper left", "belly_ur": "your belly, upper right", "belly_ll": "your belly, lower left",
    "belly_lr": "your belly, lower right", "back_ul": "your upper back, left", "back_ur": "your upper back, right",
    "back_low": "your lower back",
}


def point_words(point: str) -> str:
    """A touched point as the operator says it: `mcp_index_l` -> "your left index knuckle"."""
    side = SIDE_WORD.get(point[-1]) if point[-2:] in ("_l", "_r") else None
    base = point[:-2] if side else point
    if base.startswith("mcp_"):
        return f"your {side} {base[4:]} knuckle"
    for part in ("palm", "sole", "belly_c"):
        if base.startswith(part) and base[len(part):].lstrip("_").isdigit():
            where = {"palm": f"your {side} palm", "sole": f"the sole of your {side} foot",
                     "belly_c": "the middle of your belly"}[part]
            return f"{where}, point {base[len(part):].lstrip('_')}"
    return _POINT_WORDS.get(base, point.replace("_", " ")).format(side=side)


def _step(step: str, point: str | None = None, by: str | None = None) -> WizardStep:
    if step in _TITLES:
        return WizardStep(step, None, None, *_TITLES[step])
    if step == "touch":
        where = point_words(point)
        if by.startswith("palm_"):
            finger = f"the palm of your {SIDE_WORD[by[-1]]} hand"
        elif by.startswith("controller_tip_"):
            finger = f"the tip of your {SIDE_WORD[by[-1]]} controller"
        elif "_tip_" in by:
            name, side = by.split("_tip_")
            finger = f"your {SIDE_WORD.get(side, side)} {name} fingertip"
        else:
            finger = by.replace("_", " ")
        title = "Touch " + where.replace("your ", "the ", 1)
        text = f"put {finger} on {where} and hold it there for a moment."
        if by.startswith("controller_tip_") and point in STANDING_POINTS:
            return WizardStep(step, point, by, title, f"Standing still, {text}")
        if by.startswith("controller_tip_") and point.startswith(("knee_", "ankle_", "elbow_", "wrist_")):
            posture = (f"your {SIDE_WORD[point[-1]]} foot up on a chair" if point.startswith(("knee_", "ankle_"))
                       else f"your {SIDE_WORD[point[-1]]} elbow bent in front of you")
            return WizardStep(step, point, by, title, f"With {posture}, {text}")
        return WizardStep(step, point, by, title, text[0].upper() + text[1:])
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
        self.tips: dict[str, np.ndarray] = {}  # side -> controller tip found by its pivot step (controller's frame)
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
        if step.step.startswith("pivot_tip_"):  # the tip the next touches are read with
            _, tip = self._pivot(self.recorder.frames_since(self._began_at, max_frames=MAX_FIT_FRAMES), step.step[-1],
                                 force=True)
            if tip is not None:
                self.tips[step.step[-1]] = tip
        # a hold keeps its still stretch only: the reference pose is its middle
        seg = self.recorder.mark_segment_end(trim if trim is not None and trim < self.recorder.now else None)
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
                return hold_figure(0.0, HOLD_S, "waiting for both gloves").with_figure("palms together")
            return palms_progress(frames, hands, pairs, begin=self._began_at)
        if step.step == "touch":
            # a point on an estimated device (no pelvis tracker): the HMD carries it (calibration/
            # estimated_devices.attach)
            part = self._slot(frames, touched_role(step.point, self.device_of) or
                              ("head" if step.point in STANDING_POINTS else ""))
            track = self._toucher(frames, step.by)
            if part is None or track is None:
                return hold_figure(0.0, STILL_MIN_S, f"waiting for {step.by}")
            return touch_progress(frames, part, *track, begin=self._began_at)
        if step.step.startswith("pivot_tip_"):
            return self._pivot(frames, step.step[-1])[0]
        pair = motion_pair(step.step, self.device_of)  # None: its devices lost their roles (replan)
        a, b = (self._slot(frames, pair[0]), self._slot(frames, pair[1])) if pair else (None, None)
        if a is None or b is None:
            rel, pts = np.zeros((0, 3, 3)), np.zeros((0, 3))
        else:
            rel, pts = relative_motion(frames, a, b)
        joint = step.step.split("_")[1]
        if step.step.startswith("flex"):
            return flex_progress(rel, joint)
        return swing_progress(rel, pts, joint, float(frames.time[-1] - frames.time[0]) if frames.count else 0.0)

    def _pivot(self, frames: RecentFrames, s: str, force: bool = False):
        """(progress, tip) of a pivot step on `frames` (progress.pivot_progress); with `force`, the
        tip whenever the fit can give one (the operator ended the step)."""
        k = self._slot(frames, f"hand_{s}")
        if k is None or frames.count == 0:
            return hold_figure(0.0, 1.0, f"waiting for the {SIDE_WORD[s]} controller").with_figure("pivot"), None
        ok = frames.valid[:, k]
        rot = tf.quat_to_matrix(tf.quat_normalize(frames.rotations[ok, k]))
        pos = frames.positions[ok, k]
        span = float(frames.time[-1] - frames.time[0])
        progress, tip = pivot_progress(rot, pos, span)
        if tip is None and force and len(pos) >= MIN_STEP_FRAMES:
            try:
                tip = fit_rigid_point(rot, pos, np.broadcast_to(np.eye(3), rot.shape), np.zeros_like(pos),
                                      name="pivot").local_a
            except BodyCalError:
                tip = None
        return progress, tip

    def _toucher(self, frames: RecentFrames, by: str) -> tuple[np.ndarray, np.ndarray] | None:
        """World track and validity of the touching point: its marker, the palm's hand device (the
        palm centre rides on it), or a controller's tip (its pivot's, else the calibration's
        default: a still controller holds any of its points still)."""
        if by in frames.marker_names:
            k = frames.marker_names.index(by)
            return frames.points[:, k], frames.points_valid[:, k]
        if by.startswith("controller_tip_"):
            k = self._slot(frames, f"hand_{by[-1]}")
            if k is None:
                return None
            tip = self.tips.get(by[-1], CONTROLLER_TIP_LOCAL)
            return (tf.transform_points(frames.positions[:, k], tf.quat_normalize(frames.rotations[:, k]), tip),
                    frames.valid[:, k])
        if by.startswith("palm_"):
            k = self._slot(frames, f"hand_{by[-1]}")
            return None if k is None else (frames.positions[:, k], frames.valid[:, k])
        return None
