"""Key reduction with a guaranteed error bound (FORMATS.md §4.2, "Keys"): which samples of a densely sampled
curve to keep so that LINEAR interpolation between the kept keys reproduces every sample within
a tolerance.

- Rotations: per bone, the 4 quaternion channels keep the same frames, and the error is the angle
  between the sampled rotation and the one Blender evaluates between two kept keys: the
  component-wise lerp of the two keys, normalised (Blender normalises `rotation_quaternion`
  before it builds the bone's matrix), i.e. nlerp.
- Locations: per curve group, the Euclidean distance between the sampled point and the lerp.

The search is Douglas-Peucker run on every bone at once: each pass evaluates the interpolation
error of every frame still inside an unsettled segment, and splits every segment whose worst
frame is over the tolerance at that frame. A settled segment is never looked at again, so a pass
costs the frames still in play; the number of passes is the depth of the split tree (a few dozen
on mocap). Only numpy on arrays with a leading frame axis; no Python loop over frames or keys.

The take is searched in blocks of BLOCK_FRAMES frames whose end frames are always keys (one key
per bone every 11 s at 90 Hz, a few hundredths of a percent of the frames): a block's arrays stay
in the processor's cache and the split tree is shallower, which made the search 2-2.5x faster on
a 10-minute take with the same key count (benchmarks/bench_output.py).

Key values need not be the samples: a line through two noisy samples starts and ends off the
curve by the noise, and spends the tolerance on it. The keys take their values from the curve
smoothed by a 7-frame quadratic Savitzky-Golay filter, each value pulled back to within BAND x
the tolerance of its own sample; the error is still measured against every sample. On the CMU
walk with a SteamVR tracker's jitter (0.15 mm) this keeps 14% (egocentric) and 26% (rotations)
fewer keys, and on noise-free motion as many as the samples themselves do, within 1%
(benchmarks/bench_output.py).

The bound holds at every sample (the frames the every-frame bake would key); between samples
both the every-frame bake and the reduced one are linear.

Bézier keys (`bezier=True`): the same keys, then the curve Blender draws through them with Auto
Clamped handles (`bezier.py`) is checked at every sample, and each stretch between two keys where
it strays beyond the tolerance gets its worst sample as a key (valued as the sample), until none
does: the bound holds on the Bézier curve too. A key changes its neighbours' handles, so the
curves that got a key are checked again, a pass at a time.
"""

from __future__ import annotations

import numpy as np

from . import bezier

INTERPOLATIONS = ("linear", "bezier")  # the baked keys' interpolation (Bézier: Auto Clamped handles)
DEFAULT_TOLERANCE_DEG = 0.1  # rotation: angle between the baked and the every-sample rotation
DEFAULT_LOCATION_TOLERANCE_MM = 0.5  # root location, world millimetres
BLOCK_FRAMES = 1024  # frames searched together (their first and last are keys)
BAND = 0.7  # a key's value lies within BAND x the tolerance of its own sample
BEZIER_MARGIN = 0.999  # Bézier keys: the bound checked this much tighter (Blender evaluates in float32)
REFINE_ELEMENTS = 1 << 21  # Bézier check: curves x frames looked at together (memory)
# Savitzky-Golay, 7 frames, quadratic: the centre weights. A quadratic passes through unchanged, so
# smooth motion keeps its shape; white noise loses 57% of its amplitude.
_SMOOTHING = np.array([-2.0, 3.0, 6.0, 7.0, 6.0, 3.0, -2.0]) / 21.0
_HALF = len(_SMOOTHING) // 2


