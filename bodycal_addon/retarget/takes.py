"""A take: what a session reads from a pose source, in numpy (DESIGN.md §1, "One session path").

A take names itself (the baked action's name starts with it), says at what rate its samples come
and at which scene frame its first sample is (keys land on the frames its source plays at: a
recording's import mapping, a character action's own frames), carries the notes its reading made
(said once, when it is read), can be limited to a frame range (`window`: the pipeline then
sees, and looks ahead, only within it), and turns itself into an avatar's animation by the
pipeline. The glue (`blender/session.py`) reads a take, computes each target's animation from it
(nothing of the scene: a worker thread may run it), then bakes; it never asks which kind of take
it holds.

- `RecordingTake`: a tracker recording of a calibrated performer (`pipeline.retarget`), smoothed by
  the One Euro filter first when asked (on a copy: the recording itself is not changed).
- `CharacterTake`: another character's action (`transfer.transfer`): its body model (measured on
  its mesh, or estimated from its bone lengths) and its pose-bone values per frame, smoothed by the
  One Euro filter first when asked (its bones' rotations and locations, on a copy).
Anything with these attributes and methods is one more kind. A live stream is not a take (no end to
look ahead to, no keys): it shares the prepared solver and the pose's carrying with the bake
(DESIGN.md "A file take and a live stream", bodycal_addon/live/).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import ClassVar, Protocol

import numpy as np

from ..avatar.estimate import ESTIMATED
from ..body.animation import AvatarAnimation
from ..body.bodymodel import BodyModel
from ..core.errors import BodyCalError
from ..recording.filters import DEFAULT_FILTER, OneEuro, filter_pose, filter_recording
from ..recording.model import Recording
from .methods import check_method
from .pipeline import PreparedTake, prepare_recording, retarget
from .placement import rig_matrix
from .pose_source import AnimationSource, PoseSource, RecordingSource
from .transfer import prepare_transfer, source_in_play_area, transfer

FALLBACK_RATE = 30.0  # a one-frame take has no rate of its own
FRAME_EPS = 1e-3  # a sample this close to a range's end frame is in the range


def window_slice(time: np.ndarray, rate: float, frame_start: float, first: float, last: float,
                 source: str) -> tuple[slice, float]:
    """(the samples at scene frames first..last, the frame of the first of them) of a take whose
    sample k plays at frame_start + (t_k - t_0) x rate; one BodyCalError when none is."""
    frames = frame_start + (np.asarray(time, float) - float(time[0])) * rate
    lo = int(np.searchsorted(frames, first - FRAME_EPS, side="left"))
    hi = int(np.searchsorted(frames, last + FRAME_EPS, side="right"))
    if hi <= lo:
        raise BodyCalError(f"the frame range {first:g}-{last:g} holds none of the take's frames "
                           f"({frames[0]:g}-{frames[-1]:g})", source=source, field="frame range",
                           hint="pick a frame range that overlaps the take")
    return slice(lo, hi), float(frames[lo])


class Take(Protocol):
    kind: ClassVar[str]  # "recording" | "animation" (methods.SOURCE_KINDS)
    name: str  # the take's name: baked actions are named "<take>|<armature>|<method>"
    notes: list[str]  # what reading it found, one line each
    frame_start: float  # the scene frame of its first sample: sample k at frame_start + (t_k - t_0) x rate

    @property
    def rate(self) -> float:
        """Scene frames per second of the take's time: sample k plays at frame_start + (t_k - t_0) x rate."""

    @property
    def sample_rate(self) -> float:
        """Samples per second (the rate, unless the take was imported timed to another scene rate)."""

    def window(self, first: float, last: float) -> Take:
        """The take limited to its samples at scene frames first..last (both included)."""

    def animate(self, avatar: BodyModel, method: str, *, plant_feet: bool = True, placement: str = "object",
                progress: Callable[[float], None] | None = None,
                cancel: Callable[[], bool] | None = None) -> AvatarAnimation:
        """The avatar's animation (pure numpy). Bad input raises one BodyCalError."""

    def prepare(self, avatar: BodyModel, method: str, *, plant_feet: bool = True, placement: str = "object"
                ) -> PreparedTake:
        """`animate` prepared once, to be solved a few frames at a time (the timeline preview):
        `solve(start, stop)` gives the values `animate` gives for those frames."""

    def release(self) -> None:
        """Let go of the source's arrays: nothing will be computed from this take any more."""

    def pose_source(self, placement: str = "object") -> PoseSource:
        """The pose source `animate` computes from (smoothed as it is, in its play area): what a
        bake's review reads of the source (output/review.py)."""


