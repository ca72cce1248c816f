"""Small robust fits for the avatar surface calibration (DESIGN.md §3-4), numpy only.

`geometry.py` owns the user-side fits; these are the few the raycasting needs: a median/MAD
outlier rejection for hit distances, an algebraic sphere fit with the 2-sigma second pass of
DESIGN.md §3, and the circle of a limb's cross-section.
"""

from __future__ import annotations

import numpy as np

MAD_K = 3.0  # reject beyond 3 scaled MADs (1.4826 MAD estimates sigma for Gaussian noise)
MIN_MAD = 0.0005  # metres: below half a millimetre of spread, nothing is an outlier


def robust_keep(values: np.ndarray) -> np.ndarray:
    """Boolean mask of the values within MAD_K scaled MADs of the median."""
    v = np.asarray(values, float)
    if v.size == 0:
        return np.zeros(0, bool)
    med = np.median(v)
    mad = max(1.4826 * np.median(np.abs(v - med)), MIN_MAD)
    return np.abs(v - med) <= MAD_K * mad


def sphere_fit(points: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """Algebraic least-squares sphere (|p|² = 2 c·p + k), then a second pass without the points
    farther than 2 standard deviations from the mean distance to the centre (DESIGN.md §3).
    Returns (centre, radius = mean distance of the kept points, kept mask)."""
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


def tilt(direction: np.ndarray, toward: np.ndarray, degrees: float) -> np.ndarray:
    """Unit `direction` turned by `degrees` towards `toward` (in their common plane)."""
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    t = np.asarray(toward, float) - np.dot(toward, d) * d
    t /= np.linalg.norm(t)
    a = np.radians(degrees)
    return np.cos(a) * d + np.sin(a) * t


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


def _weighted_circle(p, w):
    a = np.column_stack([2 * p, np.ones(len(p))]) * w[:, None]
    sol, *_ = np.linalg.lstsq(a, (p * p).sum(1) * w, rcond=None)
    c = sol[:2]
    return c, np.sqrt(max(sol[2] + c @ c, 0.0))


def cross_section(points: np.ndarray) -> tuple[np.ndarray, float, np.ndarray]:
    """Circle through a limb's cross-section (K, 2) hit points around the bone (at the origin):
    algebraic fit, re-weighted (Cauchy) so a stray hit cannot drag it, then the hits beyond MAD_K
    scaled MADs of the residual are dropped and the circle fitted again. The centre is pulled
    back toward the bone to at most MAX_AXIS_OFFSET of the radius (a few hits on one side must
    not move the capsule off its bone). Returns (centre (2,), radius = mean distance of the kept
    points, kept mask)."""
    p = np.asarray(points, float)
    w = np.ones(len(p))
    c, r = _weighted_circle(p, w)
    for _ in range(8):
        res = np.linalg.norm(p - c, axis=1) - r
        scale = max(1.4826 * np.median(np.abs(res - np.median(res))), MIN_MAD)
        w = 1.0 / (1.0 + (res / scale) ** 2)
        c, r = _weighted_circle(p, w)
    res = np.linalg.norm(p - c, axis=1) - r
    keep = robust_keep(res)
    if keep.sum() >= 3:
        c, r = _weighted_circle(p[keep], np.ones(int(keep.sum())))
    else:
        keep = np.ones(len(p), bool)
    r = float(np.linalg.norm(p[keep] - c, axis=1).mean())
    off = float(np.linalg.norm(c))
    if off > MAX_AXIS_OFFSET * r:
        c = c * (MAX_AXIS_OFFSET * r / off)
        r = float(np.linalg.norm(p[keep] - c, axis=1).mean())
    return c, r, keep

