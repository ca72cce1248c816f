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
often). A frame already waiting is taken at once, unless it has waited longer than the next frame
has still to come (more than half a period: the pump was busy when it came): then the next one is
waited for and taken instead (latest wins: the waiting one is skipped, counted as dropped). Its pose
is then shown that much later, but a whole period fresher; while the pump keeps up with the stream
(its work shorter than a period) no frame waits that long and none is skipped for it.
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
        self._beat = 0.0  # frame i is expected to arrive at _beat + i * period
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
        self._beat = float(np.min(arr[recent] - idx[recent] * self.period))
        self.expected = self.arrival_of(index + 1)

    def arrival_of(self, index: int) -> float | None:
        """When frame `index` is expected to arrive, on the beat; None before there is one."""
        return None if self.period is None else self._beat + index * self.period

    def next_delay(self, now: float, waiting: tuple[int, float] | None = None) -> float:
        """Seconds from `now` until the pump should look for a frame. `waiting`: the (index,
        arrival) of a frame waiting to be taken, if one does: 0 (at once) unless the next frame
        comes sooner than that one has waited (module docstring)."""
        if waiting is not None:
            index, arrival = waiting
            following = self.arrival_of(index + 1)
            if following is not None and 0.0 < following + self.margin_s - now < now - arrival:
                return following + self.margin_s - now
            return 0.0
        if self.expected is None:  # no beat yet: the display rate
            return self.display_s
        due = self.expected + self.margin_s
        if now < due:
            return min(due - now, self.display_s)
        if now < self._arrival[-1] + self.late_periods * self.period:  # late: looked for often
            return self.poll_s
        return self.display_s  # paused: the next frame relocks the clock
