"""A take: what a session reads from a pose source, in numpy (DESIGN.md §1, "One session path").

A take names itself (the baked action's name starts with it), says at what rate its samples come,
carries the notes its reading made (said once, when it is read), and turns itself into an avatar's
animation by the pipeline. The glue (`blender/session.py`) reads a take, computes each target's
animation from it (nothing of the scene: a worker thread may run it), then bakes; it never asks
which kind of take it holds.

- `RecordingTake`: a tracker recording of a calibrated performer (`pipeline.retarget`), smoothed by
  the One Euro filter first when asked (on a copy: the recording itself is not changed).
- `CharacterTake`: another character's action (`transfer.transfer`): its body model (measured on
  its mesh, or estimated from its bone lengths) and its pose-bone values per frame.
A live stream is one more kind: anything with these attributes and methods.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import ClassVar, Protocol

import numpy as np

from ..avatar.estimate import ESTIMATED
from ..body.animation import AvatarAnimation
from ..body.bodymodel import BodyModel
from ..recording.filters import OneEuro, filter_recording
from ..recording.model import Recording
from .methods import check_method
from .pipeline import retarget
from .transfer import transfer

FALLBACK_RATE = 30.0  # a one-frame take has no rate of its own


class Take(Protocol):
    kind: ClassVar[str]  # "recording" | "animation" (methods.SOURCE_KINDS)
    name: str  # the take's name: baked actions are named "<take>|<armature>|<method>"
    notes: list[str]  # what reading it found, one line each

    @property
    def rate(self) -> float:
        """Samples per second."""

    def animate(self, avatar: BodyModel, method: str, *, plant_feet: bool = True, placement: str = "object",
                progress: Callable[[float], None] | None = None,
                cancel: Callable[[], bool] | None = None) -> AvatarAnimation:
        """The avatar's animation (pure numpy). Bad input raises one BodyCalError."""

    def release(self) -> None:
        """Let go of the source's arrays: nothing will be computed from this take any more."""


@dataclass
class RecordingTake:
    kind: ClassVar[str] = "recording"
    recording: Recording
    user: BodyModel
    filter: OneEuro | None = None  # One Euro on the devices before retargeting
    notes: list[str] = field(default_factory=list)

    def __post_init__(self):
        self.name = self.recording.name

    @property
    def rate(self) -> float:
        rec = self.recording
        return rec.fps if rec.frame_count > 1 else FALLBACK_RATE

    def animate(self, avatar, method, *, plant_feet=True, placement="object", progress=None, cancel=None):
        check_method(method, self.kind)
        rec = self.recording if self.filter is None else filter_recording(self.recording, self.filter)
        return retarget(rec, self.user, avatar, method, progress=progress, cancel=cancel, plant_feet=plant_feet,
                        placement=placement)

    def release(self) -> None:
        self.recording = None


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

    def __post_init__(self):
        self.name = self.action

    @property
    def rate(self) -> float:
        return float(self.fps)

    @property
    def estimated(self) -> bool:
        return self.model.calibration.get("method") == ESTIMATED

    def animate(self, avatar, method, *, plant_feet=True, placement="object", progress=None, cancel=None):
        return transfer(self.model, self.basis, self.locations, self.time, avatar, method, plant_feet=plant_feet,
                        placement=placement, progress=progress, cancel=cancel, name=self.armature)

    def release(self) -> None:
        self.basis = self.locations = None
