"""Planted feet (DESIGN.md §6; beyond Delahaye 2023 and AvatarGo, whose feet follow their targets).

While the performer stands on a foot, the avatar's foot stays put and on the floor, in every
method:

1. Stance from the foot tracker (`detect`): the user's ankle, carried by its foot tracker,
   low (within STANCE_HEIGHT of where it stood at the reference time) and slow (its position,
   averaged over SMOOTH_S, moving slower than STANCE_SPEED), with hysteresis (a stance that has
   begun lasts until the ankle is faster than EXIT_SPEED or higher than EXIT_HEIGHT) and no stance
   shorter than MIN_STANCE_S.
2. A weight per frame (`Stance.weight`): 1 throughout a stance, easing in over the BLEND_S before
   it and out over the BLEND_S after it (smoothstep), so nothing pops and the easing happens while
   the foot still moves (a bake sees the whole take: it can look ahead).
3. The planted place (`planted_xy`): per stance, the mean over its frames of where the method puts the
   ankle (the rotation copy's and the mapping's: the user's ankle scaled like the root; AvatarGo's:
   its own eq. 2 target); the height: the ankle's height above its lowest sole point in the foot's
   current orientation (`sole_lift`), so the sole touches the floor whatever the foot does.
4. `pelvis_drop`: where a planted foot is out of the leg's reach (an avatar whose root rides too
   high: AvatarGo's eye-height scaling, long-legged users), the pelvis comes down as much as
   needed, weighted like the feet.
5. `lock` also keeps every sole above the floor when the foot is not planted (a swinging foot
   scuffing, a rotation copy whose legs are longer than the user's).

Everything is an array over frames; the stance of the whole recording is found once (it needs
the frames on both sides of a chunk's ends).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

STANCE_SPEED = 0.20  # m/s
EXIT_SPEED = 0.40  # m/s
STANCE_HEIGHT = 0.04  # m above the ankle's height at the reference time
EXIT_HEIGHT = 0.07  # m
SMOOTH_S = 0.06  # s: the ankle's position is averaged over this before its speed is taken
MIN_STANCE_S = 0.15  # s
BLEND_S = 0.12  # s
REACH = 0.999  # a planted leg is stretched to at most this fraction of its length


@dataclass
class Stance:
    weight: np.ndarray  # (F,) in [0, 1]
    label: np.ndarray  # (F,) int: the stance a frame belongs to, -1 outside
    count: int


def _moving_average(x: np.ndarray, n: int) -> np.ndarray:
    if n <= 1 or len(x) < 2:
        return x
    pad = n // 2
    xp = np.concatenate([np.repeat(x[:1], pad, 0), x, np.repeat(x[-1:], n - 1 - pad, 0)])
    c = np.cumsum(np.concatenate([np.zeros((1,) + x.shape[1:]), xp]), axis=0)
    return (c[n:] - c[:-n]) / n


def _runs(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Starts and stops (exclusive) of the runs of True."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    return np.flatnonzero(d == 1), np.flatnonzero(d == -1)


def detect(ankle: np.ndarray, time: np.ndarray, ref_height: float) -> Stance:
    """Stance of one foot from the user's ankle (F, 3) carried by its foot tracker."""
    F = len(ankle)
    if F < 3:
        return Stance(np.zeros(F), np.full(F, -1), 0)
    fps = (F - 1) / max(float(time[-1] - time[0]), 1e-9)
    smooth = _moving_average(np.asarray(ankle, float), max(1, int(round(SMOOTH_S * fps))))
    speed = np.linalg.norm(np.gradient(smooth, time, axis=0), axis=1)
    height = smooth[:, 2] - ref_height
    enter = (speed < STANCE_SPEED) & (height < STANCE_HEIGHT)
    hold = (speed < EXIT_SPEED) & (height < EXIT_HEIGHT)
    # Hysteresis without a loop over frames: a run of `hold` frames is a stance from its first
    # `enter` frame to its end.
    starts, stops = _runs(hold)
    stance = np.zeros(F, bool)
    if len(starts):
        first = np.full(len(starts), -1)
        idx = np.flatnonzero(enter)
        run_of = np.searchsorted(starts, idx, side="right") - 1
        ok = (run_of >= 0) & (idx < stops[np.clip(run_of, 0, None)])
        idx, run_of = idx[ok], run_of[ok]
        # the first enter frame of each run
        order = np.unique(run_of, return_index=True)
        first[order[0]] = idx[order[1]]
        for_runs = first >= 0
        a, b = first[for_runs], stops[for_runs]
        keep = (b - a) >= max(2, int(round(MIN_STANCE_S * fps)))
        a, b = a[keep], b[keep]
        d = np.zeros(F + 1, int)
        np.add.at(d, a, 1)
        np.add.at(d, b, -1)
        stance = np.cumsum(d[:-1]) > 0
    starts, stops = _runs(stance)
    label = np.full(F, -1)
    weight = np.zeros(F)
    if len(starts):
        n = max(1, int(round(BLEND_S * fps)))
        # Each stance eases in over the n frames before it and out over the n after it; where two
        # stances' easings meet the weight is the larger. Distance in frames to the nearest stance:
        t = np.arange(F)
        k = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(starts) - 1)  # last stance starting <= t
        after = np.where(t >= stops[k], t - stops[k] + 1, 0)  # frames past its end
        k2 = np.clip(k + 1, 0, len(starts) - 1)
        before = np.where(starts[k2] > t, starts[k2] - t, np.iinfo(np.int64).max)  # frames before the next
        before = np.where(t < starts[0], starts[0] - t, before)
        gap = np.minimum(np.where(t < starts[0], np.iinfo(np.int64).max, after), before)
        gap = np.where(stance, 0, gap)
        s = np.clip(1.0 - gap / (n + 1.0), 0.0, 1.0)
        weight = s * s * (3.0 - 2.0 * s)
        # the stance each frame eases toward (inside: its own)
        near_next = before < np.where(t < starts[0], np.iinfo(np.int64).max, after)
        label = np.where(weight > 0, np.where(near_next & ~stance, k2, k), -1)
        label = np.where(t < starts[0], np.where(weight > 0, 0, -1), label)
    return Stance(weight, label, len(starts))


