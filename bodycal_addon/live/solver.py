"""The live loop's entry into the prepared solver (DESIGN.md "Prepared solver"): device frames are
pushed as they arrive and each is solved once, from the frames so far only.

`LiveSolver.push` appends the frame's device poses (and finger markers) to a
`recording.live.buffer.LiveRecording`, forward-filtered when asked (the causal One Euro), and solves the
new frames with a `PreparedSolver` whose stances are found frame by frame (`feet.CausalStance`).
The solver is prepared once every device the methods need (HMD, both hands, pelvis, both feet)
has been tracked; the frames before that are not solved (`push` returns None).
"""

from __future__ import annotations

import numpy as np

from ..body.bodymodel import BodyModel
from ..calibration.coverage import ANIMATED_ROLES
from ..recording.filters import OneEuro
from ..recording.live.buffer import LiveRecording
from ..recording.model import Device
from ..retarget.pose_source import RecordingSource
from ..retarget.solver import PreparedSolver, SolvedFrames


class LiveSolver:
    """`user` (a calibrated user model) streamed onto `avatar` by `method`. `devices` and
    `marker_names` say what each pushed frame's arrays hold (their roles as in the user's
    calibration); `rate` is the stream's nominal rate (Hz); `smooth` a forward One Euro
    configuration (None: the raw poses); `plant_feet` and `placement` as `PreparedSolver`'s."""

    def __init__(self, user: BodyModel, avatar: BodyModel, method: str = "egocentric", *, devices: list[Device],
                 marker_names: list[str] | None = None, rate: float = 90.0, smooth: OneEuro | None = None,
                 plant_feet: bool = True, placement: str = "object"):
        self.recording = LiveRecording(devices, marker_names, rate=rate, smooth=smooth)
        self.user, self.avatar, self.method = user, avatar, method
        self.plant_feet, self.placement = plant_feet, placement
        self._needed = [i for i, d in enumerate(devices) if d.role in ANIMATED_ROLES]
        self.solver: PreparedSolver | None = None
        self.first_solved: int | None = None  # the first frame solved

    def push(self, time, positions, rotations, valid, markers=None, marker_valid=None) -> SolvedFrames | None:
        """Add one frame (or a few: a leading frame axis) and solve it: `time` seconds, `positions`
        (D, 3), `rotations` (D, 4) w x y z, `valid` (D,), `markers` (M, 3) and `marker_valid` (M,)
        in the order given at construction. Returns the new frames' pose-bone values, world
        joints and targets, or None while a device the methods need has never been tracked."""
        new = self.recording.append(time, positions, rotations, valid, markers, marker_valid)
        if self.solver is None:
            seen = self.recording.valid[:, self._needed].any(axis=0)
            if len({self.recording.devices[i].role for i in np.asarray(self._needed)[seen]}) < len(ANIMATED_ROLES):
                return None
            self.solver = PreparedSolver(RecordingSource(self.recording, self.user), self.avatar, self.method,
                                         plant_feet=self.plant_feet, placement=self.placement, stance="causal")
            self.first_solved = new.start
        return self.solver.solve(new.start, new.stop)

    def push_newer(self, time: float, positions, rotations, valid, markers=None, marker_valid=None
                   ) -> SolvedFrames | None:
        """`push` one frame unless it is not newer than the last pushed (a sender's clock that went
        back, a replay looping: not a new moment; None then)."""
        if self.recording.frame_count and time <= self.recording.time[-1]:
            return None
        return self.push(time, positions, rotations, valid, markers, marker_valid)

    @property
    def notes(self) -> list[str]:
        return self.solver.notes if self.solver is not None else []