def _reduce(samples: np.ndarray, values: np.ndarray, tolerance: float, error) -> np.ndarray:
    """Key mask (G, F) for samples (G, F, C) such that error(sample, lerp of the two neighbouring
    keys' `values`) <= tolerance at every frame between keys, `error` taking (N, C) arrays and
    giving (N,) values that grow with the error. (Each key's own value must be within the
    tolerance of its sample, and the tolerance above 0: `_reduce_blocks` sees to both.)"""
    g, f = samples.shape[:2]
    keep = np.zeros((g, f), bool)
    keep[:, 0] = keep[:, -1] = True
    flat, value = samples.reshape(g * f, -1), values.reshape(g * f, -1)
    # The frames still inside a segment not yet known to be within tolerance, as flat g*f indices
    # (sorted, so each segment is a contiguous run), with the flat indices of their segment's
    # first and last key.
    active = np.flatnonzero(~keep.ravel())
    rows = active // f
    first_key, last_key = rows * f, rows * f + f - 1
    while active.size:
        t = ((active - first_key) / (last_key - first_key))[:, None]
        err = error(flat[active], value[first_key] * (1.0 - t) + value[last_key] * t)
        starts = np.flatnonzero(np.r_[True, first_key[1:] != first_key[:-1]])
        worst = np.maximum.reduceat(err, starts)
        bad = worst > tolerance
        if not bad.any():
            break
        # The first frame of each bad segment whose error is that segment's worst becomes a key,
        # splitting the segment in two; the frames of good segments are settled.
        seg_id = np.repeat(np.arange(len(starts)), np.diff(np.r_[starts, len(active)]))
        at_worst = np.flatnonzero((err == worst[seg_id]) & bad[seg_id])
        split = at_worst[np.r_[True, seg_id[at_worst[1:]] != seg_id[at_worst[:-1]]]]
        new_key = np.zeros(len(starts), np.int64)
        new_key[seg_id[split]] = active[split]
        keep.ravel()[active[split]] = True
        still = bad[seg_id]
        still[split] = False
        active, first_key, last_key, seg_id = active[still], first_key[still], last_key[still], seg_id[still]
        k = new_key[seg_id]
        before = active < k
        first_key = np.where(before, first_key, k)
        last_key = np.where(before, k, last_key)
    return keep


def _window(curves: np.ndarray, start: int, stop: int) -> np.ndarray:
    """Frames start - _HALF .. stop + _HALF - 1 of curves (F, G, C), float64, the take's ends
    continued by point reflection (2 x end - mirror image), which a straight line passes unchanged."""
    f = curves.shape[0]
    idx = np.arange(start - _HALF, stop + _HALF)
    inside = np.clip(idx, 0, f - 1)
    out = np.asarray(curves[inside], dtype=float)
    for end, lo in ((0, idx < 0), (f - 1, idx > f - 1)):
        if lo.any():
            mirror = np.clip(2 * end - idx[lo], 0, f - 1)
            out[lo] = 2.0 * np.asarray(curves[end], float) - np.asarray(curves[mirror], float)
    return out


def _smoothed(window: np.ndarray) -> np.ndarray:
    """The Savitzky-Golay smoothing of a window: _HALF frames shorter at each end."""
    n = window.shape[0] - 2 * _HALF
    out = _SMOOTHING[0] * window[:n]
    for k in range(1, len(_SMOOTHING)):
        out += _SMOOTHING[k] * window[k:k + n]
    return out


def _pulled_into_band(samples: np.ndarray, smooth: np.ndarray, radius: float, unit: bool) -> np.ndarray:
    """`smooth` moved toward `samples` (both (..., C)) until it is at most `radius` from it: an
    angle (rad) between unit quaternions along their great circle, or a Euclidean distance."""
    if not unit:
        d = smooth - samples
        return samples + d * np.minimum(1.0, radius / np.maximum(_norm(d), 1e-300))
    smooth = smooth / _norm(smooth)
    cos = np.einsum("...c,...c->...", samples, smooth)  # cos of half the angle between the two
    smooth *= np.where(cos < 0.0, -1.0, 1.0)[..., None]
    cos = np.abs(cos)
    # Outside the band: the sample turned by half the radius toward the smoothed value along their
    # great circle (no per-value trigonometry: the turn is the same for all of them).
    ortho = smooth - cos[..., None] * samples
    ortho /= np.maximum(_norm(ortho), 1e-300)
    edge = samples * np.cos(radius / 2.0) + ortho * np.sin(radius / 2.0)
    return np.where((cos >= np.cos(radius / 2.0))[..., None], smooth, edge)


def _norm(x: np.ndarray) -> np.ndarray:
    """Euclidean norms over the last axis, kept as a length-1 axis."""
    return np.sqrt(np.einsum("...c,...c->...", x, x))[..., None]


