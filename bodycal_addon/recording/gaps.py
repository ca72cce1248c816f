"""Untracked frames of a track (arrays (F, N, ...) with a (F, N) tracked mask): fill short gaps
(positions linear, rotations slerp) and hold the last tracked value elsewhere, in place. Used by
the readers' post-processing and by the LED hand frames."""

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


def fill_gaps(time, values, valid, max_gap_s, rotations=None) -> tuple[int, int]:
    """Fill (in place) runs of invalid frames bounded by valid frames less than `max_gap_s` apart:
    positions linearly, rotations by slerp. Returns (gaps filled, frames filled)."""
    if values.shape[1] == 0 or len(time) < 3:
        return 0, 0
    prev, nxt = _gap_bounds(valid)
    f = len(time)
    inner = (~valid) & (prev >= 0) & (nxt < f)
    span = np.where(inner, time[np.clip(nxt, 0, f - 1)] - time[np.clip(prev, 0, f - 1)], np.inf)
    fill = inner & (span < max_gap_s)
    if not fill.any():
        return 0, 0
    fi, ci = np.nonzero(fill)
    p0, p1 = prev[fi, ci], nxt[fi, ci]
    alpha = (time[fi] - time[p0]) / (time[p1] - time[p0])
    values[fi, ci] = values[p0, ci] + alpha[:, None] * (values[p1, ci] - values[p0, ci])
    if rotations is not None:
        rotations[fi, ci] = tf.slerp(rotations[p0, ci], rotations[p1, ci], alpha)
    starts = fill & ~np.concatenate([np.zeros((1, fill.shape[1]), bool), fill[:-1]], axis=0)
    valid[fill] = True
    return int(starts.sum()), int(fill.sum())


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
