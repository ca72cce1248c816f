"""Blender's Bézier F-Curve keys in numpy: the handles its Auto Clamped rule gives a run of keys
and the value the curve then takes between them (FORMATS.md §4.2, "Bézier keys"), so the key
reduction can check its bound on the curve Blender will evaluate.

The rule is Blender's for an F-Curve whose Auto Handle Smoothing is None (`calchandleNurb_intern`
and `BKE_fcurve_handles_recalc_ex` in its sources; the bake sets that smoothing on its curves: the
default, Continuous Acceleration, solves a whole run of keys at once):
- a key's handles lie along the sum of the slopes to its neighbours, (2, s_prev + s_next), their
  horizontal reach 1 / 2.5614 of the interval on their side, each interval first capped at 5
  times the other;
- Auto Clamped: a key that is a local extreme of its curve (or level with a neighbour) gets flat
  handles; a handle that would pass its neighbour's value is cut to it and the other handle
  turned to stay in line;
- the first and last keys get flat handles (constant extrapolation).
Between two keys the curve is the cubic through the key, its right handle, the next key's left
handle and the next key; its value at a frame is found by solving the cubic's x(t) = frame (x is
monotonic in t: the handles reach less than half an interval).

Keys are given flat, several curves at once: `x` (N,) frames, `y` (N, C) values (C curves sharing
their frames, e.g. a quaternion's four channels), `first` / `last` (N,) marking each run's ends.
"""

from __future__ import annotations

import numpy as np

HANDLE_REACH = 2.5614  # Blender: a handle reaches 1 / 2.5614 of its interval
MAX_RATIO = 5.0  # an interval counts for at most 5 times its neighbour in a handle's reach
NEWTON_STEPS = 12


