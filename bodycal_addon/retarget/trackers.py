"""The tracked devices of a recording by role (DESIGN.md §1 step 1), read once per (recording, user
model) and then per block of frames: what the user animation, AvatarGo's offsets and the feet plan
read from a tracker recording.

A `TrackerReader` finds each role's device (the first device with that role that was ever
tracked), its rotation at the reference (T-pose) time, and for every frame the frame whose pose
to use: the last tracked one (forward fill; a leading gap takes the first tracked pose). A
recording that grows (`recording.live.buffer.LiveRecording`, frames appended as they arrive) is read as
far as it goes: the fill is extended by the new frames only, and a device tracked for the first
time joins its role then.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..body.bodymodel import BodyModel
from ..core.transforms import quat_normalize, quat_to_matrix, stack_apply
from ..recording.model import Recording


def forward_fill(valid: np.ndarray) -> np.ndarray:
    """(F,) index of the frame whose value to use: the last valid one (leading gaps: the first)."""
    f = len(valid)
    idx = np.where(valid, np.arange(f), -1)
    idx = np.maximum.accumulate(idx)
    first = int(np.argmax(valid)) if valid.any() else 0
    return np.where(idx < 0, first, idx)


@dataclass
class Trackers:
    pos: dict[str, np.ndarray]  # role -> (F, 3)
    rot: dict[str, np.ndarray]  # role -> (F, 3, 3)
    ref_rot: dict[str, np.ndarray]  # role -> (3, 3) at the reference time
    valid: np.ndarray  # (F,)
    notes: list[str]
    # The same, roles first (`roles` order): pos[role] is positions[roles.index(role)]
    roles: tuple[str, ...] = ()
    positions: np.ndarray | None = None  # (R, F, 3)
    rotations: np.ndarray | None = None  # (R, F, 3, 3)


class _Fill:
    """Forward-fill indices of the columns of a (F, C) validity array, extended as it grows."""

    def __init__(self, columns: int):
        self.idx = np.zeros((0, columns), np.intp)  # -1 before a column's first valid frame
        self.first = np.zeros(columns, np.intp)  # its first valid frame (0 while none)
        self.seen = np.zeros(columns, bool)  # valid at least once

    def extend(self, valid: np.ndarray) -> None:
        """Take in the rows of `valid` (F, C) beyond those already filled."""
        done = len(self.idx)
        new = valid[done:]
        if not len(new):
            return
        rows = np.where(new, np.arange(done, len(valid))[:, None], -1)
        if done:
            rows = np.maximum(rows, self.idx[-1])
        np.maximum.accumulate(rows, axis=0, out=rows)
        fresh = ~self.seen & new.any(0)
        self.first[fresh] = np.argmax(new[:, fresh], axis=0) + done
        self.seen |= fresh
        self.idx = np.concatenate([self.idx, rows]) if done else rows

    def rows(self, start: int, stop: int, columns) -> np.ndarray:
        """(len(columns), stop - start) the frames to read for these columns."""
        idx = self.idx[start:stop, columns].T
        return np.where(idx < 0, self.first[columns][:, None], idx)


class TrackerReader:
    """The devices of `recording` by role for `model` (a user model: its `extra["tpose"]` gives the
    reference rotations, else the recording at `model.reference_time`), read a block of frames at
    a time (`read`). Marker columns are forward-filled the same way (`markers`)."""

    def __init__(self, recording: Recording, model: BodyModel):
        self.recording, self.model = recording, model
        self._fill = _Fill(len(recording.devices))
        self._marker_fill = _Fill(len(recording.marker_names))
        self.version = 0  # changes whenever the roles change (a device tracked for the first time)
        self._roles: tuple | None = None
        self._last = None  # ((start, stop, version), Trackers) of the last read
        self._sync()

    def _sync(self) -> None:
        rec = self.recording
        n = rec.frame_count
        if len(self._fill.idx) == n and self._roles is not None:
            return
        self._fill.extend(rec.valid[:n])
        self._marker_fill.extend(rec.marker_valid[:n])
        seen = self._fill.seen
        roles, devs, never = [], [], []
        for d_i, dev in enumerate(rec.devices):
            role = dev.role
            if role is None or role in roles:
                continue
            if not seen[d_i]:
                never.append((d_i, f"{role}: never tracked, ignored"))
                continue
            roles.append(role)
            devs.append(d_i)
        key = (tuple(roles), tuple(devs))
        if key != self._roles:
            self._roles = key
            self.roles, self.devices = tuple(roles), np.array(devs, np.intp)
            self._never = never
            self.ref_rot = self._reference_rotations()
            self.version += 1

    def _reference_rotations(self) -> dict[str, np.ndarray]:
        rec, model = self.recording, self.model
        tpose = model.extra.get("tpose") or {}
        ref_frame = None
        if model.reference_time is not None and rec.frame_count:
            ref_frame = int(np.clip(np.searchsorted(rec.time, model.reference_time), 0, rec.frame_count - 1))
        out = {}
        for role, d_i in zip(self.roles, self.devices):
            if role in tpose:
                out[role] = quat_to_matrix(quat_normalize(np.asarray(tpose[role][3:7], float)))
            elif ref_frame is not None:
                src = self._fill.rows(ref_frame, ref_frame + 1, [d_i])[0, 0]
                out[role] = quat_to_matrix(quat_normalize(rec.rotations[src, d_i]))
        return out

    def read(self, start: int = 0, stop: int | None = None) -> Trackers:
        """The tracked devices of frames [start, stop) by role: positions, rotations, their
        rotations at the reference (T-pose) time, which frames every device tracked, and notes on
        devices never or partly tracked (their untracked frames hold the last valid pose)."""
        self._sync()
        rec = self.recording
        stop = rec.frame_count if stop is None else stop
        key = (start, stop, self.version)
        if self._last is not None and self._last[0] == key:  # the animation's and the method's read
            return self._last[1]
        src = self._fill.rows(start, stop, self.devices)  # (R, F)
        cols = self.devices[:, None]
        positions = rec.positions[src, cols]
        rotations = quat_to_matrix(quat_normalize(rec.rotations[src, cols]))
        v = rec.valid[start:stop][:, self.devices]
        missing = (~v).sum(0)
        notes = []
        partly = {int(d): int(k) for d, k in zip(self.devices, missing) if k}
        events = self._never + [(d, None) for d in partly]
        for d_i, note in sorted(events, key=lambda e: e[0]):
            role = rec.devices[d_i].role
            notes.append(note or f"{role}: {partly[d_i]} frames without tracking held at the last valid pose")
        out = Trackers({r: positions[k] for k, r in enumerate(self.roles)},
                       {r: rotations[k] for k, r in enumerate(self.roles)}, self.ref_rot, v.all(1), notes,
                       self.roles, positions, rotations)
        self._last = (key, out)
        return out

    def markers(self, columns, start: int, stop: int) -> np.ndarray:
        """(len(columns), F, 3) the markers' points of frames [start, stop), forward-filled."""
        self._sync()
        src = self._marker_fill.rows(start, stop, columns)
        return self.recording.markers[src, np.asarray(columns, np.intp)[:, None]]

    def marker_seen(self, column: int) -> bool:
        """The marker was valid in at least one frame so far."""
        self._sync()
        return bool(self._marker_fill.seen[column])


def read_trackers(recording: Recording, model: BodyModel, start: int = 0, stop: int | None = None) -> Trackers:
    """`TrackerReader(recording, model).read(start, stop)`, for one read."""
    return TrackerReader(recording, model).read(start, stop)


def joint_from_trackers(model: BodyModel, tr: Trackers, joint: str, roles: list[str] | None = None):
    """Mean position of `joint` over the trackers it is known in (restricted to `roles`)."""
    j = model.joints.get(joint)
    if j is None:
        return None
    ests = [tr.pos[r] + stack_apply(tr.rot[r], np.asarray(loc, float)) for r, loc in j.frames.items()
            if r in tr.pos and (roles is None or r in roles)]
    if not ests:
        return None
    return ests[0] if len(ests) == 1 else np.mean(ests, axis=0)
