"""What a live source hands out, whatever it reads (DESIGN.md "Live source").

A live source runs on its own thread and turns what arrives into `LiveFrame`s: device poses and
marker points in the internal frame (Blender's: right-handed, Z up, metres; FORMATS.md §1), each
frame stamped with its arrival time (`time.perf_counter`) and the sender's own time when the
sender gives one. Two ways to consume them:

- sinks (`add_sink`): called on the source's thread with every frame, in arrival order, for what
  must see them all (the recorder). A sink is quick: it copies, it does not compute.
- `latest()`: the newest frame nobody has taken yet, for a consumer that runs at its own pace (a
  Blender timer, the live solve). The hand-off is latest-wins: a new frame replaces one not yet
  taken, which is counted in `stats.dropped`, so the consumer never works through a backlog that
  grows while it falls behind, and the count says how far behind it was. `wait(timeout)` blocks
  until such a frame is there (at once when one is; False after `timeout`): a consumer that may
  block (a headless loop) takes a frame the moment it is complete, one that may not (Blender's UI
  timer) asks `wait(0)` whether one is there.

`LiveSource` is the protocol: `VmcReceiver` (receiver.py) implements it for the VMC protocol; a
source for Blender's own XR session or for OpenVR implements the same six members (DESIGN.md
"Live source" says how).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np


@dataclass(slots=True)
class LiveFrame:
    """One frame of a live source. `events` are what was announced with it, in order:
    ("device", name, kind, role or None) when a device is first seen or its kind or role is
    announced, ("marker", name) when a marker is first seen, ("segment", Segment) when a
    calibration step is announced (recording/model.py)."""

    index: int  # 0, 1, 2, ... in arrival order
    arrival: float  # time.perf_counter() when the frame was complete
    sender_time: float | None  # the sender's clock (VMC: /VMC/Ext/T), seconds
    devices: tuple[str, ...]  # the devices tracked in this frame
    positions: np.ndarray  # (len(devices), 3) metres, internal frame
    rotations: np.ndarray  # (len(devices), 4) unit quaternions w, x, y, z, internal frame
    markers: tuple[str, ...] = ()
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (len(markers), 3)
    events: tuple = ()


@dataclass
class SourceStats:
    """Counts a source keeps while it runs (written by its thread, read by anyone)."""

    datagrams: int = 0  # packets received
    frames: int = 0  # frames made
    dropped: int = 0  # frames replaced in the latest-wins slot before a consumer took them
    bad_datagrams: int = 0  # packets that are not OSC (truncated, garbage): skipped
    bad_messages: int = 0  # known addresses with wrong arguments (too few, wrong types, NaN, ...): skipped
    ignored_messages: int = 0  # addresses the source does not read (bones, blend shapes, ...)
    refused_names: int = 0  # new devices or markers beyond the source's limit: skipped
    cpu_seconds: float = 0.0  # CPU time of the source's thread so far (time.thread_time)
    scaled_devices: set = field(default_factory=set)  # devices sent only scaled to the sender's avatar
    last_error: str = ""  # what the last bad packet or message was, one line
    sink_error: str = ""  # a sink that raised: it is no longer called

    def line(self) -> str:
        """One line for the command line's progress and summary, and the Live panel: what arrived,
        "nothing received" while no packet has (a sender that says it sends may not)."""
        if not self.datagrams:
            return "nothing received yet (0 packets)"
        if not self.frames:
            return f"{self.datagrams} packets received, no device in them yet"
        parts = [f"{self.frames} frames"] + ([f"{self.dropped} dropped"] if self.dropped else [])
        bad = self.bad_datagrams + self.bad_messages
        if bad:
            parts.append(f"{bad} bad packets or messages skipped ({self.last_error})")
        if self.refused_names:
            parts.append(f"{self.refused_names} messages of devices beyond the limit skipped")
        return ", ".join(parts)


class LatestSlot:
    """The latest-wins hand-off: one frame at most, never a queue. Drops count from the first
    `take`: a source nobody consumes this way (the recorder alone) drops nothing."""

    def __init__(self):
        self._lock = threading.Lock()
        self._ready = threading.Event()  # set while a frame waits: `wait` wakes on it
        self._frame: LiveFrame | None = None
        self._consumed = False
        self.dropped = 0

    def put(self, frame: LiveFrame) -> None:
        with self._lock:
            if self._frame is not None and self._consumed:
                self.dropped += 1
            self._frame = frame
            self._ready.set()

    def take(self) -> LiveFrame | None:
        with self._lock:
            frame, self._frame = self._frame, None
            self._consumed = True
            self._ready.clear()
            return frame

    def wait(self, timeout: float) -> bool:
        """True once a frame waits to be taken (at once when one does), False after `timeout` s."""
        return self._ready.wait(max(timeout, 0.0)) if timeout > 0 else self._ready.is_set()


class LiveSource(Protocol):
    """A source of live frames (module docstring). `start` opens what it reads and starts its
    thread (a BodyCalError when it cannot: a port in use); `stop` ends it and returns once the
    thread has finished, after the last frame went to the sinks; both may be called twice."""

    stats: SourceStats

    def start(self) -> None: ...

    def stop(self) -> None: ...

    def latest(self) -> LiveFrame | None: ...

    def wait(self, timeout: float) -> bool: ...

    def add_sink(self, sink: Callable[[LiveFrame], None]) -> None: ...
