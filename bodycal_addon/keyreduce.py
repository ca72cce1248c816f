"""Key reduction with a guaranteed error bound (issue 15): which samples of a densely sampled
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

The bound holds at every sample (the frames the every-frame bake would key); between samples
both the every-frame bake and the reduced one are linear.
"""

from __future__ import annotations

import numpy as np

DEFAULT_TOLERANCE_DEG = 0.1  # rotation: angle between the baked and the every-sample rotation
DEFAULT_LOCATION_TOLERANCE_MM = 0.5  # root location, world millimetres
BLOCK_FRAMES = 1024  # frames searched together (their first and last are keys)


def _reduce(samples: np.ndarray, tolerance: float, error) -> np.ndarray:
    """Key mask (G, F) for samples (G, F, C) such that error(true, lerp) <= tolerance at every
    frame, `error` taking (N, C) arrays and giving (N,) values that grow with the error."""
    g, f = samples.shape[:2]
    keep = np.zeros((g, f), bool)
    keep[:, 0] = keep[:, -1] = True
    if f <= 2 or tolerance <= 0:
        keep[:] = True
        return keep
    flat = samples.reshape(g * f, -1)
    # The frames still inside a segment not yet known to be within tolerance, as flat g*f indices
    # (sorted, so each segment is a contiguous run), with the flat indices of their segment's
    # first and last key.
    active = np.flatnonzero(~keep.ravel())
    rows = active // f
    first_key, last_key = rows * f, rows * f + f - 1
    while active.size:
        t = ((active - first_key) / (last_key - first_key))[:, None]
        err = error(flat[active], flat[first_key] * (1.0 - t) + flat[last_key] * t)
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


def _reduce_blocks(curves: np.ndarray, tolerance: float, error, unit: bool = False) -> np.ndarray:
    """Key mask (F, G) for curves (F, G, C), searched BLOCK_FRAMES frames at a time (every curve
    of a block at once; the frame shared by two blocks is a key of both). `unit`: each sample is
    normalised first (in float64)."""
    f, g = curves.shape[:2]
    keep = np.zeros((f, g), bool)
    if f <= 2 or tolerance <= 0:
        keep[:] = True
        return keep
    for start in range(0, f - 1, BLOCK_FRAMES):
        stop = min(start + BLOCK_FRAMES, f - 1) + 1
        block = np.ascontiguousarray(curves[start:stop].transpose(1, 0, 2), dtype=float)
        if unit:
            block /= np.linalg.norm(block, axis=-1, keepdims=True)
        keep[start:stop] |= _reduce(block, tolerance, error).T
    return keep


def _rotation_badness(true: np.ndarray, lerp: np.ndarray) -> np.ndarray:
    """1 - cos(angle / 2) between unit quaternions `true` and the normalised `lerp`: grows with
    the angle, and needs no arccos (the tolerance is turned into the same measure instead)."""
    norm2 = np.einsum("ij,ij->i", lerp, lerp)
    dot = np.abs(np.einsum("ij,ij->i", true, lerp))
    return 1.0 - dot / np.sqrt(np.maximum(norm2, 1e-300))


def _squared_distance(true: np.ndarray, lerp: np.ndarray) -> np.ndarray:
    d = true - lerp
    return np.einsum("ij,ij->i", d, d)


def rotation_keys(quaternions: np.ndarray, tolerance_rad: float) -> np.ndarray:
    """(F, B) mask of the frames to key for each bone's (F, B, 4) quaternion curve (already made
    continuous in sign: `transforms.continuous_quaternions`) so that nlerp between kept keys stays
    within `tolerance_rad` of every sample. A tolerance of 0 keeps every frame."""
    q = np.asarray(quaternions)
    tol = float(tolerance_rad)
    # Normalised: the badness 1 - cos(angle / 2) is ~4e-7 at 0.1 deg, and a float32 quaternion's
    # norm is off by up to ~6e-8, which would take 0.01 deg off (or add it to) the bound.
    return _reduce_blocks(q, 1.0 - np.cos(tol / 2.0) if tol > 0 else 0.0, _rotation_badness, unit=True)


def location_keys(locations: np.ndarray, tolerance: float) -> np.ndarray:
    """(F,) mask of the frames to key for an (F, 3) location curve so that lerp between kept keys
    stays within `tolerance` (same units) of every sample. A tolerance of 0 keeps every frame."""
    p = np.asarray(locations)
    tol = float(tolerance)
    return _reduce_blocks(p[:, None], tol * tol if tol > 0 else 0.0, _squared_distance)[:, 0]


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
