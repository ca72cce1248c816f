"""The One Euro filter on device poses (Casiez, Roussel & Vogel, CHI 2012: "1€ Filter: a simple
speed-based low-pass filter for noisy input in interactive systems"), the usual smoothing of VR
tracking: a first-order low-pass whose cutoff rises with speed, so a still tracker is smoothed hard
(its noise goes) and a fast one hardly (no lag on quick moves):

    dx̂_n = lowpass(ẋ_n, d_cutoff),  cutoff_n = min_cutoff + beta |dx̂_n|,  x̂_n = lowpass(x_n, cutoff_n)

with lowpass(v, fc): y_n = y_{n-1} + α_n (v_n - y_{n-1}), α = 1 / (1 + 1 / (2π fc dt)), ẋ from the
raw samples (the reference implementation's `lastRawValue`). Positions use their speed (m/s);
rotations their angular speed (rad/s), the quaternion's four components low-passed together
(hemisphere-aligned) and renormalised.

Once the cutoffs are known both low-passes are linear recurrences y_n = c_n y_{n-1} + b_n, solved
for all frames at once by a prefix scan of affine maps (log2 F vectorised passes, no loop over
frames, no division, so no underflow trouble).

`two_pass=True` (the default of `filter_recording`): a take being baked is known in full, so the
filter also runs backward in time and the two results are averaged: the forward pass lags, the
backward one leads by as much, and contacts keep their timing. `two_pass=False` is the causal
filter a live VR runtime uses; `OneEuroStream` runs it on a stream a block of frames at a time
(a live recording, `live.LiveRecording`), the recurrences carried from one block to the next, so
a take streamed frame by frame gets the forward filter of the whole take (to rounding).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from ..core.errors import BodyCalError
from ..core.transforms import continuous_quaternions
from .model import Recording


@dataclass(frozen=True)
class OneEuro:
    """Parameters (FORMATS.md-free; the CLI's --filter MIN_CUTOFF,BETA[,ROT_MIN_CUTOFF,ROT_BETA])."""

    # Defaults measured on benchmarks/bench_real_motion.py (0.5 mm / 0.3° of tracker noise): lower
    # cutoffs flatten the pelvis's own 1-2 Hz yaw in gait (the avatar's hip line strays 6-10°),
    # higher ones leave the noise (wrist acceleration 1.3x the source's and more).
    min_cutoff: float = 3.0  # Hz: the cutoff of a still device's position
    beta: float = 5.0  # Hz per m/s: how fast the position's cutoff rises with speed
    rot_min_cutoff: float = 4.0  # Hz
    rot_beta: float = 1.0  # Hz per rad/s
    d_cutoff: float = 1.0  # Hz: the speed estimate's own low-pass
    two_pass: bool = True

    def __post_init__(self):
        for name in ("min_cutoff", "beta", "rot_min_cutoff", "rot_beta", "d_cutoff"):
            v = getattr(self, name)
            if not np.isfinite(v) or v < 0 or (name in ("min_cutoff", "rot_min_cutoff", "d_cutoff") and v <= 0):
                raise BodyCalError(f"{name} must be a positive number, got {v}", field="filter",
                                   hint="e.g. --filter 3,5 (min cutoff in Hz, beta in Hz per m/s)")

    @classmethod
    def parse(cls, text: str) -> OneEuro:
        """'3,5' or '3,5,4,1' (position min cutoff, beta, then rotation's); '' or 'on' = defaults."""
        text = (text or "").strip().lower()
        if text in ("", "on", "default", "true", "1"):
            return cls()
        try:
            vals = [float(v) for v in text.split(",")]
        except ValueError:
            raise BodyCalError(f"'{text}' is not a list of numbers", field="--filter",
                               hint="use MIN_CUTOFF,BETA[,ROT_MIN_CUTOFF,ROT_BETA], e.g. 3,5") from None
        if len(vals) not in (2, 4):
            raise BodyCalError(f"expected 2 or 4 numbers, got {len(vals)}", field="--filter",
                               hint="use MIN_CUTOFF,BETA[,ROT_MIN_CUTOFF,ROT_BETA], e.g. 3,5")
        if len(vals) == 2:
            vals += [cls.rot_min_cutoff, cls.rot_beta]
        return cls(*vals)


def _alpha(cutoff, dt):
    return 1.0 / (1.0 + 1.0 / (2.0 * np.pi * cutoff * dt))


def affine_scan(c: np.ndarray, b: np.ndarray, y0) -> np.ndarray:
    """y_n = c_n y_{n-1} + b_n for every n (leading axis), y_{-1} = y0: Hillis-Steele prefix scan
    of the affine maps y -> c y + b (log2 F passes over the arrays)."""
    C = np.array(c, float, copy=True)
    B = np.array(b, float, copy=True)
    n = len(C)
    step = 1
    while step < n:
        B[step:] = C[step:] * B[:-step] + B[step:]
        C[step:] = C[step:] * C[:-step]
        step *= 2
    return C * y0 + B


def _lowpass(x: np.ndarray, alpha: np.ndarray, y0=None) -> np.ndarray:
    """First-order low-pass with per-frame α (F, ...) of x (F, ...); starts at x[0], or goes on from
    `y0` (the output of the frame before)."""
    a = np.array(alpha, float, copy=True)
    if y0 is None:
        a[0] = 1.0
        y0 = 0.0
    return affine_scan(1.0 - a, a * x, y0)


def _one_euro(x: np.ndarray, dt: np.ndarray, velocity: np.ndarray, cfg_min: float, cfg_beta: float,
              d_cutoff: float, state: tuple | None = None) -> tuple[np.ndarray, np.ndarray]:
    """x (F, D, K) signals, dt (F,) seconds since the previous frame, velocity (F, D, 3) their raw
    rate of change (the speed is the norm of its low-passed components, as the paper filters ẋ).
    `state`: (the low-passed velocity, the output) of the frame before, to go on from. Returns (the
    output, the low-passed velocity)."""
    a_d = _alpha(d_cutoff, dt)[:, None, None]
    edx = _lowpass(velocity, np.broadcast_to(a_d, velocity.shape), None if state is None else state[0])
    cutoff = cfg_min + cfg_beta * np.linalg.norm(edx, axis=-1)
    return _lowpass(x, _alpha(cutoff, dt[:, None])[..., None], None if state is None else state[1]), edx


def _dt(time: np.ndarray) -> np.ndarray:
    t = np.asarray(time, float)
    dt = np.diff(t, prepend=t[0] - (t[1] - t[0] if len(t) > 1 else 1.0 / 90.0))
    return np.maximum(dt, 1e-6)


def smooth_positions(time: np.ndarray, pos: np.ndarray, min_cutoff: float, beta: float, d_cutoff: float = 1.0,
                     two_pass: bool = True) -> np.ndarray:
    """One Euro of positions (F, D, 3) sampled at `time` (F,)."""
    pos = np.asarray(pos, float)
    if len(pos) < 2:
        return pos.copy()

    def once(t, p):
        dt = _dt(t)
        velocity = np.diff(p, axis=0, prepend=p[:1]) / dt[:, None, None]
        return _one_euro(p, dt, velocity, min_cutoff, beta, d_cutoff)[0]

    fwd = once(time, pos)
    if not two_pass:
        return fwd
    bwd = once(-np.asarray(time, float)[::-1], pos[::-1])[::-1]
    return 0.5 * (fwd + bwd)


def smooth_rotations(time: np.ndarray, quat: np.ndarray, min_cutoff: float, beta: float, d_cutoff: float = 1.0,
                     two_pass: bool = True) -> np.ndarray:
    """One Euro of unit quaternions (F, D, 4) (w, x, y, z), the cutoff from the angular speed."""
    q = continuous_quaternions(np.asarray(quat, float))
    if len(q) < 2:
        return q.copy()

    def once(t, qq):
        dt = _dt(t)
        prev = np.concatenate([qq[:1], qq[:-1]])
        return _one_euro(qq, dt, _angular_velocity(qq, prev, dt), min_cutoff, beta, d_cutoff)[0]

    fwd = once(time, q)
    out = fwd if not two_pass else 0.5 * (fwd + once(-np.asarray(time, float)[::-1], q[::-1])[::-1])
    return out / np.linalg.norm(out, axis=-1, keepdims=True)


def _angular_velocity(q: np.ndarray, prev: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """(F, D, 3) angular velocity ~ 2 vec(q_n conj(q_{n-1})) / dt (small turns between frames)."""
    w, v = q[..., :1], q[..., 1:]
    pw, pv = prev[..., :1], -prev[..., 1:]
    vec = w * pv + pw * v + np.cross(v, pv)
    return 2.0 * vec / dt[:, None, None]


class OneEuroStream:
    """The forward One Euro filter (`two_pass=False`) of one group of signals arriving a block of
    frames at a time: positions (F, D, 3) or unit quaternions (F, D, 4) (`rotations=True`). The
    recurrences of `smooth_positions` / `smooth_rotations` go on from the last frame of the
    previous block (the last sample, its time, the low-passed speed and the output), so any split
    of a take into blocks gives its forward filter, to rounding."""

    def __init__(self, cfg: OneEuro, rotations: bool = False):
        self.cfg, self.rotations = cfg, rotations
        self._last = None  # (time, sample, low-passed velocity, output) of the last frame

    def __call__(self, time: np.ndarray, x: np.ndarray) -> np.ndarray:
        time, x = np.asarray(time, float), np.asarray(x, float)
        if not len(time):
            return x.copy()
        cfg = self.cfg
        lo, beta = (cfg.rot_min_cutoff, cfg.rot_beta) if self.rotations else (cfg.min_cutoff, cfg.beta)
        if self._last is None:
            if self.rotations:
                x = continuous_quaternions(x)
            dt, prev, state = _dt(time), x[:1], None
        else:
            t0, x0, edx0, y0 = self._last
            if self.rotations:  # the same hemisphere as the frame before
                x = continuous_quaternions(np.concatenate([x0[None], x]))[1:]
            dt = np.maximum(np.diff(time, prepend=t0), 1e-6)
            prev, state = x0[None], (edx0, y0)
        prev = np.concatenate([prev, x[:-1]])
        velocity = _angular_velocity(x, prev, dt) if self.rotations else (x - prev) / dt[:, None, None]
        out, edx = _one_euro(x, dt, velocity, lo, beta, cfg.d_cutoff, state)
        self._last = (time[-1], x[-1], edx[-1], out[-1])
        return out / np.linalg.norm(out, axis=-1, keepdims=True) if self.rotations else out


def filter_recording(rec: Recording, cfg: OneEuro | None = None) -> Recording:
    """A copy of `rec` with every device pose and marker One-Euro filtered (the original is not
    touched). Untracked frames already hold the last tracked value, so they filter as a device at rest."""
    cfg = cfg or OneEuro()
    out = copy.copy(rec)
    out.positions = smooth_positions(rec.time, rec.positions, cfg.min_cutoff, cfg.beta, cfg.d_cutoff, cfg.two_pass)
    out.rotations = smooth_rotations(rec.time, rec.rotations, cfg.rot_min_cutoff, cfg.rot_beta, cfg.d_cutoff,
                                     cfg.two_pass)
    if rec.markers is not None and rec.markers.shape[1]:
        out.markers = smooth_positions(rec.time, rec.markers, cfg.min_cutoff, cfg.beta, cfg.d_cutoff, cfg.two_pass)
    out.notes = list(rec.notes) + [
        f"One Euro filter: position {cfg.min_cutoff:g} Hz + {cfg.beta:g} Hz per m/s, rotation "
        f"{cfg.rot_min_cutoff:g} Hz + {cfg.rot_beta:g} Hz per rad/s"
        + (", forward and backward" if cfg.two_pass else "")]
    return out
