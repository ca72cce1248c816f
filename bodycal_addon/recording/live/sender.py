"""A take sent as a VMC stream in real time (`bodycal stream`, FORMATS.md §6.3): for tests and
demos, and to feed any VMC receiver (VSeeFace, VMC4B, a Unity scene with EVMC4U) from a file.

`VmcSender` owns the UDP socket; `replay` paces the frames of a take (anything with `time` and
`messages(k, offset)`: `RecordingMessages` for a recording's devices and markers, the avatar's
bones in output/vmc_bones.py) and ends each frame with `/VMC/Ext/OK` and `/VMC/Ext/T` (the
take's own time, so a receiver recording the stream gets the take's times at any speed), bundled
as VirtualMotionCapture does (each bundle under 1500 bytes). Every second of the take it also
announces the devices, their kinds and roles and the markers (`/BodyCal/Device`, `/BodyCal/Marker`),
and it announces each calibration step once its end has been sent, so a BodyCal receiver that
records the stream records the take.
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from pythonosc.osc_message import OscMessage

from ...core.errors import BodyCalError
from ..coords import from_internal
from ..model import Recording
from .vmc import (
    AVAILABLE,
    DEFAULT_PORT,
    DEVICE_INFO,
    MARKER,
    MARKER_INFO,
    SEGMENT,
    TIME,
    UNITY,
    bundles,
    device_messages,
    message,
)

ANNOUNCE_EVERY_S = 1.0  # take seconds between announcements of the devices and markers


class VmcSender:
    """A UDP socket sending datagrams to host:port."""

    def __init__(self, host: str = "127.0.0.1", port: int = DEFAULT_PORT):
        try:
            self.address = socket.getaddrinfo(host, port, socket.AF_INET, socket.SOCK_DGRAM)[0][4]
        except (socket.gaierror, UnicodeError, OverflowError) as exc:
            raise BodyCalError(f"cannot send to {host}:{port} ({exc})", field="--host",
                               hint="give a host name or an IPv4 address, and a port 1..65535") from None
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.datagrams = 0
        self.errors = 0  # datagrams the system refused (no route, a full buffer): the stream goes on
        self.last_error = ""

    def send(self, datagrams: list[bytes]) -> None:
        for d in datagrams:
            try:
                self._sock.sendto(d, self.address)
                self.datagrams += 1
            except OSError as exc:
                self.errors += 1
                self.last_error = exc.strerror or str(exc)

    def close(self) -> None:
        self._sock.close()

    def __enter__(self) -> VmcSender:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class FrameMessages(Protocol):
    """A take to send: its times (strictly increasing seconds) and each frame's messages."""

    name: str
    time: np.ndarray

    def messages(self, k: int, offset: float) -> list[OscMessage]:
        """Frame k's messages, `/VMC/Ext/T` excepted; `offset` is added to the take's times (a loop)."""

    def announcements(self) -> list[OscMessage]:
        """What is said every ANNOUNCE_EVERY_S (may be empty)."""


class RecordingMessages:
    """A recording's tracked devices (`/VMC/Ext/<Hmd|Con|Tra>/Pos/Local` and the plain message with
    the same values) and markers (`/BodyCal/Marker/Pos`), frame by frame, in Unity's axes."""

    def __init__(self, rec: Recording, *, scaled: bool = True):
        self.name, self.rec, self.scaled = rec.name, rec, scaled
        self.time = np.asarray(rec.time, float)
        self._names = [d.name for d in rec.devices]
        self._kinds = [d.kind for d in rec.devices]
        self._points = from_internal(rec.markers, None, *UNITY)[0] if rec.marker_names else None
        # A step is announced with the frame that reaches its end (the last frame at the latest).
        ends = np.searchsorted(self.time, [s.end for s in rec.segments], side="left")
        self._steps_at = np.minimum(ends, len(self.time) - 1)

    def announcements(self) -> list[OscMessage]:
        return ([message(DEVICE_INFO, d.name, d.kind, d.role or "") for d in self.rec.devices]
                + [message(MARKER_INFO, n) for n in self.rec.marker_names])

    def messages(self, k: int, offset: float) -> list[OscMessage]:
        rec = self.rec
        out = []
        for j in np.flatnonzero(self._steps_at == k):
            s = rec.segments[j]
            out.append(message(SEGMENT, s.step, s.point or "", s.by or "", s.start + offset, s.end + offset))
        if self._points is not None:
            for j in np.flatnonzero(rec.marker_valid[k]):
                x, y, z = self._points[k, j].tolist()
                out.append(message(MARKER, rec.marker_names[j], x, y, z))
        live = np.flatnonzero(rec.valid[k])
        if live.size:
            out += device_messages([self._names[i] for i in live], [self._kinds[i] for i in live],
                                   rec.positions[k, live], rec.rotations[k, live], scaled=self.scaled)
        return out


@dataclass
class ReplayStats:
    frames: int = 0  # frames sent
    loops: int = 0  # times the take started over (--loop)
    late: int = 0  # frames sent more than a frame interval after their time (the sender fell behind)
    take_seconds: float = 0.0  # take time sent, loops included


def replay(take: FrameMessages, sender: VmcSender, *, speed: float = 1.0, loop: bool = False,
           stop: threading.Event | None = None, progress: Callable[[ReplayStats], None] | None = None,
           progress_every_s: float = 2.0) -> ReplayStats:
    """Send `take` in real time (`speed` times faster), from its first frame to its last, again
    and again with `loop` (its times then go on increasing: a loop starts one frame interval after
    the last frame), until `stop` is set. `progress(stats)` every `progress_every_s` wall seconds."""
    if not (np.isfinite(speed) and speed > 0):
        raise BodyCalError(f"speed {speed:g} is not a positive number", field="--speed")
    t = np.asarray(take.time, float)
    if t.size == 0:
        raise BodyCalError("the take has no frame", source=take.name)
    step = float(np.median(np.diff(t))) if t.size > 1 else 1.0 / 30.0
    period = float(t[-1] - t[0]) + step
    stats, stop = ReplayStats(), stop or threading.Event()
    start = time.perf_counter()
    next_note = start + progress_every_s
    next_announce = -np.inf
    while not stop.is_set():
        offset = stats.loops * period
        for k in range(t.size):
            due = start + (offset + t[k] - t[0]) / speed
            if _wait_until(due, stop):
                break
            now = time.perf_counter()
            stats.late += now - due > step / speed
            msgs = take.announcements() if t[k] + offset >= next_announce else []
            if msgs:
                next_announce = t[k] + offset + ANNOUNCE_EVERY_S
            msgs += take.messages(k, offset)
            msgs += [message(AVAILABLE, 1), message(TIME, float(t[k] + offset))]
            sender.send(bundles(msgs))
            stats.frames += 1
            stats.take_seconds = float(t[k] - t[0] + offset)
            if progress is not None and now >= next_note:
                progress(stats)
                next_note = now + progress_every_s
        if not loop or stop.is_set():
            break
        stats.loops += 1
    return stats


def _wait_until(due: float, stop: threading.Event) -> bool:
    """Sleep until `due` (perf_counter); True when `stop` was set meanwhile."""
    while True:
        left = due - time.perf_counter()
        if left <= 0:
            return stop.is_set()
        if stop.wait(min(left, 0.05)):
            return True
