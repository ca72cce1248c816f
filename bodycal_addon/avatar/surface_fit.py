"""Small robust fits for the avatar surface calibration (DESIGN.md §3-4), numpy only.

`geometry.py` owns the user-side fits; these are the few the raycasting needs: a median/MAD
outlier rejection for hit distances, an algebraic sphere fit with the 2-sigma second pass of
DESIGN.md §3, and the circle of a limb's cross-section.
"""

from __future__ import annotations

import numpy as np

MAD_K = 3.0  # reject beyond 3 scaled MADs (1.4826 MAD estimates sigma for Gaussian noise)
MIN_MAD = 0.0005  # metres: below half a millimetre of spread, nothing is an outlier
# A limb's cross-section is not a circle: a thigh's front (the quadriceps) stands 5-8 mm beyond the
# circle through the rest of its ring on the shared child avatar (13 % of its 57 mm radius), its
# inner front up to 4 mm under it. A hit within this fraction of the radius is the limb's own skin, never an
# outlier: with the MAD alone (most of the ring round within 1 mm) the thigh's front was dropped,
# its capsule sat ~8 mm under the skin there, and a palm laid on it sank that deep. A stray hit (a
# ray through a gap onto the other leg) lands tens of percent off and is still dropped.
SKIN_WITHIN = 0.2


def robust_keep(values: np.ndarray) -> np.ndarray:
    """Boolean mask of the values within MAD_K scaled MADs of the median."""
    v = np.asarray(values, float)
    if v.size == 0:
        return np.zeros(0, bool)
    return _keep_rows(v[None], np.ones((1, v.size), bool))[0]