def auto_clamped_handles(x: np.ndarray, y: np.ndarray, first: np.ndarray, last: np.ndarray):
    """(left_x (N,), left_y (N, C), right_x (N,), right_y (N, C)): each key's handles."""
    x = np.asarray(x, float)
    y = np.asarray(y, float)
    prev_x, prev_y = np.roll(x, 1), np.roll(y, 1, axis=0)
    next_x, next_y = np.roll(x, -1), np.roll(y, -1, axis=0)
    # A run's ends see their one neighbour mirrored (Blender's `2 p2 - p3`).
    prev_x = np.where(first, 2 * x - next_x, prev_x)
    prev_y = np.where(first[:, None], 2 * y - next_y, prev_y)
    next_x = np.where(last, 2 * x - prev_x, next_x)
    next_y = np.where(last[:, None], 2 * y - prev_y, next_y)
    len_a, len_b = x - prev_x, next_x - x
    len_a = np.where(len_a == 0, 1.0, len_a)
    len_b = np.where(len_b == 0, 1.0, len_b)
    dir_x = (next_x - x) / len_b + (x - prev_x) / len_a
    dir_y = (next_y - y) / len_b[:, None] + (y - prev_y) / len_a[:, None]
    reach = dir_x * HANDLE_REACH
    reach = np.where(reach == 0, 1.0, reach)
    len_a = np.minimum(len_a, MAX_RATIO * len_b)
    len_b = np.minimum(len_b, MAX_RATIO * len_a)
    ka, kb = len_a / reach, len_b / reach
    left_x, right_x = x - dir_x * ka, x + dir_x * kb
    left_y, right_y = y - dir_y * ka[:, None], y + dir_y * kb[:, None]
    # Auto Clamped, inside a run: extremes flat; a handle past its neighbour's value cut to it.
    inner = (~first & ~last)[:, None]
    d1, d2 = prev_y - y, next_y - y
    extreme = inner & (((d1 <= 0) & (d2 <= 0)) | ((d1 >= 0) & (d2 >= 0)))
    rising = d1 <= 0
    left_cut = inner & ~extreme & np.where(rising, prev_y > left_y, prev_y < left_y)
    right_cut = inner & ~extreme & np.where(rising, next_y < right_y, next_y > right_y)
    left_y = np.where(left_cut, prev_y, left_y)
    right_y = np.where(right_cut, next_y, right_y)
    h1, h2 = (left_x - x)[:, None], (x - right_x)[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        right_y = np.where(left_cut, y + (y - left_y) / h1 * h2, right_y)
        left_y = np.where(right_cut & ~left_cut, y + (y - right_y) / h2 * h1, left_y)
    flat = extreme | (first | last)[:, None]
    left_y = np.where(flat, y, left_y)
    right_y = np.where(flat, y, right_y)
    return left_x, left_y, right_x, right_y


def evaluate(x: np.ndarray, y: np.ndarray, handles, seg: np.ndarray, at: np.ndarray) -> np.ndarray:
    """The curves' values (M, C) at frames `at` (M,), each inside the segment from key `seg` to key
    `seg + 1` (indices into the flat keys; `handles` from `auto_clamped_handles`)."""
    left_x, left_y, right_x, right_y = handles
    x0, x3 = np.asarray(x, float)[seg], np.asarray(x, float)[seg + 1]
    x1, x2 = right_x[seg], left_x[seg + 1]
    y0, y3 = np.asarray(y, float)[seg], np.asarray(y, float)[seg + 1]
    y1, y2 = right_y[seg], left_y[seg + 1]
    span = x3 - x0
    # Handles never reach past the next key (Blender's BKE_fcurve_correct_bezpart).
    over1, over2 = (x1 - x0) > span, (x3 - x2) > span
    if over1.any() or over2.any():
        f1 = np.where(over1, span / np.maximum(x1 - x0, 1e-300), 1.0)
        f2 = np.where(over2, span / np.maximum(x3 - x2, 1e-300), 1.0)
        x1, y1 = x0 + f1 * (x1 - x0), y0 + f1[:, None] * (y1 - y0)
        x2, y2 = x3 - f2 * (x3 - x2), y3 - f2[:, None] * (y3 - y2)
    c1, c2, c3 = 3 * (x1 - x0), 3 * (x0 - 2 * x1 + x2), x3 - x0 + 3 * (x1 - x2)
    target = np.asarray(at, float) - x0
    t = np.clip(target / np.where(span == 0, 1.0, span), 0.0, 1.0)
    for _ in range(NEWTON_STEPS):  # x(t) is monotonic: Newton from the linear guess converges fast
        f = ((c3 * t + c2) * t + c1) * t - target
        d = (3 * c3 * t + 2 * c2) * t + c1
        t = np.clip(t - f / np.where(d > 1e-12, d, 1e-12), 0.0, 1.0)
    t = t[:, None]
    s = 1.0 - t
    return s * s * s * y0 + 3 * s * s * t * y1 + 3 * s * t * t * y2 + t * t * t * y3


def runs(mask: np.ndarray):
    """The keys of curves given as rows of `mask` (n, F) (True: a key at that frame), flat and in
    order: (curve (N,), frame index (N,), first (N,), last (N,)), and for every frame of every curve
    the index of the segment it lies in (n, F): the key at or before it, the one before the last
    key for the frames from the last key on."""
    kc, kf = np.nonzero(mask)
    first = np.r_[True, kc[1:] != kc[:-1]]
    last = np.r_[kc[1:] != kc[:-1], True]
    counts = mask.sum(axis=1)
    ends = np.cumsum(counts)
    seg = np.cumsum(mask, axis=1) - 1 + (ends - counts)[:, None]
    seg = np.clip(seg, (ends - counts)[:, None], np.maximum(ends - 2, ends - counts)[:, None])
    return kc, kf, first, last, seg


def evaluate_keys(keep: np.ndarray, values: np.ndarray, frames: np.ndarray | None = None) -> np.ndarray:
    """What Bézier keys with Auto Clamped handles, at the kept frames of each curve (`keep` (F, G),
    values (F, G, C); a curve's first and last frames are keys), evaluate to at every frame:
    (F, G, C). `frames` (F,): the frames the keys are on (default 0, 1, 2 ...)."""
    f, g = keep.shape
    if f == 1:  # one key: the value, everywhere
        return np.asarray(values, float).copy()
    x_all = np.arange(f, dtype=float) if frames is None else np.asarray(frames, float)
    kc, kf, first, last, seg = runs(keep.T)
    x, y = x_all[kf], np.asarray(values[kf, kc], float)
    out = evaluate(x, y, auto_clamped_handles(x, y, first, last), seg.ravel(), np.tile(x_all, g))
    return out.reshape(g, f, -1).transpose(1, 0, 2)
