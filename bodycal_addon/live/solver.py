"""The live loop's entry into the prepared solver (DESIGN.md "Prepared solver"): device frames are
pushed as they arrive and each is solved once, from the frames so far only.

`LiveSolver.push` appends the frame's device poses (and finger markers) to a
`recording.live.buffer.LiveRecording`, forward-filtered when asked (the causal One Euro), and solves the
new frames with a `PreparedSolver` whose stances are found frame by frame (`feet.CausalStance`).
The solver is prepared once every device the methods need (HMD, both hands, pelvis, both feet)
has been tracked; the frames before that are not solved (`push` returns None). A kit below six
devices gets the estimated devices its user model has (calibration/estimated_devices.py) from the
frame's head and hands as each frame comes (`lower_body.LiveLowerBody`, forward only).
"""

from __future__ import annotations

import numpy as np

from ..body.bodymodel import BodyModel
from ..calibration.coverage import ANIMATED_ROLES
from ..core.transforms import quat_normalize, quat_to_matrix
from ..recording.filters import OneEuro
from ..recording.live.buffer import LiveRecording
from ..recording.model import Device
from ..retarget import lower_body
from ..retarget.pose_source import RecordingSource
from ..retarget.solver import PreparedSolver, SolvedFrames


class LiveSolver:
    """`user` (a calibrated user model) streamed onto `avatar` by `method`. `devices` and
    `marker_names` say what each pushed frame's arrays hold (their roles as in the user's
    calibration); `rate` is the stream's nominal rate (Hz); `smooth` a forward One Euro
    configuration (None: the raw poses); `plant_feet` and `placement` as `PreparedSolver`'s;
    `seat_height` for a seated performer of a kit without foot trackers (lower_body)."""

    def __init__(self, user: BodyModel, avatar: BodyModel, method: str = "egocentric", *, devices: list[Device],
                 marker_names: list[str] | None = None, rate: float = 90.0, smooth: OneEuro | None = None,
                 plant_feet: bool = True, placement: str = "object", seat_height: float | None = None):
        probe = LiveRecording(devices, marker_names, rate=rate)
        estimated = lower_body.estimated_roles(probe, user)
        self._lower = lower_body.LiveLowerBody(user, estimated, rate, seat_height=seat_height) if estimated else None
        self._given = len(devices)
        self._head = next((i for i, d in enumerate(devices) if d.role == "head"), None)
        self._pelvis = next((i for i, d in enumerate(devices) if d.role == "pelvis"), None)
        self._hands = [next((i for i, d in enumerate(devices) if d.role == f"hand_{s}"), None) for s in "lr"]
        self._last_head = None  # the head's last tracked pose (position, rotation matrix)
        devices = list(devices) + [Device(f"estimated {r}", lower_body.KIND, r) for r in estimated]
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
        if self._lower is not None:
            positions, rotations, valid = self._with_estimated(time, positions, rotations, valid)
        new = self.recording.append(time, positions, rotations, valid, markers, marker_valid)
        if self.solver is None:
            seen = self.recording.valid[:, self._needed].any(axis=0)
            if len({self.recording.devices[i].role for i in np.asarray(self._needed)[seen]}) < len(ANIMATED_ROLES):
                return None
            self.solver = PreparedSolver(RecordingSource(self.recording, self.user), self.avatar, self.method,
                                         plant_feet=self.plant_feet, placement=self.placement, stance="causal")
            self.first_solved = new.start
        return self.solver.solve(new.start, new.stop)

    def _with_estimated(self, time, positions, rotations, valid):
        """The frame's arrays with the estimated devices' columns: their poses from the head (and
        the pelvis tracker) as given; untracked until the head has been tracked once."""
        one = np.ndim(time) == 0
        time = np.atleast_1d(np.asarray(time, float))
        pos = np.asarray(positions, float).reshape(len(time), self._given, 3)
        rot = np.asarray(rotations, float).reshape(len(time), self._given, 4)
        ok = np.asarray(valid, bool).reshape(len(time), self._given)
        n = len(self._lower.roles)
        out_p, out_q, out_v = np.zeros((len(time), n, 3)), np.tile([1.0, 0, 0, 0], (len(time), n, 1)), \
            np.zeros((len(time), n), bool)
        for k in range(len(time)):  # the frames of one push: usually one
            if ok[k, self._head]:
                self._last_head = (pos[k, self._head], quat_to_matrix(quat_normalize(rot[k, self._head])))
            if self._last_head is None:
                continue
            pelvis = None
            if self._pelvis is not None and ok[k, self._pelvis]:
                pelvis = (pos[k, self._pelvis], quat_to_matrix(quat_normalize(rot[k, self._pelvis])))
            hands = None
            if None not in self._hands and ok[k, self._hands].all():
                hands = [(pos[k, i], quat_to_matrix(quat_normalize(rot[k, i]))) for i in self._hands]
            poses = self._lower.frame(float(time[k]), *self._last_head, *(pelvis or (None, None)), hands=hands)
            for c, r in enumerate(self._lower.roles):
                out_p[k, c], out_q[k, c] = poses[r]
                out_v[k, c] = True
        cat = (np.concatenate([pos, out_p], 1), np.concatenate([rot, out_q], 1), np.concatenate([ok, out_v], 1))
        return tuple(a[0] for a in cat) if one else cat

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