def planted_xy(reference: np.ndarray, stance: Stance) -> np.ndarray:
    """(F, 2) the planted place of each stance (the weighted mean of `reference` (F, 3) over it),
    NaN outside stances."""
    out = np.full((len(reference), 2), np.nan)
    if stance.count == 0:
        return out
    inside = stance.label >= 0
    lab = stance.label[inside]
    w = (stance.weight[inside] >= 1.0) + 1e-9  # the stance itself; its easings only where it has no frame
    total = np.bincount(lab, w, stance.count)
    for k in range(2):
        mean = np.bincount(lab, w * reference[inside, k], stance.count) / total
        out[inside, k] = mean[lab]
    return out


def sole_lift(foot_frames: np.ndarray, sole_local: np.ndarray) -> np.ndarray:
    """(F,) the ankle's height above the lowest of the sole points (K, 3) (local to the canonical
    foot frames (F, 3, 3)): where the ankle stands when that point is on the floor."""
    z = np.einsum("fj,kj->fk", foot_frames[:, 2, :], sole_local)  # the points' heights below the ankle
    return -z.min(axis=1)


def lock(ankle: np.ndarray, planted: np.ndarray, weight: np.ndarray, lift: np.ndarray) -> np.ndarray:
    """(F, 3) the ankle target: the method's `ankle` (F, 3) eased onto the planted place (F, 2)
    at the height `lift` (F,) by `weight` (F,), and never lower than `lift` (no sole under the
    floor)."""
    w = weight[:, None]
    on_floor = np.concatenate([np.where(np.isfinite(planted), planted, ankle[:, :2]), lift[:, None]], axis=1)
    out = ankle + w * (on_floor - ankle)
    out[:, 2] = np.maximum(out[:, 2], lift)
    return out


def pelvis_drop(hips: np.ndarray, targets: np.ndarray, lengths: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """(F,) how far the pelvis must come down for legs of `lengths` (L,) from `hips` (F, L, 3) to
    reach `targets` (F, L, 3), each leg counting by its weight (F, L)."""
    reach = REACH * np.asarray(lengths, float)[None, :]
    d = targets - hips
    dxy2 = (d[..., :2] ** 2).sum(-1)
    # lowest hip height above the target that still reaches: sqrt(reach² - dxy²)
    can = np.sqrt(np.maximum(reach * reach - dxy2, 0.0))
    need = np.maximum(-d[..., 2] - can, 0.0)
    return (need * weights).max(axis=1)
