"""`LiveRecorder`: every frame of a live source, in arrival order, into a Recording (FORMATS.md §2,
§6.2), and the calibration steps a wizard marks while it records.

It is a sink (source.py): the source's thread calls it with each frame, and it copies the frame
into arrays that grow by doubling (so a take of any length costs one copy per frame, no Python
loop over frames afterwards). A device absent from a frame is not tracked in it, so a gap in a
stream is a gap in the recording; a device first seen later is not tracked before.

Time: the take's clock follows the sender's (`/VMC/Ext/T`) while it agrees with arrival, else the
arrival clock; always strictly increasing (`MIN_STEP_S`). A frame's step is the sender's when its
clock moved forward and the take, stepped so, stays no more than `LEAD_S` ahead of the arrival
clock (frames then land on the sender's times, whatever the network did to their arrival: a burst
after a stall keeps its spacing; behind is any amount: frames held up, a sender slower than real
time, a test that waits between frames); otherwise it is the arrival's step since the previous
frame. So a stray time (1e9, a clock restarted back or forward) costs a step or two on the
arrival clock, and a sender whose clock runs ahead of its frames' arrival (a flood of frames, a
replay sped up) cannot make the take longer than the session by more than LEAD_S: the take never
runs away from arrival time. The arrival clock is mapped onto the take's by the first frame, then
follows the take's own lead (over `TRACK_S`) at most `DRIFT` of the arrival's time: a sender's
clock drifting against the receiver's (crystals differ by 10-100 ppm) is followed, a flood gains
the take at most that much.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...core.errors import BodyCalError
from ...core.outputs import replacing
from ..io.writer import save_recording
from ..model import ROLES, Device, Recording, Segment
from ..roles import identify_roles
from ..segments import check_segment, parse_segments
from .source import LiveFrame

MIN_STEP_S = 1e-6  # frames closer than this in time (one datagram ending two frames) are spaced by it
LEAD_S = 0.25  # the take's clock may be this far ahead of arrival on the sender's steps (its stamping jitter)
DRIFT = 1e-3  # arrival's mapping onto the take's clock follows the take's lead at most this fast (1000 ppm)
TRACK_S = 10.0  # over this long


@dataclass
class RecentFrames:
    """Frames of a recording in progress (`LiveRecorder.frames_since`): arrays with a leading frame
    axis over the devices `names` and the markers `marker_names` known when it was taken."""

    time: np.ndarray  # (F,) seconds, the recording's clock
    names: list[str]
    positions: np.ndarray  # (F, D, 3)
    rotations: np.ndarray  # (F, D, 4) w, x, y, z (meaningless where not valid)
    valid: np.ndarray  # (F, D)
    marker_names: list[str]
    points: np.ndarray  # (F, M, 3)
    points_valid: np.ndarray  # (F, M)

    @property
    def count(self) -> int:
        return len(self.time)


class _Grow:
    """A (frames, slots, width) array growing along both first axes by doubling."""

    def __init__(self, width: int, fill=0.0, dtype=float):
        self.width, self.fill, self.dtype = width, fill, dtype
        self.data = np.full((256, 4) + ((width,) if width else ()), fill, dtype)

    def ensure(self, frames: int, slots: int) -> np.ndarray:
        f, s = self.data.shape[:2]
        if frames > f or slots > s:
            grown = np.full((max(f, 1) * 2 if frames > f else f, max(s, 1) * 2 if slots > s else s)
                            + self.data.shape[2:], self.fill, self.dtype)
            grown[:f, :s] = self.data
            self.data = grown
            return self.ensure(frames, slots)
        return self.data


class LiveRecorder:
    """A sink that records (module docstring). `roles` (device name -> role) are the user's: they
    win over roles a stream announces; devices without either get theirs from the T-pose when the
    file is read, as for any recording (recording/roles.py). With `limit_s`, frames more than that
    many seconds after the first (wall clock: their arrival) are not recorded (`full` is set at the
    first of them)."""

    def __init__(self, name: str = "live", roles: dict[str, str] | None = None, *, limit_s: float | None = None):
        self.name = name
        self.limit_s = limit_s  # record this many seconds (arrival) from the first frame, then set `full`
        self.full = threading.Event()
        self.user_roles = _checked_roles(roles or {})
        self._lock = threading.Lock()
        self.names: list[str] = []
        self.kinds: dict[str, str] = {}
        self.announced_roles: dict[str, str | None] = {}
        self.identified_roles: dict[str, str] = {}  # from the T-pose (`identify_roles`)
        self.marker_names: list[str] = []
        self._slot: dict[str, int] = {}
        self._mslot: dict[str, int] = {}
        self._times = np.zeros(256)
        self._arrival = np.zeros(256)
        self._sender = np.zeros(256)
        self._pos, self._rot = _Grow(3), _Grow(4)
        self._valid = _Grow(0, False, bool)
        self._pts, self._pvalid = _Grow(3), _Grow(0, False, bool)
        self.frames = 0
        self.last_tracked = 0  # devices tracked in the last frame
        self.segments: list[Segment] = []
        self._open: tuple[str, str | None, str | None, float] | None = None
        self._prev: tuple[float, float | None, float] | None = None  # (time, sender time, arrival)
        self._offset = 0.0  # the take's clock minus the arrival clock (`_time_of`)
        self.sender_clock = True  # every frame's time came from the sender's clock

    # --- the sink ---------------------------------------------------------------------------------

    def __call__(self, frame: LiveFrame) -> None:
        with self._lock:
            if self.full.is_set():
                return
            k = self.frames
            if self.limit_s is not None and k and frame.arrival - self._arrival[0] > self.limit_s:
                self.full.set()
                return
            t = self._time_of(frame)
            for event in frame.events:
                self._event(event)
            if k >= len(self._times):
                self._times, self._arrival, self._sender = (np.resize(a, 2 * len(a)) for a in
                                                            (self._times, self._arrival, self._sender))
            self._times[k], self._arrival[k] = t, frame.arrival
            self._sender[k] = np.nan if frame.sender_time is None else frame.sender_time
            self._put(k, frame)
            self.frames = k + 1
            self.last_tracked = len(frame.devices)

    def _event(self, event: tuple) -> None:
        if event[0] == "device":
            _, name, kind, role = event
            self._slot_of(name)
            self.kinds[name] = kind
            self.announced_roles[name] = role
        elif event[0] == "marker":
            self._marker_slot(event[1])
        elif event[0] == "segment":
            self.segments.append(event[1])

    def _slot_of(self, name: str) -> int:
        if name not in self._slot:
            self._slot[name] = len(self.names)
            self.names.append(name)
            self.kinds.setdefault(name, "tracker")
        return self._slot[name]

    def _marker_slot(self, name: str) -> int:
        if name not in self._mslot:
            self._mslot[name] = len(self.marker_names)
            self.marker_names.append(name)
        return self._mslot[name]

    def _time_of(self, frame: LiveFrame) -> float:
        """The frame's time on the take's clock (module docstring)."""
        s, a = frame.sender_time, frame.arrival
        if self._prev is None:
            self.sender_clock = s is not None
            t = s if s is not None else 0.0
            self._offset = t - a  # the take's clock minus the arrival clock
        else:
            t0, s0, a0 = self._prev
            da = max(a - a0, 0.0)
            arrived = a + self._offset  # the arrival clock, on the take's
            follows = s is not None and s0 is not None and s > s0 and t0 + (s - s0) - arrived <= LEAD_S
            self.sender_clock &= follows
            t = max(t0 + (s - s0 if follows else da), t0 + MIN_STEP_S)
            self._offset += min(max((t - arrived) * da / TRACK_S, -DRIFT * da), DRIFT * da)  # a drift followed
        self._prev = (t, s, a)
        return t

    def _put(self, k: int, frame: LiveFrame) -> None:
        idx = [self._slot_of(n) for n in frame.devices]
        n_dev = len(self.names)
        self._pos.ensure(k + 1, n_dev)
        self._rot.ensure(k + 1, n_dev)
        self._valid.ensure(k + 1, n_dev)
        if idx:
            self._pos.data[k, idx] = frame.positions
            self._rot.data[k, idx] = frame.rotations
            self._valid.data[k, idx] = True
        midx = [self._marker_slot(n) for n in frame.markers]
        self._pts.ensure(k + 1, len(self.marker_names))
        self._pvalid.ensure(k + 1, len(self.marker_names))
        if midx:
            self._pts.data[k, midx] = frame.points
            self._pvalid.data[k, midx] = True

    # --- calibration steps ---------------------------------------------------------------------------

    @property
    def now(self) -> float:
        """The time of the last frame recorded (the recording's clock); 0 before the first."""
        with self._lock:
            return float(self._times[self.frames - 1]) if self.frames else 0.0

    @property
    def first_arrival(self) -> float | None:
        """When the first frame arrived (the source's clock, `LiveFrame.arrival`), None before it."""
        with self._lock:
            return float(self._arrival[0]) if self.frames else None

    @property
    def last_arrival(self) -> float | None:
        """When the last frame recorded arrived, None before the first."""
        with self._lock:
            return float(self._arrival[self.frames - 1]) if self.frames else None

    @property
    def duration(self) -> float:
        """Seconds from the first frame to the last (the recording's clock)."""
        with self._lock:
            return float(self._times[self.frames - 1] - self._times[0]) if self.frames else 0.0

    def mark_segment_start(self, step: str, point: str | None = None, by: str | None = None) -> float:
        """A calibration step (FORMATS.md §2.4) starts now (the last frame's time); returns that time.
        A step still open is ended first."""
        if self._open is not None:
            self.mark_segment_end()
        check_segment(step, point, by, 0.0, 1.0)  # the step, point and toucher, before anything is kept
        start = self.now
        self._open = (step, point, by, start)
        return start

    def mark_segment_end(self, start: float | None = None) -> Segment:
        """The open step ends now; with `start` (a time after the marked one), it is kept from then
        (the wizard keeps a hold's still stretch only). One BodyCalError when none is open or it
        holds no time."""
        if self._open is None:
            raise BodyCalError("no calibration step is open", hint="mark its start first")
        step, point, by, marked = self._open
        self._open = None
        return self.add_segment(check_segment(step, point, by, marked if start is None else max(marked, start),
                                              self.now))

    def add_segment(self, segment: Segment) -> Segment:
        with self._lock:
            self.segments.append(segment)
        return segment

    @property
    def open_segment(self) -> tuple[str, str | None, str | None, float] | None:
        """The step marked started and not yet ended: (step, point, by, start), else None."""
        return self._open

    def cancel_segment(self) -> None:
        """Forget the open step, if any (no segment is kept: the wizard's skip and redo)."""
        self._open = None

    def remove_segment(self, segment: Segment) -> bool:
        """Drop one kept segment (the very object `add_segment` or `mark_segment_end` returned);
        False when it is not there."""
        with self._lock:
            for k, s in enumerate(self.segments):
                if s is segment:
                    del self.segments[k]
                    return True
        return False

    # --- reading while recording ---------------------------------------------------------------

    def frames_since(self, start: float, *, max_frames: int | None = None) -> RecentFrames:
        """Copies of the frames recorded at or after `start` (the recording's clock), for a consumer
        that looks at the data while the take goes on (the calibration wizard, wizard.py). Only
        those frames are copied (the first is found by bisection), so the cost follows the window,
        never the take's length; with `max_frames`, a longer window is thinned evenly to that many
        (its first and last frames kept)."""
        with self._lock:
            n, d, m = self.frames, len(self.names), len(self.marker_names)
            first = int(np.searchsorted(self._times[:n], start, side="left"))
            if max_frames is not None and n - first > max_frames:
                rows = np.unique(np.linspace(first, n - 1, max(int(max_frames), 2)).round().astype(int))
            else:
                rows = slice(first, n)
            dev = [g.ensure(n, d)[:n, :d][rows] for g in (self._pos, self._rot, self._valid)]
            mark = [g.ensure(n, m)[:n, :m][rows] for g in (self._pts, self._pvalid)]
            # fancy indexing (thinned rows) copies already; a slice is a view: copy it
            dev, mark = ([a.copy() if isinstance(rows, slice) else a for a in grp] for grp in (dev, mark))
            return RecentFrames(self._times[:n][rows].copy(), list(self.names), *dev, list(self.marker_names),
                                *mark)

    # --- the result --------------------------------------------------------------------------------

    def recording(self) -> Recording:
        """What was recorded so far, as a Recording (copies: recording goes on). Roles: the user's,
        else the stream's; segments the recording cannot hold (a toucher it never saw, a time outside
        it) are left out and said in the notes. One BodyCalError when nothing was recorded."""
        with self._lock:
            n, d, m = self.frames, len(self.names), len(self.marker_names)
            if n == 0 or d + m == 0:
                raise BodyCalError("no device or marker arrived", hint="is the sender sending to this port?")
            devices = [Device(nm, self.kinds[nm], self.user_roles.get(nm) or self.announced_roles.get(nm)
                              or self.identified_roles.get(nm)) for nm in self.names]
            rec = Recording(self.name, self._times[:n].copy(), devices, self._pos.ensure(n, d)[:n, :d].copy(),
                            self._rot.ensure(n, d)[:n, :d].copy(), self._valid.ensure(n, d)[:n, :d].copy(),
                            list(self.marker_names), self._pts.ensure(n, m)[:n, :m].copy(),
                            self._pvalid.ensure(n, m)[:n, :m].copy(), source=self.name)
            segments = list(self.segments)
        rec.rotations[~rec.valid] = (1.0, 0.0, 0.0, 0.0)
        _unique_roles(rec)
        rec.segments = _segments_that_fit(rec, segments)
        return rec

    @property
    def nbytes(self) -> int:
        """Memory the recorded arrays hold (grown by doubling: up to twice the frames recorded)."""
        with self._lock:
            return sum(a.nbytes for a in (self._times, self._arrival, self._sender, self._pos.data, self._rot.data,
                                          self._valid.data, self._pts.data, self._pvalid.data))

    def identify_roles(self) -> dict[str, str]:
        """Roles of the devices that have none, from the first T-pose step recorded so far (AvatarGo's
        plane through the devices, recording/roles.py, as for a file); kept for what is recorded
        next. Returns those found; one BodyCalError when the T-pose cannot be read."""
        rec = self.recording()
        found = {n: r for n, r in identify_roles(rec).items()
                 if n not in self.user_roles and not self.announced_roles.get(n)}
        with self._lock:
            self.identified_roles.update(found)
        return found

    def extra(self) -> dict:
        """What the file's `extra` keeps of the stream (FORMATS.md §6.2): each frame's arrival
        (seconds after the first) and sender time (null when it gave none)."""
        with self._lock:
            n = self.frames
            arrival = np.round(self._arrival[:n] - (self._arrival[0] if n else 0.0), 6).tolist()
            sender = [None if np.isnan(s) else float(s) for s in self._sender[:n]]
        return {"live": {"arrival": arrival, "sender_time": sender, "clock": "sender" if self.sender_clock
                         else "arrival"}}

    def save(self, path, *, overwrite: bool = False) -> list[Path]:
        """Write the recording (JSON, or CSV + sidecar for a .csv path; Z up, right-handed, metres),
        each file whole or not at all (core/outputs.py): checked, written beside, renamed."""
        return save_whole(self.recording(), path, overwrite=overwrite, extra=self.extra())


def save_whole(rec: Recording, path, *, overwrite: bool = False, extra: dict | None = None) -> list[Path]:
    """`save_recording` through `outputs.replacing`: a CSV and its sidecar are each renamed into place
    only once both are written."""
    path = Path(path)
    targets = [path, path.with_suffix(".json")] if path.suffix.lower() == ".csv" else [path]
    folder = Path(tempfile.mkdtemp(prefix=".bodycal-rec-", dir=_existing_parent(path)))
    try:
        written = save_recording(rec, folder / path.name, up="Z", handedness="right", units="m", extra=extra)
        with contextlib.ExitStack() as stack:
            temps = [stack.enter_context(replacing(t, overwrite=overwrite)) for t in targets]
            for src, tmp in zip(written, temps, strict=True):
                os.replace(src, tmp)
    finally:
        shutil.rmtree(folder, ignore_errors=True)
    return targets


def _existing_parent(path: Path) -> Path:
    folder = path.absolute().parent
    folder.mkdir(parents=True, exist_ok=True)
    return folder


def _checked_roles(roles: dict[str, str]) -> dict[str, str]:
    seen = {}
    for name, role in roles.items():
        if role not in ROLES:
            raise BodyCalError(f"unknown role {role!r} for {name!r}", field="--role",
                               hint=f"use one of {', '.join(ROLES)}")
        if role in seen:
            raise BodyCalError(f"role '{role}' is given to both '{seen[role]}' and '{name}'", field="--role")
        seen[role] = name
    return dict(roles)


def _unique_roles(rec: Recording) -> None:
    """A role announced for two devices (or announced and given): the later one keeps none."""
    taken = set()
    for d in rec.devices:
        if d.role in taken:
            rec.notes.append(f"role {d.role} of {d.name} left out: another device has it")
            d.role = None
        elif d.role:
            taken.add(d.role)


def _segments_that_fit(rec: Recording, segments: list[Segment]) -> list[Segment]:
    kept = []
    for s in segments:
        item = {k: v for k, v in (("step", s.step), ("start", s.start), ("end", s.end), ("point", s.point),
                                  ("by", s.by)) if v is not None}
        try:
            kept += parse_segments([item], rec.time, rec.name, rec.devices, rec.marker_names)
        except BodyCalError as exc:
            rec.notes.append(f"calibration step left out: {exc.line()}")
    return kept
