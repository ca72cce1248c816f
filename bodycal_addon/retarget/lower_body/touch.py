"""Hands resting on the body inform the estimated pelvis (DESIGN.md §6 "A lower body from head and
hands", "A touch-informed trunk"), offline, vectorised over frames: on the belly they hold it
(`hold_pelvis`), on the thighs they lift it (`rest_on_thighs`).

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

from ...core.geometry import two_bone_mid
from .body_path import BodyPath, gaussian, lift_of, over_the_floor
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
    velocity, centre, centre_velocity = over_the_floor(shape, time, path.neck, pelvis, on_pelvis=path.centre is None)
    return BodyPath(path.neck, path.heading, path.lean, pelvis, path.pelvis_rot, path.lift, velocity, centre,
                    centre_velocity)


def _runs(mask: np.ndarray, min_len: int) -> list[tuple[int, int]]:
    """[start, stop) of the runs of True at least `min_len` long."""
    d = np.diff(np.concatenate([[0], mask.astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    return [(int(a), int(b)) for a, b in zip(starts, stops, strict=True) if b - a >= max(min_len, 1)]


def _smoothstep(t: np.ndarray) -> np.ndarray:
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


# --- hands resting on the thighs ----------------------------------------------------------------------
# A leaning squat curls the spine: the pelvis is nearer the skull base than the trunk held rigid
# puts it (the synthetic performer's 0.583 m against 0.623), and the thighs pass below the palms
# resting on them. A palm still and facing down that a thigh can meet (the legs on the feet they
# stand on, bent forward, the trunk shortened by at most what a curled spine shortens it) is a hand
# resting on that thigh: the pelvis moves toward the skull base by the shortening that brings the
# thigh up under the palm, its median over the rest, held through it and blended in and out.
FACING = 0.5  # cos 60 deg: a resting palm faces down, and faces the thigh it rests on, at least this much
ALONG_THIGH = (0.2, 1.0)  # where along the thigh (hip 0, knee 1) a palm resting on it is
MAX_SHORTEN = 0.1  # x the pelvis-to-skull-base span: the most a curled spine shortens it (an arc
# through a right angle has a chord 0.90 of its length)
SHORTEN_STEPS = 41


def rest_on_thighs(shape: LowerBodyShape, time: np.ndarray, path: BodyPath, palms: np.ndarray,
                   stand) -> BodyPath:
    """`path` with its trunk shortened (the pelvis moved toward the skull base) by as much as puts
    the thighs under the hands resting on them (DESIGN.md §6 "A touch-informed trunk"); `palms`
    (F, 2, 2, 3) each hand's palm centre and normal (out of the palm) in the room, a zero normal
    where not known; `stand(path)` the feet a body on that path stands on ((F, 2, 3) ankles,
    (F, 2) headings, (F, 2) toes-down pitches), asked only when a hand may rest on a thigh. The
    same path when none does."""
    F = len(time)
    if F < 3 or not palms[..., 1, :].any():
        return path
    fps = (F - 1) / max(float(time[-1] - time[0]), 1e-9)
    centre, normal = palms[..., 0, :], palms[..., 1, :]
    speed = np.stack([gaussian(np.linalg.norm(np.gradient(centre[:, k], time, axis=0), axis=1), SPEED_SMOOTH_S * fps)
                      for k in range(2)], axis=1)
    still = (speed < REST_SPEED) & (normal[..., 2] < -FACING)  # (F, 2) a still palm facing down
    min_len = int(round(REST_MIN_S * fps))
    if not any(_runs(still[:, k], min_len) for k in range(2)):
        return path
    feet, headings, pitches = stand(path)
    rows = np.flatnonzero(still.any(axis=1))
    shorten = np.full((F, 2), np.nan)
    shorten[rows] = _shortening(shape, path, rows, centre[rows], normal[rows], feet[rows], headings[rows],
                                pitches[rows] != 0.0)
    weight, target = np.zeros(F), np.zeros(F)
    blend = max(int(round(BLEND_S * fps)), 1)
    for k in range(2):
        for a, b in _runs(still[:, k] & np.isfinite(shorten[:, k]), min_len):
            # the trunk's shortening the resting hand measures, on average over the rest, held
            # through it and blended in before and out after it
            value = float(np.median(shorten[a:b, k]))
            a0, b1 = max(a - blend, 0), min(b + blend, F)
            ramp = np.concatenate([_smoothstep((np.arange(a0, a) - (a - blend) + 0.5) / blend), np.ones(b - a),
                                   _smoothstep(((b + blend) - np.arange(b, b1) - 0.5) / blend)])
            weight[a0:b1] += ramp
            target[a0:b1] += ramp * value
    on = weight > 0
    if not on.any():
        return path
    amount = np.zeros(F)
    amount[on] = np.minimum(weight[on], 1.0) * target[on] / weight[on]
    pelvis = path.pelvis + amount[:, None] * (path.neck - path.pelvis)
    velocity, centre, centre_velocity = over_the_floor(shape, time, path.neck, pelvis, on_pelvis=path.centre is None)
    return BodyPath(path.neck, path.heading, path.lean, pelvis, path.pelvis_rot, lift_of(shape, pelvis[:, 2]),
                    velocity, centre, centre_velocity)


def _shortening(shape: LowerBodyShape, path: BodyPath, rows: np.ndarray, centre: np.ndarray, normal: np.ndarray,
                feet: np.ndarray, headings: np.ndarray, kneeling: np.ndarray) -> np.ndarray:
    """(R, 2) for each hand at the path's `rows` the least shortening of the trunk (x its span, up
    to `MAX_SHORTEN`) that brings a thigh up under its palm (the palm's centre on the thigh's skin,
    facing it, along it), NaN where none does. The legs stand on `feet` (R, 2, 3) turned to
    `headings` (R, 2), two-bone legs bent forward, none stretched past its length; a kneeling foot
    (`kneeling` (R, 2)) stands under its hip as a squatting one would."""
    axes = body_axes(path.heading[rows])  # (R, 3, 3)
    under = path.pelvis[rows, None] + np.einsum("rij,sj->rsi", axes, shape.ankle)
    under[..., 2] = shape.ankle_height
    ankles = np.where(kneeling[..., None], under, feet)
    heading = np.where(kneeling, path.heading[rows, None] + shape.foot_turn, headings)
    forward = np.stack([np.cos(heading), np.sin(heading), np.zeros_like(heading)], axis=-1)  # (R, 2, 3)
    c = np.linspace(0.0, MAX_SHORTEN, SHORTEN_STEPS)
    span = path.neck[rows] - path.pelvis[rows]
    pelvis = path.pelvis[rows][None] + c[:, None, None] * span[None]  # (C, R, 3)
    hips = pelvis[:, :, None] + np.einsum("rij,sj->rsi", axes, shape.hip)[None]  # (C, R, side, 3)
    knees, reached = _knees(shape, hips, ankles[None], forward[None])
    a, ab = hips[:, :, None], (knees - hips)[:, :, None]  # (C, R, 1, side, 3)
    p = centre[None, :, :, None]  # (1, R, hand, 1, 3)
    u = np.clip(np.einsum("...i,...i->...", p - a, ab) / np.maximum(np.einsum("...i,...i->...", ab, ab), 1e-12),
                0.0, 1.0)
    to_axis = a + u[..., None] * ab - p  # (C, R, hand, side, 3)
    d = np.linalg.norm(to_axis, axis=-1)
    gap = d - (shape.thigh_radii[0] + u * (shape.thigh_radii[1] - shape.thigh_radii[0]))
    facing = np.einsum("...i,...i->...", to_axis, normal[None, :, :, None]) > FACING * np.maximum(d, 1e-9)
    ok = (reached[:, :, None] & facing & (u >= ALONG_THIGH[0]) & (u <= ALONG_THIGH[1]))
    met = ok & (gap <= 0.0)
    first = np.argmax(met, axis=0)  # (R, hand, side): the first shortening at which the thigh meets the palm
    found = met.any(axis=0)
    g1 = np.take_along_axis(gap, first[None], axis=0)[0]
    prev = np.maximum(first - 1, 0)
    g0 = np.take_along_axis(gap, prev[None], axis=0)[0]
    ok0 = np.take_along_axis(ok, prev[None], axis=0)[0]
    frac = np.where((first > 0) & ok0 & (g0 > g1), g0 / np.where(g0 > g1, g0 - g1, 1.0), 1.0)
    amount = np.where(first > 0, c[prev] + np.clip(frac, 0.0, 1.0) * (c[1] - c[0]), 0.0)
    amount = np.where(found, amount, np.inf)
    best = amount.min(axis=-1)  # the thigh the rising body first meets under the palm
    return np.where(np.isfinite(best), best, np.nan)


def _knees(shape: LowerBodyShape, hips: np.ndarray, ankles: np.ndarray, forward: np.ndarray):
    """(..., 3) the knees of two-bone legs from `hips` to `ankles` (..., 3) bent toward `forward`,
    and (...,) whether the leg reaches (not stretched past its length)."""
    reached = np.linalg.norm(ankles - hips, axis=-1) <= shape.thigh + shape.shin
    return two_bone_mid(hips, ankles, shape.thigh, shape.shin, forward), reached