@dataclass
class RecordingTake:
    kind: ClassVar[str] = "recording"
    recording: Recording
    user: BodyModel
    filter: OneEuro | None = DEFAULT_FILTER  # One Euro on the devices before retargeting (None: as recorded)
    notes: list[str] = field(default_factory=list)
    frame_start: float = 1.0  # the import's mapping (recording_scene); a file's take starts at frame 1
    frame_rate: float | None = None  # the frames' rate when not the recording's own (a window keeps its take's)
    seat_height: float | None = None  # a seated performer without foot trackers: the seat's height (lower_body)
    # the smoothed recording and the filter it was made with: `animate` and then the review read it once
    _smoothed: tuple | None = field(default=None, init=False, repr=False, compare=False)

    def __post_init__(self):
        self.name = self.recording.name

    @property
    def rate(self) -> float:
        if self.frame_rate is not None:
            return self.frame_rate
        return self.sample_rate

    @property
    def sample_rate(self) -> float:
        rec = self.recording
        return rec.fps if rec.frame_count > 1 else FALLBACK_RATE

    def window(self, first: float, last: float) -> RecordingTake:
        rec = self.recording
        part, start = window_slice(rec.time, self.rate, self.frame_start, first, last, rec.source or rec.name)
        return replace(self, recording=rec.window(part.start, part.stop), notes=list(self.notes), frame_start=start,
                       frame_rate=self.rate)

    def animate(self, avatar, method, *, plant_feet=True, placement="object", progress=None, cancel=None):
        check_method(method, self.kind)
        return retarget(self._filtered(), self.user, avatar, method, progress=progress, cancel=cancel,
                        plant_feet=plant_feet, placement=placement, seat_height=self.seat_height)

    def prepare(self, avatar, method, *, plant_feet=True, placement="object"):
        check_method(method, self.kind)
        return prepare_recording(self._filtered(), self.user, avatar, method, plant_feet=plant_feet,
                                 placement=placement, seat_height=self.seat_height)

    def _filtered(self) -> Recording:
        if self.filter is None:
            return self.recording
        if self._smoothed is None or self._smoothed[0] is not self.filter or self._smoothed[1] is not self.recording:
            self._smoothed = (self.filter, self.recording, filter_recording(self.recording, self.filter))
        return self._smoothed[2]

    def pose_source(self, placement="object") -> RecordingSource:
        return RecordingSource(self._filtered(), self.user, seat_height=self.seat_height)

    def release(self) -> None:
        self.recording = None
        self._smoothed = None


@dataclass
class CharacterTake:
    """Everything the transfer needs of the source character, in numpy: nothing refers to Blender data."""

    kind: ClassVar[str] = "animation"
    model: BodyModel
    basis: np.ndarray  # (F, N, 4) in AvatarRig.from_model(model).names order
    locations: np.ndarray  # (F, N, 3)
    time: np.ndarray  # (F,) s
    fps: float
    action: str
    armature: str
    notes: list[str] = field(default_factory=list)
    frame_start: float = 1.0  # the action's frame of the first sample
    filter: OneEuro | None = None  # One Euro on the source's pose before transferring

    def __post_init__(self):
        self.name = self.action

    @property
    def rate(self) -> float:
        return float(self.fps)

    @property
    def sample_rate(self) -> float:
        return float(self.fps)

    def window(self, first: float, last: float) -> CharacterTake:
        part, start = window_slice(self.time, self.rate, self.frame_start, first, last, self.action)
        return replace(self, basis=self.basis[part], locations=self.locations[part], time=self.time[part],
                       notes=list(self.notes), frame_start=start)

    @property
    def estimated(self) -> bool:
        return self.model.calibration.get("method") == ESTIMATED

    def animate(self, avatar, method, *, plant_feet=True, placement="object", progress=None, cancel=None):
        basis, locations = self._pose()
        anim = transfer(self.model, basis, locations, self.time, avatar, method, plant_feet=plant_feet,
                        placement=placement, progress=progress, cancel=cancel, name=self.armature)
        if self.filter is not None:
            anim.notes.append(f"One Euro filter on {self.armature}'s pose: {self.filter.describe()}")
        return anim

    def prepare(self, avatar, method, *, plant_feet=True, placement="object"):
        basis, locations = self._pose()
        return prepare_transfer(self.model, basis, locations, self.time, avatar, method, plant_feet=plant_feet,
                                placement=placement, name=self.armature)

    def _pose(self) -> tuple[np.ndarray, np.ndarray]:
        """The source's pose values, smoothed when asked."""
        if self.filter is None:
            return self.basis, self.locations
        # Locations in the source's armature units; the filter's speeds are in metres.
        scale = float(np.cbrt(abs(np.linalg.det(rig_matrix(self.model)[:3, :3])))) or 1.0
        return filter_pose(self.time, self.basis, self.locations, self.filter, scale)

    def pose_source(self, placement="object") -> AnimationSource:
        basis, locations = self._pose()
        moved, _ = source_in_play_area(self.model, placement)
        return AnimationSource(moved, basis, locations, self.time, self.armature)

    def release(self) -> None:
        self.basis = self.locations = None