def _reduce_blocks(curves: np.ndarray, tolerance: float, error, radius: float, unit: bool,
                   out: np.ndarray) -> np.ndarray:
    """Key mask (F, G) for curves (F, G, C), searched BLOCK_FRAMES frames at a time (every curve
    of a block at once; the frame shared by two blocks is a key of both, with the same value).
    Key values within `radius` of their samples go to `out` (only at kept frames: `out` may be
    `curves` itself). `unit`: samples and values are unit quaternions (normalised in float64)."""
    f, g = curves.shape[:2]
    keep = np.zeros((f, g), bool)
    if f <= 2 or tolerance <= 0:
        keep[:] = True
        out[:] = curves
        return keep
    # Key values wait until no later block's window reads their frames (`out` may be `curves`).
    pending: list = []  # (last frame, (frames, curves), values)
    for start in range(0, f - 1, BLOCK_FRAMES):
        stop = min(start + BLOCK_FRAMES, f - 1) + 1
        window = _window(curves, start, stop)
        next_window = start + BLOCK_FRAMES - _HALF
        while pending and pending[0][0] < next_window:
            _, where, values = pending.pop(0)
            out[where] = values
        if unit:
            window /= _norm(window)
        samples = window[_HALF:-_HALF]
        # Rounded as they will be stored, so the bound is measured on what Blender evaluates.
        values = _pulled_into_band(samples, _smoothed(window), radius, unit).astype(out.dtype).astype(float)
        if unit:
            # a float32 quaternion's norm is off by up to ~6e-8: renormalising moves no direction
            values /= _norm(values)
        block_keep = _reduce(samples.transpose(1, 0, 2).copy(), values.transpose(1, 0, 2).copy(), tolerance,
                             error).T
        keep[start:stop] |= block_keep
        rows, cols = np.nonzero(block_keep)
        pending.append((stop - 1, (rows + start, cols), values[rows, cols]))
    for _, where, values in pending:
        out[where] = values
    return keep


