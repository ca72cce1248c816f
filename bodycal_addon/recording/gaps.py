"""Untracked frames of a track (arrays (F, N, ...) with a (F, N) tracked mask): bridge short gaps
and hold the last tracked value elsewhere, in place. Used by the readers' post-processing, the
solver's tracker reader (retarget/trackers.py) and the LED hand frames (DESIGN.md §6 "Lost devices").

A gap between two tracked frames is bridged by a cubic Hermite curve that leaves the last tracked
pose and reaches the next one at the device's own velocity there (one-frame differences with the
neighbouring tracked frames): positions component-wise; rotations as the slerp between the two
ends times a correction `exp(c(s))` whose Hermite curve is zero at both ends and whose slopes make
up the difference between the slerp's constant angular velocity and the device's own (body frame),
so the rotation and its angular velocity are continuous at both ends and every value is a unit
quaternion. `linear=True` gives the straight line and the slerp (the readers' former fill).
"""

from __future__ import annotations

import numpy as np

from ..core import transforms as tf


def _gap_bounds(valid: np.ndarray):
    """For every frame and column: index of the last valid frame at or before, and of the first
    valid frame at or after (-1 / F when none)."""
    f = valid.shape[0]
    idx = np.arange(f)[:, None]
    prev = np.maximum.accumulate(np.where(valid, idx, -1), axis=0)
    nxt = np.minimum.accumulate(np.where(valid, idx, f)[::-1], axis=0)[::-1]
    return prev, nxt


def quat_log(q: np.ndarray) -> np.ndarray:
    """Rotation vectors (..., 3) of unit quaternions (..., 4) w x y z, the shorter way round."""
    q = np.where(q[..., :1] < 0, -q, q)
    s = np.linalg.norm(q[..., 1:], axis=-1)
    angle = 2.0 * np.arctan2(s, q[..., 0])
    k = np.where(s > 1e-12, angle / np.where(s > 1e-12, s, 1.0), 2.0)
    return q[..., 1:] * k[..., None]


