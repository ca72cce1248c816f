"""The tracked devices of a recording by role (DESIGN.md §1 step 1), read once per (recording, user
model) and then per block of frames: what the user animation, AvatarGo's offsets and the feet plan
read from a tracker recording.

A `TrackerReader` finds each role's device (the first device with that role that was ever
tracked) and its rotation at the reference (T-pose) time. Lost devices (DESIGN.md §6 "Lost
devices"): in a whole take (both ends of every gap known) a gap shorter than `BRIDGE_S` is bridged
by cubic Hermite curves at the device's own velocity (`recording.gaps.fill_gaps`), a longer one
rides on its carrier (`CARRIERS`: the device's pose in the carrier's frame blended from one end of
the gap to the other, `recording.gaps.ride_gaps`), and a device without a carrier (HMD, hands,
feet) holds its last pose. A recording that grows (`recording.live.buffer.LiveRecording`, frames
appended as they arrive) cannot see a gap's far end: its devices ride on their carriers with the
relation of the last tracked frame from the first lost frame on (held where there is no carrier);
the fill is extended by the new frames only, and a device tracked for the first time joins its
role then. `Trackers.tracked` says which frames carry a device's own (or bridged) pose.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from ..body.bodymodel import BodyModel
from ..core.transforms import all_true, quat_conj, quat_mul, quat_normalize, quat_to_matrix, rotate, stack_apply
from ..recording.gaps import fill_gaps, hold_untracked, ride_gaps
from ..recording.live.buffer import LiveRecording
from ..recording.model import Recording

# Gaps bridged by Hermite curves in a whole take, up to this length; longer ones ride on their
# carrier. Measured (benchmarks/bench_lost_devices.py, DESIGN.md §6): the limb trackers' position
# error over a gap is lower bridged up to 0.3-0.4 s and lower riding from 0.5 s on.
BRIDGE_S = 0.4


def forward_fill(valid: np.ndarray) -> np.ndarray:
    """(F,) index of the frame whose value to use: the last valid one (leading gaps: the first)."""
    f = len(valid)
    idx = np.where(valid, np.arange(f), -1)
    idx = np.maximum.accumulate(idx)
    first = int(np.argmax(valid)) if valid.any() else 0
    return np.where(idx < 0, first, idx)


# What a lost device rides on (DESIGN.md §6 "Lost devices"), side-less, first tracked carrier
# wins: the limb trackers on the body part their joint hangs from or rests on, the chest on the
# pelvis, the pelvis on the HMD's heading (its turn about the vertical only: a nod does not tilt
# the hips).
CARRIERS = {"pelvis": ("head",), "chest": ("pelvis",), "thigh": ("pelvis",), "shin": ("foot",),
            "upperarm": ("chest", "pelvis"), "forearm": ("hand",)}
HEADING_CARRIERS = ("head",)
# The joint a limb tracker hangs from: while the tracker is lost (bridged or ridden) this point
# rides on the carrier (the hip on the pelvis, the shoulder on the chest) and the tracker's
# position follows it at its bridged rotation: a Hermite-bridged thigh turning 4 degrees off over
# 0.2 s moved the hip 10-20 mm, the hip line 9.5 degrees (DESIGN.md §6 "Lost devices").
ANCHORS = {"thigh": "hip", "upperarm": "shoulder"}


def heading(quat: np.ndarray) -> np.ndarray:
    """The turn about the vertical (+Z) of rotations (..., 4) w x y z: their twist about Z."""
    q = np.zeros_like(quat)
    q[..., 0], q[..., 3] = quat[..., 0], quat[..., 3]
    n = np.linalg.norm(q, axis=-1, keepdims=True)
    return np.where(n > 1e-9, q / np.where(n > 1e-9, n, 1.0), np.array([1.0, 0.0, 0.0, 0.0]))


def carrier_of(role: str, roles) -> str | None:
    """The role a lost `role` rides on among `roles` (CARRIERS), None: it holds."""
    base, _, side = role.rpartition("_") if role.endswith(("_l", "_r")) else (role, "", "")
    for c in CARRIERS.get(base, ()):
        name = f"{c}_{side}" if c in ("foot", "hand") else c
        if name in roles:
            return name
    return None


def carrier_poses(roles, positions: np.ndarray, quats: np.ndarray):
    """(F, D, 3) positions and (F, D, 4) rotations each column rides on when lost (`carrier_of`;
    a column with none rides on itself, i.e. holds), from positions (F, D, 3) and quats (F, D, 4)
    of the devices of `roles` (D)."""
    roles = list(roles)
    idx = [roles.index(c) if (c := carrier_of(r, roles)) is not None else d for d, r in enumerate(roles)]
    cp, cq = positions[:, idx], quats[:, idx].copy()
    head = [k for k, c in enumerate(idx) if roles[c] in HEADING_CARRIERS and c != k]
    if head:
        cq[:, head] = heading(cq[:, head])
    return cp, cq


class ByRole(Mapping):
    """role -> its row of a roles-first array (R, ...), a view made when read: a block's read
    makes one of these for the positions and one for the rotations, and a live frame reads a few
    of their ~15 rows (a dict of every row's view was a sixth of a one-frame read)."""

    __slots__ = ("_index", "_rows")

    def __init__(self, index: dict[str, int], rows: np.ndarray):
        self._index, self._rows = index, rows

    def __getitem__(self, role: str) -> np.ndarray:
        return self._rows[self._index[role]]

    def __contains__(self, role) -> bool:
        return role in self._index

    def __iter__(self):
        return iter(self._index)

    def __len__(self) -> int:
        return len(self._index)


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
    # (R, F) the device's own pose or a Hermite bridge (not ridden on a carrier, not held)
    tracked: np.ndarray | None = None


class _Fill:
    """Forward-fill indices of the columns of a (F, C) validity array, extended as it grows (a
    live stream: a frame at a time, into a buffer that doubles when full, so a frame's rows are
    written once and never copied per frame again; the copy grew with the take)."""

    def __init__(self, columns: int):
        self._buf = np.zeros((0, columns), np.intp)
        self.idx = self._buf  # (F, C) the rows filled so far; -1 before a column's first valid frame
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
        n = len(valid)
        if not done:  # the first block (a whole take: the only one)
            self._buf = rows
        elif n > len(self._buf):
            bigger = np.empty((max(n, 2 * len(self._buf), 256),) + self._buf.shape[1:], np.intp)
            bigger[:done] = self._buf[:done]
            self._buf = bigger
        if done:
            self._buf[done:n] = rows
        self.idx = self._buf[:n]

    def rows(self, start: int, stop: int, columns) -> np.ndarray:
        """(len(columns), stop - start) the frames to read for these columns (an index array, or
        a list: converted on every call)."""
        idx = self.idx[start:stop].take(columns, axis=1).T
        if all_true(idx >= 0):  # every column valid once before (a live frame's usual case)
            return idx
        return np.where(idx < 0, self.first.take(columns)[:, None], idx)


# One-frame reads of a whole take convert its rotations a block of this many frames at a time
# (`TrackerReader._whole_rotations`: 1 MB for a dozen devices).
ROTATION_BLOCK = 1024


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
        self._rotation_block = None  # ((first frame, version), matrices) of `_whole_rotations`' block
        self.live = isinstance(recording, LiveRecording)  # it grows: gaps read causally
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
            self._role_index = {r: k for k, r in enumerate(self.roles)}
            self._never = never
            self.ref_rot = self._reference_rotations()
            self.carriers = np.array([self.roles.index(c) if (c := carrier_of(r, self.roles)) is not None else -1
                                      for r in self.roles], np.intp)
            self._whole = None if self.live else self._bridge_whole()
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
        rotations = None
        if self._whole is not None:
            pos, quat, tracked, how = (a[start:stop].swapaxes(0, 1) for a in self._whole)
            tracked = tracked.copy()
            if stop - start == 1:
                rotations = self._whole_rotations(start)
        else:
            pos, quat, tracked, how = self._read_causal(start, stop)
        positions = np.ascontiguousarray(pos)
        if rotations is None:
            rotations = quat_to_matrix(quat)
        v = rec.valid[start:stop].take(self.devices, axis=1)
        if all_true(v):  # every device tracked (a live frame's usual case)
            valid, partly = np.ones(stop - start, bool), {}
        else:
            missing = (~v).sum(0).tolist()
            partly = {d: (k, n) for k, (d, n) in enumerate(zip(self.devices.tolist(), missing)) if n}
            valid = v.all(1)
        notes = []
        events = self._never + [(d, None) for d in partly]
        for d_i, note in sorted(events, key=lambda e: e[0]):
            notes.append(note or self._lost_note(*partly[d_i], how))
        out = Trackers(ByRole(self._role_index, positions), ByRole(self._role_index, rotations), self.ref_rot,
                       valid, notes, self.roles, positions, rotations, tracked)
        self._last = (key, out)
        return out

    def _lost_note(self, k: int, lost: int, how: np.ndarray) -> str:
        """The note on role `k`'s `lost` untracked frames of a read: how many were bridged, ridden
        on the carrier, held (`how` (R, F): 1 bridged, 2 ridden, 3 held)."""
        role = self.roles[k]
        counts = np.bincount(how[k], minlength=4)
        parts = [f"{counts[1]} bridged (cubic Hermite)"] if counts[1] else []
        if counts[2]:
            on = "the hip line" if not self.live and k == self._rides_on_hips() else self.roles[self.carriers[k]]
            parts.append(f"{counts[2]} ridden on {on}")
        if counts[3]:
            parts.append(f"{counts[3]} held at the last valid pose")
        return f"{role}: {lost} frames without tracking: " + ", ".join(parts)

    def _whole_rotations(self, frame: int) -> np.ndarray:
        """(R, 1, 3, 3) the rotation matrices of one frame of a whole take (a preview's scrubbed
        frame), from its block of `ROTATION_BLOCK` frames' made at once and kept: one numpy pass
        a block instead of one a frame (quat_to_matrix's entries are each its own arithmetic, so
        the same bits)."""
        b0 = frame - frame % ROTATION_BLOCK
        held = self._rotation_block
        if held is None or held[0] != (b0, self.version):
            quat = self._whole[1][b0:b0 + ROTATION_BLOCK].swapaxes(0, 1)
            held = self._rotation_block = ((b0, self.version), quat_to_matrix(quat))
        return held[1][:, frame - b0:frame - b0 + 1].copy()  # the caller owns it (as a fresh one)

    def _bridge_whole(self):
        """The whole take's poses of the roles' devices with every gap bridged, ridden or held
        (the module's docstring): (F, R, 3) positions, (F, R, 4) rotations, (F, R) tracked or
        bridged, (F, R) how each frame was filled (0 tracked, 1 bridged, 2 ridden, 3 held)."""
        rec = self.recording
        n = rec.frame_count
        pos = np.array(rec.positions[:n][:, self.devices], float)
        quat = quat_normalize(np.array(rec.rotations[:n][:, self.devices], float))
        valid = np.array(rec.valid[:n][:, self.devices], bool)
        bridged = valid.copy()
        on_hips = self._rides_on_hips()
        fill_gaps(rec.time[:n], pos, bridged, BRIDGE_S, quat)
        if on_hips is not None:  # the hip line beats any bridge: lost at all, the pelvis rides on it
            bridged[:, on_hips] = valid[:, on_hips]
        how = np.where(valid, 0, np.where(bridged, 1, 3)).astype(np.intp)
        # Every lost frame held first: the devices without carrier stay so, the others carry
        # finite poses (a file's untracked values may be anything) until they ride below.
        hold_untracked(pos, bridged, quat)
        for k in self._carrier_order():
            cp, cq = self._carrier_pose(k, pos, quat)
            col = [k]
            p, q = pos[:, col], quat[:, col]  # copies (fancy indexing): written back below
            ride_gaps(rec.time[:n], p, bridged[:, col], q, cp, cq)
            pos[:, k], quat[:, k] = p[:, 0], q[:, 0]
            how[~bridged[:, k], k] = 2
        self._ride_anchors(pos, quat, valid)
        return pos, quat, bridged, how

    def _ride_anchors(self, pos: np.ndarray, quat: np.ndarray, valid: np.ndarray) -> None:
        """(in place) Over a limb tracker's untracked frames, its anchor joint (`ANCHORS`, as
        calibrated in the tracker) rides on the carrier, and the tracker's position follows it."""
        t = self.recording.time[:len(pos)]
        for k in range(len(self.roles)):
            local = self._anchor_local(k)
            if self.carriers[k] < 0 or local is None or valid[:, k].all():
                continue
            anchor = pos[:, [k]] + rotate(quat[:, [k]], local)
            ride_gaps(t, anchor, valid[:, [k]], quat[:, [k]].copy(), *self._carrier_pose(k, pos, quat))
            lost = ~valid[:, k]
            pos[lost, k] = anchor[lost, 0] - rotate(quat[lost, k], local)

    def _carrier_pose(self, k: int, pos: np.ndarray, quat: np.ndarray):
        """(F, 1, 3) positions and (F, 1, 4) rotations role `k` rides on: its carrier's pose, the
        HMD's heading; the pelvis, with both thighs' hips calibrated, on the hip line (their mid
        point, turned as the line between them about the vertical): the hips turn under a still
        head (a dancer reversing her turn left the HMD-carried hips 5.4 degrees behind)."""
        c = self.carriers[k]
        if k == self._rides_on_hips():
            kl, kr = self.roles.index("thigh_l"), self.roles.index("thigh_r")
            hl = pos[:, kl] + rotate(quat[:, kl], self._anchor_local(kl))
            hr = pos[:, kr] + rotate(quat[:, kr], self._anchor_local(kr))
            line = hl - hr
            half = 0.5 * np.arctan2(line[:, 1], line[:, 0])
            q = np.zeros((len(pos), 1, 4))
            q[:, 0, 0], q[:, 0, 3] = np.cos(half), np.sin(half)
            return 0.5 * (hl + hr)[:, None], q
        cq = heading(quat[:, [c]]) if self.roles[c] in HEADING_CARRIERS else quat[:, [c]]
        return pos[:, [c]], cq

    def _rides_on_hips(self) -> int | None:
        """The pelvis's index when both thighs' hips are calibrated (it rides on the hip line)."""
        if "pelvis" not in self.roles or not all(f"thigh_{s}" in self.roles for s in "lr"):
            return None
        if any(self._anchor_local(self.roles.index(f"thigh_{s}")) is None for s in "lr"):
            return None
        return self.roles.index("pelvis")

    def _anchor_local(self, k: int):
        """The anchor joint of limb tracker role `k` (`ANCHORS`) in that tracker, None: none."""
        base, _, side = self.roles[k].rpartition("_")
        joint = self.model.joints.get(f"{ANCHORS.get(base, '')}_{side}")
        if not base or joint is None or self.roles[k] not in joint.frames:
            return None
        return np.asarray(joint.frames[self.roles[k]], float)

    def _carrier_order(self) -> list[int]:
        """The roles with a carrier, each after its own carrier (the pelvis before the thighs)."""
        done, order = set(), []
        todo = [k for k in range(len(self.roles)) if self.carriers[k] >= 0]
        while todo:
            ready = [k for k in todo if self.carriers[k] not in todo]
            if not ready:  # a cycle (none in CARRIERS): take them as they come
                ready = todo
            order += ready
            done.update(ready)
            todo = [k for k in todo if k not in done]
        return order

    def _read_causal(self, start: int, stop: int):
        """(R, F, 3) positions, (R, F, 4) rotations, (R, F) tracked, (R, F) how filled of frames
        [start, stop) of a growing recording: the last tracked pose, ridden on the carrier with
        the relation of that frame (the carrier's own last tracked pose then and now)."""
        rec = self.recording
        src = self._fill.rows(start, stop, self.devices)  # (R, F)
        cols = self.devices[:, None]
        pos = np.array(rec.positions[src, cols], float)
        quat = quat_normalize(rec.rotations[src, cols])
        tracked = rec.valid[start:stop][:, self.devices].T.copy()
        how = np.where(tracked, 0, 3).astype(np.intp)
        for k in np.nonzero((self.carriers >= 0) & ~tracked.all(1))[0]:
            c = self.carriers[k]
            f = np.nonzero(~tracked[k])[0]
            then = src[k, f]  # the frame whose pose is held
            dev = self.devices[c]
            c_then = self._fill.idx[then, dev]
            c_then = np.where(c_then < 0, self._fill.first[dev], c_then)
            c_now = src[c, f]
            cq_then, cq_now = rec.rotations[c_then, dev], rec.rotations[c_now, dev]
            if self.roles[c] in HEADING_CARRIERS:
                cq_then, cq_now = heading(cq_then), heading(cq_now)
            cq_then, cq_now = quat_normalize(cq_then), quat_normalize(cq_now)
            inv = quat_conj(cq_then)
            rel_p = rotate(inv, pos[k, f] - rec.positions[c_then, dev])
            rel_q = quat_mul(inv, quat[k, f])
            pos[k, f] = rec.positions[c_now, dev] + rotate(cq_now, rel_p)
            quat[k, f] = quat_normalize(quat_mul(cq_now, rel_q))
            how[k, f] = 2
        return pos, quat, tracked, how

    def markers(self, columns, start: int, stop: int) -> np.ndarray:
        """(len(columns), F, 3) the markers' points of frames [start, stop), forward-filled."""
        self._sync()
        columns = np.asarray(columns, np.intp)
        src = self._marker_fill.rows(start, stop, columns)
        return self.recording.markers[src, columns[:, None]]

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
