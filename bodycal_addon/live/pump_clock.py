"""`PumpClock`: when a live session's pump should look for the next frame (DESIGN.md "Live session
in Blender", "The pump's clock"). No bpy, no clock of its own: every call is given `now`, so the
schedule is tested with an injected clock.

A pump on a fixed timer unsynchronised with the stream waits, on average, half a frame interval for
each frame (up to a whole one): at 90 Hz that alone is most of a one-frame latency budget. The
clock instead locks onto the stream: from the frames taken (their source index and arrival time)
it keeps the stream's period (the mean interval over the last `window` frames, frames skipped
counted by their indices; a pause starts the window again) and its phase (the earliest arrival the
last `phase_frames` frames project onto the next index: delays of the network and the threads only
ever make a frame later, so the least delayed of them shows the sender's beat best; few, so that
an error of the period is not multiplied far), and schedules the next look at the next frame's
expected arrival plus `margin_s`. A frame not there by then is late: the pump looks again every
`poll_s` until it comes, for up to `late_periods` periods; after that the stream has paused and
the pump runs at the display rate (`display_hz`) until a frame relocks it. It never waits longer
than one display interval (the viewport and the wizard's progress are refreshed at least that
often), and a frame already waiting (`pending`) is taken at once.
"""

from __future__ import annotations

from collections import deque

import numpy as np

DISPLAY_HZ = 90.0  # the pump's rate with no stream to lock on
MARGIN_S = 0.0005  # after a frame's expected arrival: the receiver's thread has stamped and handed it on
POLL_S = 0.001  # the look-again interval while a frame is late
LATE_PERIODS = 2.0  # no frame this many periods after the last: the stream paused
WINDOW = 90  # frames the period is estimated over (one second at 90 Hz)
PHASE_FRAMES = 8  # the last frames the phase is estimated from


class PumpClock:
    """The pump's schedule (module docstring). `taken(index, arrival)` with each frame the pump
    takes; `next_delay(now, pending)` the seconds until the pump should look again."""

    def __init__(self, display_hz: float = DISPLAY_HZ, margin_s: float = MARGIN_S, poll_s: float = POLL_S,
                 late_periods: float = LATE_PERIODS, window: int = WINDOW, phase_frames: int = PHASE_FRAMES):
        self.display_s = 1.0 / display_hz
        self.margin_s, self.poll_s, self.late_periods = margin_s, poll_s, late_periods
        self.phase_frames = phase_frames
        self._index: deque[int] = deque(maxlen=window)
        self._arrival: deque[float] = deque(maxlen=window)
        self.period: float | None = None  # seconds between the stream's frames, once two were taken
        self.expected: float | None = None  # the next frame's expected arrival (the clock's time)

    def taken(self, index: int, arrival: float) -> None:
        """A frame the pump took: its source index (0, 1, ... in arrival order: skipped frames
        leave gaps) and its arrival time. The period and phase are estimated again (relocked)."""
        if self._index and (index <= self._index[-1] or (  # a restarted source, or a pause: a new beat
                self.period is not None
                and arrival - self._arrival[-1] > self.late_periods * self.period * (index - self._index[-1]))):
            self._index.clear()
            self._arrival.clear()
            self.period = None
        self._index.append(index)
        self._arrival.append(arrival)
        if len(self._index) < 2:
            self.expected = None
            return
        idx, arr = np.asarray(self._index, float), np.asarray(self._arrival, float)
        span = arr[-1] - arr[0]
        if span <= 0.0:  # frames stamped at one instant (a burst): no beat to lock on
            self.period = self.expected = None
            return
        self.period = span / (idx[-1] - idx[0])
        recent = slice(-self.phase_frames, None)
        self.expected = float(np.min(arr[recent] + (idx[-1] + 1 - idx[recent]) * self.period))

    def next_delay(self, now: float, pending: bool = False) -> float:
        """Seconds from `now` until the pump should look for a frame; 0 when one is `pending`."""
        if pending:
            return 0.0
        if self.expected is None:  # no beat yet: the display rate
            return self.display_s
        due = self.expected + self.margin_s
        if now < due:
            return min(due - now, self.display_s)
        if now < self._arrival[-1] + self.late_periods * self.period:  # late: looked for often
            return self.poll_s
        return self.display_s  # paused: the next frame relocks the clock