def quat_exp(v: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) of rotation vectors (..., 3)."""
    v = np.asarray(v, float)
    angle = np.linalg.norm(v, axis=-1)
    half = 0.5 * angle
    k = np.where(angle > 1e-12, np.sin(half) / np.where(angle > 1e-12, angle, 1.0), 0.5)
    return np.concatenate([np.cos(half)[..., None], v * k[..., None]], axis=-1)


def _neighbour(time, valid, end, step, ci):
    """The frame `end + step` beside each gap end (clipped to the take), whether it is tracked in
    column `ci` and comes at a later time than the other, and the time between the two."""
    f = len(time)
    nb = end + step
    nbc = np.clip(nb, 0, f - 1)
    dt = (time[end] - time[nbc]) * -step
    return (nb >= 0) & (nb < f) & valid[nbc, ci] & (dt > 0), nbc, dt


def _end_velocity(time, values, valid, end, step, ci, chord):
    """The velocity of column `ci` at tracked frame `end` from its neighbour `end + step` when that
    one is tracked too (else `chord`, the gap's own straight line)."""
    ok, nbc, dt = _neighbour(time, valid, end, step, ci)
    v = (values[np.where(step > 0, nbc, end), ci] - values[np.where(step > 0, end, nbc), ci]) / \
        np.where(ok, dt, 1.0)[:, None]
    return np.where(ok[:, None], v, chord)


def _angular_velocity(time, quats, valid, end, step, ci, chord):
    """The body-frame angular velocity of column `ci` at tracked frame `end` (see `_end_velocity`)."""
    ok, nbc, dt = _neighbour(time, valid, end, step, ci)
    a = quats[np.where(step > 0, end, nbc), ci]
    b = quats[np.where(step > 0, nbc, end), ci]
    w = quat_log(tf.quat_mul(tf.quat_conj(a), b)) / np.where(ok, dt, 1.0)[:, None]
    return np.where(ok[:, None], w, chord)


def fill_gaps(time, values, valid, max_gap_s, rotations=None, *, linear: bool = False,
              min_gap_s: float = 0.0) -> tuple[int, int]:
    """Fill (in place) runs of invalid frames bounded by valid frames less than `max_gap_s` apart
    (and at least `min_gap_s`): cubic Hermite bridges at the device's own velocity (the module's
    docstring), or with `linear` positions linearly and rotations by slerp. Returns (gaps filled,
    frames filled). Gaps at the start or end of the take (one end unknown) are left alone."""
    if values.shape[1] == 0 or len(time) < 3:
        return 0, 0
    prev, nxt = _gap_bounds(valid)
    f = len(time)
    inner = (~valid) & (prev >= 0) & (nxt < f)
    span = np.where(inner, time[np.clip(nxt, 0, f - 1)] - time[np.clip(prev, 0, f - 1)], np.inf)
    fill = inner & (span < max_gap_s) & (span >= min_gap_s)
    if not fill.any():
        return 0, 0
    fi, ci = np.nonzero(fill)
    p0, p1 = prev[fi, ci], nxt[fi, ci]
    T = time[p1] - time[p0]
    s = (time[fi] - time[p0]) / T
    x0, x1 = values[p0, ci], values[p1, ci]
    if linear:
        values[fi, ci] = x0 + s[:, None] * (x1 - x0)
    else:
        chord = (x1 - x0) / T[:, None]
        v0 = _end_velocity(time, values, valid, p0, -1, ci, chord)
        v1 = _end_velocity(time, values, valid, p1, 1, ci, chord)
        h00, h10, h01, h11 = _hermite(s)
        values[fi, ci] = (h00[:, None] * x0 + h01[:, None] * x1
                          + (T * h10)[:, None] * v0 + (T * h11)[:, None] * v1)
    if rotations is not None:
        q0, q1 = rotations[p0, ci], rotations[p1, ci]
        if linear:
            rotations[fi, ci] = tf.slerp(q0, q1, s)
        else:
            r = quat_log(tf.quat_mul(tf.quat_conj(q0), q1))  # the turn from q0 to q1, q0's frame
            w_chord = r / T[:, None]  # the slerp's angular velocity (the same in both end frames)
            w0 = _angular_velocity(time, rotations, valid, p0, -1, ci, w_chord)
            w1 = _angular_velocity(time, rotations, valid, p1, 1, ci, w_chord)
            _, h10, _, h11 = _hermite(s)
            c = (T * h10)[:, None] * (w0 - w_chord) + (T * h11)[:, None] * (w1 - w_chord)
            q = tf.quat_mul(tf.quat_mul(q0, quat_exp(s[:, None] * r)), quat_exp(c))
            rotations[fi, ci] = tf.normalize(q)
    starts = fill & ~np.concatenate([np.zeros((1, fill.shape[1]), bool), fill[:-1]], axis=0)
    valid[fill] = True
    return int(starts.sum()), int(fill.sum())


def _hermite(s):
    """The cubic Hermite basis h00, h10, h01, h11 at s in [0, 1]."""
    s2, s3 = s * s, s * s * s
    return 2 * s3 - 3 * s2 + 1, s3 - 2 * s2 + s, -2 * s3 + 3 * s2, s3 - s2


def hold_untracked(values, valid, rotations=None) -> None:
    """Untracked frames take the last tracked value (the first tracked one before it), so arrays
    never carry NaN or jumps to the origin; `valid` still says they were not tracked."""
    if values.shape[1] == 0 or values.shape[0] == 0:
        return
    prev, nxt = _gap_bounds(valid)
    src = np.where(prev >= 0, prev, nxt)
    fi, ci = np.nonzero(~valid & (src < valid.shape[0]))
    values[fi, ci] = values[src[fi, ci], ci]
    if rotations is not None:
        rotations[fi, ci] = rotations[src[fi, ci], ci]
        never = ~valid.any(axis=0)
        rotations[:, never] = (1.0, 0.0, 0.0, 0.0)


def ride_gaps(time, values, valid, rotations, carrier_values, carrier_rotations, *, min_gap_s: float = 0.0,
              causal: bool = False) -> int:
    """Untracked frames (in place) ride on a carrier: the device's pose in the carrier's frame
    (carrier (F, N, 3) positions and (F, N, 4) rotations, one per column, tracked or bridged
    there) at the gap's last tracked frame, blended to the one at its next tracked frame (lerp,
    slerp, by time: the pose meets both ends), then carried by the carrier frame by frame. Only
    gaps of at least `min_gap_s` between two tracked frames (a gap at the start or end of the take
    rides on the one relation it has). `causal`: the relation at the gap's start only (a live
    stream cannot see the far end). `valid` is left as it is. Returns the frames moved."""
    f = len(time)
    if values.shape[1] == 0 or f == 0:
        return 0
    prev, nxt = _gap_bounds(valid)
    if causal:
        nxt = np.full_like(nxt, f)
    seen = (prev >= 0) | (nxt < f)
    span = np.where((prev >= 0) & (nxt < f), time[np.clip(nxt, 0, f - 1)] - time[np.clip(prev, 0, f - 1)], np.inf)
    ride = ~valid & seen & (span >= min_gap_s)
    if not ride.any():
        return 0
    fi, ci = np.nonzero(ride)
    p0, p1 = prev[fi, ci], nxt[fi, ci]
    has0, has1 = p0 >= 0, p1 < f
    a, b = np.where(has0, p0, p1), np.where(has1, p1, p0)  # one end only: both read it

    def relation(k):
        cq = carrier_rotations[k, ci]
        return (tf.rotate(tf.quat_conj(cq), values[k, ci] - carrier_values[k, ci]),
                tf.quat_mul(tf.quat_conj(cq), rotations[k, ci]))

    (x0, q0), (x1, q1) = relation(a), relation(b)
    s = np.where(has0 & has1, (time[fi] - time[a]) / np.maximum(time[b] - time[a], 1e-12), 0.0)
    rel_x = x0 + s[:, None] * (x1 - x0)
    rel_q = tf.slerp(q0, q1, s)
    cq = carrier_rotations[fi, ci]
    values[fi, ci] = carrier_values[fi, ci] + tf.rotate(cq, rel_x)
    rotations[fi, ci] = tf.normalize(tf.quat_mul(cq, rel_q))
    return len(fi)


def extrapolate_gaps(time, values, valid, rotations, decay_s: float) -> int:
    """Untracked frames (in place) carried on from the last tracked frame at the device's own
    velocity and angular velocity there, decaying with time constant `decay_s` (the pose comes
    to rest `decay_s` times the speed further on): what a live stream could do without the far
    end. Measured against riding on a carrier (benchmarks/bench_lost_devices.py) and not used by
    the readers: it only delays the hold (DESIGN.md §6 "Lost devices"). Frames before the first
    tracked one are left alone. Returns the frames moved."""
    f = len(time)
    if values.shape[1] == 0 or f < 2:
        return 0
    prev, _ = _gap_bounds(valid)
    fi, ci = np.nonzero(~valid & (prev >= 0))
    if not len(fi):
        return 0
    p0 = prev[fi, ci]
    zero = np.zeros((len(fi), 3))
    v0 = _end_velocity(time, values, valid, p0, -1, ci, zero)
    w0 = _angular_velocity(time, rotations, valid, p0, -1, ci, zero)
    reach = decay_s * (1.0 - np.exp(-(time[fi] - time[p0]) / decay_s))
    values[fi, ci] = values[p0, ci] + reach[:, None] * v0
    rotations[fi, ci] = tf.normalize(tf.quat_mul(rotations[p0, ci], quat_exp(reach[:, None] * w0)))
    return len(fi)
