"""A recording that grows as a live stream's frames arrive (DESIGN.md "Prepared solver"): the same
`Recording` every reader makes, whose arrays are views onto buffers filled by `append`, so the
user animation, the trackers and the feet plan read it as they read a file, a block of frames at a
time, and a frame appended is never copied again (the buffers double when full).

A frame's untracked devices (and markers) hold their last tracked pose, as the file readers fill
gaps, so a filter sees a device at rest; `valid` keeps saying which were tracked. With a One Euro
configuration the poses are filtered as they arrive, forward only (`filters.OneEuroStream`: the
causal filter; a bake's runs both ways over the whole take, which a stream cannot).
"""

from __future__ import annotations

import numpy as np

from ...core.errors import BodyCalError
from ..filters import OneEuro, OneEuroStream
from ..model import Device, Recording


class LiveRecording(Recording):
    """An append-only `Recording` of `devices` (their roles as the user's calibration knows them)
    and `marker_names`, sampled at about `rate` Hz (`fps` until two frames have arrived)."""

    def __init__(self, devices: list[Device], marker_names: list[str] | None = None, *, rate: float = 90.0,
                 name: str = "live", smooth: OneEuro | None = None):
        marker_names = list(marker_names or [])
        d, m = len(devices), len(marker_names)
        self._cap = 0
        self._n = 0
        self._raw: dict[str, np.ndarray] = {}  # the last frame's poses as given (held where untracked)
        self._buf = {"time": np.empty(0), "positions": np.empty((0, d, 3)), "rotations": np.empty((0, d, 4)),
                     "valid": np.zeros((0, d), bool), "markers": np.empty((0, m, 3)),
                     "marker_valid": np.zeros((0, m), bool)}
        super().__init__(name, self._buf["time"], list(devices), self._buf["positions"], self._buf["rotations"],
                         self._buf["valid"], marker_names, self._buf["markers"], self._buf["marker_valid"],
                         source=name)
        if smooth is not None and (smooth.two_pass or smooth.anchored):
            raise BodyCalError("a live stream can only be filtered forward, each device in the room's frame",
                               field="filter", hint="use OneEuro(two_pass=False, anchored=False)")
        self.rate = float(rate)
        self._smooth = None if smooth is None else (OneEuroStream(smooth), OneEuroStream(smooth, rotations=True),
                                                    OneEuroStream(smooth))

    @property
    def nbytes(self) -> int:
        """Memory the frames hold (grown by doubling: up to twice the frames appended)."""
        return sum(buf.nbytes for buf in self._buf.values())

    @property
    def fps(self) -> float:
        return super().fps if self._n >= 2 else self.rate

    def append(self, time, positions, rotations, valid, markers=None, marker_valid=None) -> range:
        """Add frames (a leading frame axis, or one frame without it): `time` (K,) seconds, strictly
        after the last; `positions` (K, D, 3), `rotations` (K, D, 4) w x y z, `valid` (K, D);
        `markers` (K, M, 3) and `marker_valid` (K, M) when the recording has markers. Returns the
        new frames' indices."""
        time = np.atleast_1d(np.asarray(time, float))
        k = len(time)
        new = {"time": time}
        for key, value, width in (("positions", positions, 3), ("rotations", rotations, 4),
                                  ("markers", markers, 3)):
            cols = self._buf[key].shape[1]
            value = np.zeros((k, cols, width)) if value is None and key == "markers" else np.asarray(value, float)
            new[key] = value.reshape(k, cols, width)
        for key, value in (("valid", valid), ("marker_valid", marker_valid)):
            cols = self._buf[key].shape[1]
            new[key] = (np.zeros((k, cols), bool) if value is None else np.asarray(value, bool)).reshape(k, cols)
        self._check(new)
        self._hold(new)
        if self._smooth is not None:
            pos_f, rot_f, mark_f = self._smooth
            new["positions"] = pos_f(time, new["positions"])
            new["rotations"] = rot_f(time, new["rotations"])
            if new["markers"].shape[1]:
                new["markers"] = mark_f(time, new["markers"])
        self._grow(self._n + k)
        for key, value in new.items():
            self._buf[key][self._n:self._n + k] = value
        self._n += k
        self._views()
        return range(self._n - k, self._n)

    def _check(self, new: dict) -> None:
        time = new["time"]
        last = self.time[-1] if self._n else -np.inf
        if not (np.all(np.isfinite(time)) and np.all(np.diff(np.concatenate([[last], time])) > 0)):
            raise BodyCalError("live frames must come in strictly increasing time", source=self.name, field="time")
        for key in ("positions", "rotations", "markers"):
            ok = new["valid" if key != "markers" else "marker_valid"]
            if not np.all(np.isfinite(new[key])[ok]):
                raise BodyCalError(f"a tracked device has non-finite {key}", source=self.name, field=key)

    def _hold(self, new: dict) -> None:
        """Untracked devices and markers hold their last tracked pose (a leading gap: the first
        pose given, whatever it is)."""
        for key, flag in (("positions", "valid"), ("rotations", "valid"), ("markers", "marker_valid")):
            value, ok = new[key], new[flag]
            if not ok.all():
                value = value.copy()
                for i in range(len(value)):  # the frames of one append: usually one
                    prev = value[i - 1] if i else self._raw.get(key, value[0])
                    value[i] = np.where(ok[i][:, None], value[i], prev)
                new[key] = value
            self._raw[key] = value[-1]  # before any filter: what the next untracked frame holds

    def _grow(self, n: int) -> None:
        if n <= self._cap:
            return
        cap = max(n, 2 * self._cap, 256)
        for key, buf in self._buf.items():
            bigger = np.zeros((cap,) + buf.shape[1:], buf.dtype)
            bigger[:self._n] = buf[:self._n]
            self._buf[key] = bigger
        self._cap = cap

    def _views(self) -> None:
        n, b = self._n, self._buf
        self.time, self.positions, self.rotations, self.valid = b["time"][:n], b["positions"][:n], \
            b["rotations"][:n], b["valid"][:n]
        self.markers, self.marker_valid = b["markers"][:n], b["marker_valid"][:n]
