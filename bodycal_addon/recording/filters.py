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
from ..core.transforms import continuous_quaternions, cross, quat_conj, quat_mul, rotate
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
    anchored: bool = True  # each device smoothed on the body part it moves with (filter_recording)

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

    def describe(self) -> str:
        """The parameters as the notes say them."""
        return (f"position {self.min_cutoff:g} Hz + {self.beta:g} Hz per m/s, rotation {self.rot_min_cutoff:g} Hz + "
                f"{self.rot_beta:g} Hz per rad/s" + (", forward and backward" if self.two_pass else ""))


DEFAULT_FILTER = OneEuro()  # what a take is smoothed with unless the user says otherwise (DESIGN.md §6b)


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
    if y0 is not None and len(x) == 1:  # a stream's frame: affine_scan's one step, without its copies
        return (1.0 - alpha) * y0 + alpha * x
    a = np.array(alpha, float, copy=True)
    if y0 is None:
        a[0] = 1.0
        y0 = 0.0
    return affine_scan(1.0 - a, a * x, y0)


def _one_euro(x: np.ndarray, dt: np.ndarray, velocity: np.ndarray, cfg_min: float, cfg_beta: float,
              d_cutoff: float, state: tuple | None = None, extra: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray]:
    """x (F, D, K) signals, dt (F,) seconds since the previous frame, velocity (F, D, 3) their raw
    rate of change (the speed is the norm of its low-passed components, as the paper filters ẋ).
    `state`: (the low-passed velocity, the output) of the frame before, to go on from; `extra`
    (F, D) Hz added to the cutoff. Returns (the output, the low-passed velocity)."""
    a_d = _alpha(d_cutoff, dt)[:, None, None]
    edx = _lowpass(velocity, np.broadcast_to(a_d, velocity.shape), None if state is None else state[0])
    cutoff = cfg_min + cfg_beta * np.linalg.norm(edx, axis=-1)
    if extra is not None:
        cutoff = cutoff + extra
    return _lowpass(x, _alpha(cutoff, dt[:, None])[..., None], None if state is None else state[1]), edx


def _dt(time: np.ndarray) -> np.ndarray:
    t = np.asarray(time, float)
    dt = np.diff(t, prepend=t[0] - (t[1] - t[0] if len(t) > 1 else 1.0 / 90.0))
    return np.maximum(dt, 1e-6)


def smooth_positions(time: np.ndarray, pos: np.ndarray, min_cutoff: float, beta: float, d_cutoff: float = 1.0,
                     two_pass: bool = True, extra: np.ndarray | None = None) -> np.ndarray:
    """One Euro of positions (F, D, 3) sampled at `time` (F,); `extra` (F, D) Hz added to the cutoff."""
    pos = np.asarray(pos, float)
    if len(pos) < 2:
        return pos.copy()

    def once(t, p, ex):
        dt = _dt(t)
        velocity = np.diff(p, axis=0, prepend=p[:1]) / dt[:, None, None]
        return _one_euro(p, dt, velocity, min_cutoff, beta, d_cutoff, extra=ex)[0]

    fwd = once(time, pos, extra)
    if not two_pass:
        return fwd
    bwd = once(-np.asarray(time, float)[::-1], pos[::-1], None if extra is None else extra[::-1])[::-1]
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
    vec = w * pv + pw * v + cross(v, pv)  # np.cross's products in its order, fewer calls
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
    touched). Untracked frames already hold the last tracked value, so they filter as a device at
    rest. `cfg.anchored` (the default): each device relative to the body part it moves with
    (`_anchored`); else every device in the room's frame."""
    cfg = cfg or OneEuro()
    out = copy.copy(rec)
    out.positions = smooth_positions(rec.time, rec.positions, cfg.min_cutoff, cfg.beta, cfg.d_cutoff, cfg.two_pass)
    out.rotations = smooth_rotations(rec.time, rec.rotations, cfg.rot_min_cutoff, cfg.rot_beta, cfg.d_cutoff,
                                     cfg.two_pass)
    if rec.markers is not None and rec.markers.shape[1]:
        out.markers = smooth_positions(rec.time, rec.markers, cfg.min_cutoff, cfg.beta, cfg.d_cutoff, cfg.two_pass)
    note = f"One Euro filter: {cfg.describe()}"
    if cfg.anchored:
        note += _anchored(rec, out, cfg)
    out.notes = list(rec.notes) + [note]
    return out


# Each device is smoothed in the frame of the body part it moves with (DESIGN.md §6b): the limbs and
# the head on the pelvis, the fingers' markers on their hand; the pelvis and the feet (which stand
# on the world's floor) in the world.
WORLD_ROLES = ("pelvis", "foot_l", "foot_r")


def _anchor_index(rec: Recording, role: str) -> int | None:
    return next((i for i, d in enumerate(rec.devices) if d.role == role), None)