def _refine_bezier(curves: np.ndarray, values: np.ndarray, keep: np.ndarray, tolerance: float, error,
                   unit: bool, frames: np.ndarray) -> None:
    """Add keys (to `keep` (F, G) and their values, the samples, to `values` (F, G, C)) until the
    Bézier curves through the kept keys (Blender's Auto Clamped handles) are within `tolerance`
    (in `error`'s measure) of every sample of `curves` (F, G, C). Curves are looked at in groups of
    about REFINE_ELEMENTS frames; within a group, only the curves that got a key are checked again."""
    f, g = keep.shape
    if f <= 2 or tolerance <= 0:
        return
    step = max(1, REFINE_ELEMENTS // f)
    for lo in range(0, g, step):
        todo = np.arange(lo, min(lo + step, g))
        while todo.size:
            added = _bezier_pass(curves, values, keep, tolerance, error, unit, frames, todo)
            todo = todo[np.isin(todo, added)]


def _bezier_pass(curves, values, keep, tolerance, error, unit, frames, cols) -> np.ndarray:
    """One check of curves `cols`: the worst sample of every stretch beyond the tolerance becomes a
    key. Returns the curves that got one."""
    sub = keep[:, cols].T  # (n, F): one row per curve, frames in order
    kc, kf, first, last, seg = bezier.runs(sub)
    x = frames[kf]
    y = np.asarray(values[kf, cols[kc]], float)
    handles = bezier.auto_clamped_handles(x, y, first, last)
    qc, qf = np.nonzero(~sub)  # every sample between keys (a curve's ends are always keys)
    if not qc.size:
        return np.empty(0, np.int64)
    seg = seg[qc, qf]
    approx = bezier.evaluate(x, y, handles, seg, frames[qf])
    true = np.asarray(curves[qf, cols[qc]], float)
    if unit:  # a float32 quaternion's norm would move the bound by ~0.01 deg (rotation_keys)
        true /= _norm(true)
    err = error(true, approx)
    starts = np.flatnonzero(np.r_[True, seg[1:] != seg[:-1]])
    worst = np.maximum.reduceat(err, starts)
    bad = np.flatnonzero(worst > tolerance)
    if not bad.size:
        return np.empty(0, np.int64)
    seg_of = np.repeat(np.arange(len(starts)), np.diff(np.r_[starts, len(seg)]))
    at_worst = np.flatnonzero((err == worst[seg_of]) & np.isin(seg_of, bad))
    pick = at_worst[np.r_[True, seg_of[at_worst[1:]] != seg_of[at_worst[:-1]]]]
    rows, cols_new = qf[pick], cols[qc[pick]]
    keep[rows, cols_new] = True
    new = np.asarray(curves[rows, cols_new], float)
    values[rows, cols_new] = new / _norm(new) if unit else new
    return np.unique(cols_new)


def _rotation_badness(true: np.ndarray, lerp: np.ndarray) -> np.ndarray:
    """1 - cos(angle / 2) between unit quaternions `true` and the normalised `lerp`: grows with
    the angle, and needs no arccos (the tolerance is turned into the same measure instead)."""
    norm2 = np.einsum("ij,ij->i", lerp, lerp)
    dot = np.abs(np.einsum("ij,ij->i", true, lerp))
    return 1.0 - dot / np.sqrt(np.maximum(norm2, 1e-300))


def _squared_distance(true: np.ndarray, lerp: np.ndarray) -> np.ndarray:
    d = true - lerp
    return np.einsum("ij,ij->i", d, d)


def _values_array(curves: np.ndarray, out: np.ndarray | None) -> np.ndarray:
    """Where key values go: `out`, or a copy of the curves (floating point)."""
    return np.array(curves, dtype=curves.dtype if curves.dtype.kind == "f" else float) if out is None else out


def _frames_of(frames, f: int) -> np.ndarray:
    return np.arange(f, dtype=float) if frames is None else np.asarray(frames, float)


def rotation_keys(quaternions: np.ndarray, tolerance_rad: float, out: np.ndarray | None = None, *,
                  bezier: bool = False, frames: np.ndarray | None = None):
    """(keep, values) for each bone's (F, B, 4) quaternion curve (already made continuous in sign:
    `transforms.continuous_quaternions`): the (F, B) mask of frames to key and an (F, B, 4) array
    holding, at each kept frame, the value to key there, such that nlerp between kept keys stays
    within `tolerance_rad` of every sample (with `bezier`, the normalised Bézier curves through
    them too: their keys at `frames`, default 0, 1, 2 ...). `values` is `out` when given (it may be
    `quaternions` itself: only kept frames are written). A tolerance of 0 keeps every sample as it is."""
    q = np.asarray(quaternions)
    tol = float(tolerance_rad)
    out = _values_array(q, out)
    # Normalised: the badness 1 - cos(angle / 2) is ~4e-7 at 0.1 deg, and a float32 quaternion's
    # norm is off by up to ~6e-8, which would take 0.01 deg off (or add it to) the bound.
    keep = _reduce_blocks(q, 1.0 - np.cos(tol / 2.0) if tol > 0 else 0.0, _rotation_badness, BAND * tol, True, out)
    if bezier and tol > 0:
        _refine_bezier(q, out, keep, 1.0 - np.cos(BEZIER_MARGIN * tol / 2.0), _rotation_badness, True,
                       _frames_of(frames, len(q)))
    return keep, out


def location_keys(locations: np.ndarray, tolerance: float, out: np.ndarray | None = None, *,
                  bezier: bool = False, frames: np.ndarray | None = None):
    """(keep, values) for an (F, 3) location curve: the (F,) mask of frames to key and an (F, 3)
    array holding the value to key at each kept frame, such that lerp between kept keys (with
    `bezier`, the Bézier curves through them, keyed at `frames`) stays within `tolerance` (same
    units) of every sample. `values` is `out` when given (it may be `locations` itself). A
    tolerance of 0 keeps every sample as it is."""
    p = np.asarray(locations)
    tol = float(tolerance)
    values = _values_array(p, out)
    keep = _reduce_blocks(p[:, None], tol * tol if tol > 0 else 0.0, _squared_distance, BAND * tol, False,
                          values[:, None])
    if bezier and tol > 0:
        _refine_bezier(p[:, None], values[:, None], keep, (BEZIER_MARGIN * tol) ** 2, _squared_distance, False,
                       _frames_of(frames, len(p)))
    return keep[:, 0], values


def rotation_error(true: np.ndarray, approx: np.ndarray) -> np.ndarray:
    """Angle (rad) between unit quaternions and (not necessarily unit) approximations, any shape
    (..., 4): what a pose bone shows, since Blender normalises the quaternion it evaluates."""
    approx = approx / np.linalg.norm(approx, axis=-1, keepdims=True)
    return 2.0 * np.arccos(np.minimum(np.abs((true * approx).sum(-1)), 1.0))


def interpolate(frames: np.ndarray, keep: np.ndarray, values: np.ndarray) -> np.ndarray:
    """What linear keys at `frames[keep]` evaluate to at every frame: (F, C) from (F, C) values
    (component-wise, as Blender's F-Curves do; quaternions still need normalising)."""
    kf = frames[keep]
    return np.stack([np.interp(frames, kf, values[keep, c]) for c in range(values.shape[1])], axis=1)