def sphere_fit(points: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """Algebraic least-squares sphere (|p|² = 2 c·p + k), then a second pass without the points
    farther than 2 standard deviations from the mean distance to the centre (DESIGN.md §3).
    Returns (centre, radius = mean distance of the kept points, kept mask).
    Not `geometry.fit_sphere`, the user calibration's: that one refines the algebraic sphere to
    the geometric least squares and repeats the 2-sigma pass; on the demo's skull rays it moved
    the sphere by 0.1-0.3 mm and changed 1022 of the demo's 4108 baked curves."""
    p = np.asarray(points, float)
    if len(p) < 4:
        raise ValueError("a sphere fit needs at least 4 points")
    keep = np.ones(len(p), bool)
    for _ in range(2):
        q = p[keep]
        a = np.column_stack([2 * q, np.ones(len(q))])
        sol, *_ = np.linalg.lstsq(a, (q * q).sum(1), rcond=None)
        c = sol[:3]
        d = np.linalg.norm(p - c, axis=1)
        mu, sd = d[keep].mean(), d[keep].std()
        new = np.abs(d - mu) <= max(2 * sd, 1e-6)
        if new.sum() < 4 or np.array_equal(new, keep):
            break
        keep = new
    return c, float(np.linalg.norm(p[keep] - c, axis=1).mean()), keep


def _line_ends(stations, values, extend: float = 0.0) -> tuple[float, float]:
    """A least-squares line through per-station values, evaluated at 0 (head) and 1 (tail),
    clamped to the measured range widened by `extend` times its width on each side (0: no
    extrapolation beyond the stations)."""
    t, v = np.asarray(stations, float), np.asarray(values, float)
    if len(t) >= 2 and np.ptp(t) > 0:
        slope, icpt = np.polyfit(t, v, 1)
    else:
        slope, icpt = 0.0, float(v.mean())
    lo, hi = v.min(), v.max()
    w = extend * (hi - lo)
    return float(np.clip(icpt, lo - w, hi + w)), float(np.clip(icpt + slope, lo - w, hi + w))


def linear_radii(stations: np.ndarray, radii: np.ndarray, extend: float = 0.0) -> tuple[float, float]:
    """Head and tail radius of a capsule from per-station radii (stations clear of the joints): a
    straight line through them at the joints, within the measured range (`extend` = 0: a
    phalanx's stations are close together and its neighbours interfere, so no wild
    extrapolation) or beyond it by `extend` times its width (a limb: the contacts land between
    the stations, and a thigh line clamped to the stations' range was ~9 mm under its middle),
    never under half the thinnest station."""
    head, tail = _line_ends(stations, radii, extend)
    floor = 0.5 * float(np.min(radii))
    return max(head, floor), max(tail, floor)


def linear_offsets(stations: np.ndarray, centres: np.ndarray, extend: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Axis offsets at the head (0) and tail (1) from per-station cross-section centres (K, D): a
    straight line through them per component, bounded like linear_radii."""
    c = np.asarray(centres, float)
    head, tail = zip(*(_line_ends(stations, c[:, k], extend) for k in range(c.shape[1])))
    return np.array(head), np.array(tail)


MAX_AXIS_OFFSET = 0.75  # of the radius: the bone stays inside its capsule


def _weighted_circles(q, w):
    """Algebraic circles |p|² = 2 c·p + k per station, least squares with weights w (S, K):
    3x3 normal equations, batched. Returns centres (S, 2) and radii (S,)."""
    a = np.concatenate([2 * q, np.ones(q.shape[:2] + (1,))], axis=-1)
    aw = a * (w * w)[..., None]
    m = np.einsum("ski,skj->sij", aw, a)
    empty = (w > 0).sum(axis=1) < 3  # kept solvable; the caller discards these stations
    m[empty] += np.eye(3)
    sol = np.linalg.solve(m, np.einsum("ski,sk->si", aw, (q * q).sum(-1))[..., None])[..., 0]
    c = sol[:, :2]
    return c, np.sqrt(np.maximum(sol[:, 2] + (c * c).sum(-1), 0.0))


def _row_median(v, mask):
    """Median of each row's entries where `mask` (0 for a row without any), (S, 1)."""
    srt = np.sort(np.where(mask, v, np.inf), axis=1)
    n = mask.sum(axis=1)
    lo = np.take_along_axis(srt, np.maximum((n - 1) // 2, 0)[:, None], axis=1)
    hi = np.take_along_axis(srt, (n // 2)[:, None], axis=1)
    return np.where((n == 0)[:, None], 0.0, 0.5 * (lo + hi))


def _median_scale(res, mask):
    """Per-station median and scaled MAD (at least MIN_MAD) of the residuals where `mask`."""
    med = _row_median(res, mask)
    return med, np.maximum(1.4826 * _row_median(np.abs(res - med), mask), MIN_MAD)


def _keep_rows(v, mask):
    """Per row, the entries where `mask` within MAD_K scaled MADs of that row's median."""
    med, scale = _median_scale(v, mask)
    return mask & (np.abs(v - med) <= MAD_K * scale)


def _section_scale(res, mask, radius):
    """`_median_scale` of a cross-section's residuals, the scale at least SKIN_WITHIN of its circle's
    radius over MAD_K (whatever lies within that fraction of the radius is kept)."""
    med, scale = _median_scale(res, mask)
    return med, np.maximum(scale, SKIN_WITHIN / MAD_K * radius[:, None])


def cross_sections(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Circles through a limb's cross-sections, all stations at once: (S, K, 2) hit points around
    the bone (at the origin), NaN where a ray missed. Algebraic fit, re-weighted (Cauchy) so a
    stray hit cannot drag it, then the hits beyond MAD_K scaled MADs of the residual are dropped
    and the circle fitted again. The centre is pulled back toward the bone to at most
    MAX_AXIS_OFFSET of the radius (a few hits on one side must not move the capsule off its
    bone). Returns centres (S, 2), radii (S,) = mean distance of the kept points, kept (S, K);
    NaN centre and radius for a station with fewer than 3 hits."""
    p = np.asarray(points, float)
    valid = np.isfinite(p).all(axis=-1)
    q = np.where(valid[..., None], p, 0.0)
    enough = valid.sum(axis=1) >= 3
    w = valid.astype(float)
    c, r = _weighted_circles(q, w)
    for _ in range(8):
        res = np.linalg.norm(q - c[:, None], axis=-1) - r[:, None]
        w = valid / (1.0 + (res / _section_scale(res, valid, r)[1]) ** 2)
        c_new, r_new = _weighted_circles(q, w)
        done = np.all(np.abs(c_new - c)[enough] < 1e-5) and np.all(np.abs(r_new - r)[enough] < 1e-5)  # 0.01 mm
        c, r = c_new, r_new
        if done:
            break
    res = np.linalg.norm(q - c[:, None], axis=-1) - r[:, None]
    med, scale = _section_scale(res, valid, r)
    keep = valid & (np.abs(res - med) <= MAD_K * scale)
    keep = np.where((keep.sum(axis=1) < 3)[:, None], valid, keep)
    c, _ = _weighted_circles(q, keep.astype(float))
    n = np.maximum(keep.sum(axis=1), 1)
    r = (np.linalg.norm(q - c[:, None], axis=-1) * keep).sum(axis=1) / n
    off = np.linalg.norm(c, axis=1)
    pull = off > MAX_AXIS_OFFSET * r
    if pull.any():
        c[pull] *= (MAX_AXIS_OFFSET * r[pull] / off[pull])[:, None]
        r = (np.linalg.norm(q - c[:, None], axis=-1) * keep).sum(axis=1) / n
    c[~enough], r[~enough] = np.nan, np.nan
    return c, r, keep & enough[:, None]