def _anchored(rec: Recording, out: Recording, cfg: OneEuro) -> str:
    """Smooth `out`'s limbs, head and hands again relative to the pelvis, and the finger markers
    relative to their hand (`out` holds the room-frame result, whose pelvis, feet and hand poses
    are the anchors): a hand resting on the belly keeps its place on the body however the body
    moves, the filter's speed term is the hand's speed over the body, and a hand meeting the other
    hand fast is hardly smoothed at that moment (`contact_cutoff`: a clap is not rounded off).
    Returns what the note adds."""
    pelvis = _anchor_index(rec, "pelvis")
    rel = [i for i, d in enumerate(rec.devices) if d.role not in WORLD_ROLES]
    hands = [i for i in rel if rec.devices[i].role in ("hand_l", "hand_r")]
    if pelvis is None:
        # Decision: without a pelvis tracker (a headset's kit) there is no body part to smooth on,
        # but a clap is still a clap: the hands are smoothed in the room with the contact term.
        # Without it the synthetic performer's clap with HMD and controllers opened 13.4 mm on the
        # avatar (p95; the wrists 33 mm apart at the contacts, the recording's 19).
        if len(hands) != 2:
            return " (no pelvis tracker: every device in the room's frame)"
        out.positions[:, hands] = smooth_positions(rec.time, rec.positions[:, hands], cfg.min_cutoff, cfg.beta,
                                                   cfg.d_cutoff, cfg.two_pass, contact_cutoff(rec, hands))
        return " (no pelvis tracker: every device in the room's frame, the hands with the contact term)"
    if rel:
        extra = np.zeros((len(rec.time), len(rel)))
        if len(hands) == 2:
            extra[:, [rel.index(h) for h in hands]] = contact_cutoff(rec, hands)
        out.positions[:, rel], out.rotations[:, rel] = _relative_smoothed(
            rec, rec.positions[:, rel], rec.rotations[:, rel], pelvis, out, cfg, extra)
    if rec.markers is not None and rec.markers.shape[1]:
        for side in ("l", "r"):
            hand = _anchor_index(rec, f"hand_{side}")
            idx = [k for k, n in enumerate(rec.marker_names) if n.endswith(f"_{side}")]
            if hand is not None and idx:
                out.markers[:, idx], _ = _relative_smoothed(rec, rec.markers[:, idx], None, hand, out, cfg)
    return ", each device on the body part it moves with"


def _relative_smoothed(rec: Recording, pos, rot, anchor: int, smoothed: Recording, cfg: OneEuro, extra=None):
    """(positions, rotations) of devices (F, D, 3) / (F, D, 4) smoothed in the anchor's frame and put
    back on the anchor's smoothed pose (`smoothed`'s)."""
    qa = rec.rotations[:, anchor][:, None]
    pa = rec.positions[:, anchor][:, None]
    local = rotate(quat_conj(qa), pos - pa)
    local = smooth_positions(rec.time, local, cfg.min_cutoff, cfg.beta, cfg.d_cutoff, cfg.two_pass, extra)
    qs, ps = smoothed.rotations[:, anchor][:, None], smoothed.positions[:, anchor][:, None]
    new_pos = ps + rotate(qs, local)
    if rot is None:
        return new_pos, None
    lrot = quat_mul(quat_conj(qa), rot)
    lrot = smooth_rotations(rec.time, lrot, cfg.rot_min_cutoff, cfg.rot_beta, cfg.d_cutoff, cfg.two_pass)
    return new_pos, quat_mul(qs, lrot)


# Measured on the synthetic contact motions (bench_retarget_quality's set, 0.5 mm / 1.5 mm noise,
# egocentric, the calibrated surface): the clap's p95 gap is 2.4 mm unfiltered, 20.7 mm filtered in
# the room, 7.1 mm with these (9.4 at 0.2 m / 30, 6.9 at 0.2 m / 60); more radius or gain lets more
# noise through while the hands move near each other (wrist acceleration up).
CONTACT_RADIUS = 0.25  # m between the controllers' origins: the hands may touch
CONTACT_BETA = 40.0  # Hz per m/s of the hands' relative speed, at full proximity
CONTACT_SPEED_CUTOFF = 8.0  # Hz: the relative speed's own low-pass


def contact_cutoff(rec: Recording, hands: list[int]) -> np.ndarray:
    """(F, 2) Hz added to the two hands' cutoffs: where they come near each other fast (a clap)
    they are hardly smoothed, so the filter does not round off the moment they meet; held
    together, they are smoothed as usual (their relative speed is small)."""
    rel = rec.positions[:, hands[1]] - rec.positions[:, hands[0]]
    dt = _dt(rec.time)
    speed = np.linalg.norm(np.diff(rel, axis=0, prepend=rel[:1]), axis=-1) / dt
    speed = _lowpass(speed, _alpha(CONTACT_SPEED_CUTOFF, dt))
    near = np.clip(1.0 - np.linalg.norm(rel, axis=-1) / CONTACT_RADIUS, 0.0, 1.0) ** 2
    return np.repeat((CONTACT_BETA * near * speed)[:, None], 2, axis=1)


def filter_pose(time: np.ndarray, basis: np.ndarray, locations: np.ndarray, cfg: OneEuro | None = None,
                metres_per_unit: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """A character's pose (DESIGN.md §8) One-Euro filtered, as `filter_recording` filters devices:
    each bone's rotation (`basis` (F, N, 4) quaternions) by its angular speed, its location
    (`locations` (F, N, 3), or (F, 3), in units of `metres_per_unit`) by its speed in metres.
    Returns new arrays."""
    cfg = cfg or OneEuro()
    basis = smooth_rotations(time, basis, cfg.rot_min_cutoff, cfg.rot_beta, cfg.d_cutoff, cfg.two_pass)
    loc = np.asarray(locations, float)
    flat = loc.ndim == 2
    metres = (loc[:, None] if flat else loc) * metres_per_unit
    metres = smooth_positions(time, metres, cfg.min_cutoff, cfg.beta, cfg.d_cutoff, cfg.two_pass) / metres_per_unit
    return basis, metres[:, 0] if flat else metres
