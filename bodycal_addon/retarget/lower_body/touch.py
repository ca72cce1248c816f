"""A hand resting on the trunk holds the estimated pelvis (DESIGN.md §6 "A lower body from head and
hands", "A touch-informed trunk"), offline, vectorised over frames.

The pelvis under the head (`body_path`) moves with every sway of the head; a performer swaying
with a hand on the belly sways over a pelvis that stays, and the hand stays on the belly. With only
the HMD and controllers the belly is estimated, so the hand then went in and out of it by the
head's sway. While a hand rests in front of the lower trunk (still in the room, in the zone a hand
on the belly or a hip is in, for a while) the pelvis keeps its offset from that hand over the floor,
the offset the head's pelvis had from it on average over the rest: the body under the head on
average, the hand on the body throughout; the spine bends between the pelvis and the skull base
(the spine IK aims at the skull base as always). Held through the whole rest (a hand comes to
rest as it touches), blended in before it and out after it.
"""

from __future__ import annotations

import numpy as np

from .body_path import VELOCITY_SMOOTH_S, BodyPath, gaussian
from .shape import LowerBodyShape, body_axes

REST_SPEED = 0.08  # m/s: a hand this slow in the room (smoothed over SPEED_SMOOTH_S) rests
SPEED_SMOOTH_S = 0.15
REST_MIN_S = 0.6  # a rest shorter than this is a hand passing by
BLEND_S = 0.3  # the hold's blend in before a rest and out after it
# The zone in front of the lower trunk (body axes from the head's pelvis, x stature): across the
# body, in front of the hip joints to a forearm's length, from the hips up to below the chest.
ACROSS = 0.12
FORWARD = (-0.02, 0.14)
UP = (-0.03, 0.2)


def hold_pelvis(shape: LowerBodyShape, time: np.ndarray, path: BodyPath, wrists: np.ndarray) -> BodyPath:
    """`path` with its pelvis held by the hands resting on the lower trunk (the module docstring);
    `wrists` (F, 2, 3) where the hand devices put the wrists. The same path when no hand rests."""
    F = len(time)
    if F < 3:
        return path
    fps = (F - 1) / max(float(time[-1] - time[0]), 1e-9)
    H = shape.stature
    axes = body_axes(path.heading)  # (F, 3, 3) columns right, forward, up
    weight, target = np.zeros(F), np.zeros((F, 2))
    for k in range(wrists.shape[1]):
        w = wrists[:, k]
        local = np.einsum("fji,fj->fi", axes, w - path.pelvis)
        speed = gaussian(np.linalg.norm(np.gradient(w, time, axis=0), axis=1), SPEED_SMOOTH_S * fps)
        rest = ((np.abs(local[:, 0]) < ACROSS * H) & (local[:, 1] > FORWARD[0] * H) & (local[:, 1] < FORWARD[1] * H)
                & (local[:, 2] > UP[0] * H) & (local[:, 2] < UP[1] * H) & (speed < REST_SPEED))
        blend = max(int(round(BLEND_S * fps)), 1)
        for a, b in _runs(rest, int(round(REST_MIN_S * fps))):
            # the offset in body axes, the head's pelvis's from the hand on average over the rest
            off = local[a:b].mean(axis=0)
            held = (w[a:b] - np.einsum("fij,j->fi", axes[a:b], off))[:, :2]
            # held through the whole rest (a hand comes to rest as it touches), blended in before
            # it and out after it from where the hold begins and ends
            a0, b1 = max(a - blend, 0), min(b + blend, F)
            ramp = np.concatenate([_smoothstep((np.arange(a0, a) - (a - blend) + 0.5) / blend), np.ones(b - a),
                                   _smoothstep(((b + blend) - np.arange(b, b1) - 0.5) / blend)])
            value = np.concatenate([np.repeat(held[:1], a - a0, axis=0), held, np.repeat(held[-1:], b1 - b, axis=0)])
            weight[a0:b1] += ramp
            target[a0:b1] += ramp[:, None] * value
    on = weight > 0
    if not on.any():
        return path
    pelvis = path.pelvis.copy()
    share = np.minimum(weight[on], 1.0)
    pelvis[on, :2] = (1 - share)[:, None] * pelvis[on, :2] + share[:, None] * (target[on] / weight[on, None])
    velocity = gaussian(np.gradient(pelvis[:, :2], time, axis=0), VELOCITY_SMOOTH_S * fps)
    return BodyPath(path.neck, path.heading, path.lean, pelvis, path.pelvis_rot, path.lift, velocity)


def _runs(mask: np.ndarray, min_len: int) -> list[tuple[int, int]]:
    """[start, stop) of the runs of True at least `min_len` long."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    return [(int(a), int(b)) for a, b in zip(starts, stops, strict=True) if b - a >= max(min_len, 1)]


def _smoothstep(t: np.ndarray) -> np.ndarray:
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)
