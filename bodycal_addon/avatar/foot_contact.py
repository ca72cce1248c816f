"""The sole's contact points measured on the avatar's skin (DESIGN.md §6, "Feet"; FORMATS.md §3,
`mesh:sole_<s>` `contact`): where a foot standing in its rest pose touches the floor, and which
skin points come lowest when it rolls.

A grid of rays is cast straight up from under the floor, over the foot's footprint and beyond it
(`GRID_ALONG` stations from `BEHIND` ankle-to-toe lengths behind the ankle to `BEYOND` past the
toe joint, `GRID_ACROSS` columns `HALF_WIDTH` either side): the first hits below `MAX_HEIGHT` of
the ankle's height sample the underside of the foot's skin (the heel's round, the arch, the ball,
the toes' tips), whatever the shoe or the foot's shape. From the hits:
- `heel`: the rearmost of the hits within `LOW_BAND` of the lowest (what a heel strike lands on);
- `ball`: of those, the one nearest the toe joint (the pivot of a toe-off);
- `support`: the hits that are the lowest for some way the foot may turn (pitched `PITCHES_DEG`,
  rolled `ROLLS_DEG`): the points of the skin that can touch the floor, kept by the plant above it.
  Rays cast forward at the back of the heel (`back_origins`) add its back, which no ray from under
  the floor reaches and which is lowest when the foot stands on its heel pitched far toes up.

The sole's outline (rays.py's six rays at a fifth of the ankle's height, put on the floor plane)
stays the surface element; these points are what the feet's plant stands on (feet.py).
"""

from __future__ import annotations

import numpy as np

GRID_ALONG = 24
GRID_ACROSS = 7
BEHIND = 0.6  # ankle-to-toe lengths behind the ankle (a heel's round lies 0.3-0.45 behind)
BEYOND = 0.8  # ankle-to-toe lengths past the toe joint (the toes' tips: 0.4-0.6)
HALF_WIDTH = 0.6  # ankle-to-toe lengths either side of the foot's line (a foot is 0.4-0.45 wide)
BELOW = 0.05  # m: the rays start this far under the floor
MAX_HEIGHT = 0.5  # of the ankle's height above the floor: skin higher up is not the sole's
LOW_BAND = 0.01  # m
MIN_HITS = 6  # fewer hits on the sole: not measured (the outline stands in)
PITCHES_DEG = np.arange(-60.0, 91.0, 10.0)  # toes up to 90 degrees: a dancer stands on the heel's back
ROLLS_DEG = (-20.0, -10.0, 0.0, 10.0, 20.0)
RAYS = GRID_ALONG * GRID_ACROSS
BACK_HEIGHTS = (0.1, 0.25, 0.4, 0.55, 0.7)  # of the ankle's height: the rays cast forward at the heel's back
BACK_ACROSS = (-0.15, 0.0, 0.15)  # ankle-to-toe lengths either side of the foot's line (a heel is 0.3 wide)
BACK_RAYS = len(BACK_HEIGHTS) * len(BACK_ACROSS)


def grid_origins(ankle: np.ndarray, toe: np.ndarray, floor: float, forward: np.ndarray, lateral: np.ndarray,
                 up: np.ndarray) -> np.ndarray:
    """(RAYS, 3) the rays' origins under the floor; every ray goes `up`."""
    length = float(np.linalg.norm((toe - ankle) - np.dot(toe - ankle, up) * up))
    along = np.linspace(-BEHIND * length, length * (1.0 + BEYOND), GRID_ALONG)
    across = np.linspace(-HALF_WIDTH * length, HALF_WIDTH * length, GRID_ACROSS)
    base = ankle + up * (floor - BELOW - float(ankle @ up))
    return (base + along[:, None, None] * forward + across[None, :, None] * lateral).reshape(-1, 3)


def back_origins(ankle: np.ndarray, toe: np.ndarray, floor: float, forward: np.ndarray, lateral: np.ndarray,
                 up: np.ndarray) -> tuple[np.ndarray, float]:
    """((BACK_RAYS, 3) origins behind the heel, every ray going `forward`, the rays' length): as far
    behind the ankle as the grid begins, up to the ankle (a hit beyond it is not the heel's back)."""
    length = float(np.linalg.norm((toe - ankle) - np.dot(toe - ankle, up) * up))
    height = float(ankle @ up) - floor
    base = ankle - BEHIND * length * forward + up * (floor - float(ankle @ up))
    out = [base + h * height * up + c * length * lateral for h in BACK_HEIGHTS for c in BACK_ACROSS]
    return np.array(out), BEHIND * length


def contact_points(hits: np.ndarray, ankle: np.ndarray, toe: np.ndarray, floor: float, forward: np.ndarray,
                   lateral: np.ndarray, up: np.ndarray, back: np.ndarray | None = None) -> dict | None:
    """{"heel": (3,), "ball": (3,), "support": (K, 3)} world points from the grid's hits (N, 3)
    (NaN rows: missed), or None when too few hit the sole; `back` (M, 3): the hits of the rays at
    the heel's back (`back_origins`), support only."""
    hits = np.asarray(hits, float).reshape(-1, 3)
    hits = hits[np.isfinite(hits).all(axis=1)]
    height = hits @ up - floor
    hits = hits[height <= MAX_HEIGHT * (float(ankle @ up) - floor)]
    if len(hits) < MIN_HITS:
        return None
    z = hits @ up
    low = hits[z <= z.min() + LOW_BAND]
    heel = low[np.argmin(low @ forward)]
    flat = (low - toe) - np.outer((low - toe) @ up, up)
    ball = low[np.argmin(np.linalg.norm(flat, axis=1))]
    p, r = np.meshgrid(np.radians(PITCHES_DEG), np.radians(ROLLS_DEG), indexing="ij")
    p, r = p.ravel()[:, None], r.ravel()[:, None]
    # "down" of a foot pitched by p (toes up for p > 0) and rolled by r, in the rest frame
    down = -(np.cos(p) * np.cos(r)) * up - np.sin(p) * forward - (np.cos(p) * np.sin(r)) * lateral
    if back is not None:
        back = np.asarray(back, float).reshape(-1, 3)
        hits = np.vstack([hits, back[np.isfinite(back).all(axis=1)]])
    keep = np.unique(np.argmax(down @ hits.T, axis=1))
    support = np.unique(np.vstack([hits[keep], heel, ball]), axis=0)
    return {"heel": heel, "ball": ball, "support": support}
