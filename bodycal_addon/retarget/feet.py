"""Planted feet: a walking foot rolls heel -> flat -> ball (DESIGN.md §6 "Planted feet"; beyond
Delahaye 2023 and AvatarGo, whose feet follow their targets). In every method and in transfer:

1. Stances (`detect`) of two points of the performer's foot, each carried by the foot tracker
   (a source character's foot bone): the heel and the ball, low (within STANCE_HEIGHT of where
   it stood at the reference time) and slow (averaged over SMOOTH_S, slower than STANCE_SPEED),
   with hysteresis (until faster than EXIT_SPEED or higher than EXIT_HEIGHT), none shorter than
   MIN_STANCE_S; `eased` gives each a weight easing over BLEND_S outside it (a bake looks ahead)
   and an inner weight easing over BLEND_S inside it. A foot turning in place about its ankle
   (the ankle itself low and slow, `detect_pivot`, neither point down) stands on its heel
   (`with_pivots`).
2. Places (`rolling_places`): where the method puts the avatar's heel and ball contact points
   (measured on its skin, avatar/foot_contact.py), averaged over a stance that begins alone; a
   stance that begins while the other point is down is placed from the other's place, so the two
   agree with the avatar's foot.
3. The contact (`rolling`): planted while either point is down (eased around their union; two
   contacts closer than two easings are one); the ball's share of the pivot from the inner weights
   (`pivot_share`): heel strike about the heel, flat about both, toe-off about the ball. Off the
   contact (the easings) the places move over the floor as the method moves its contact points
   from the contact's edge on, so the easing only takes away the plant's offset at the edge.
4. The ankle target (`roll`): where the ankle stands with the pivot's contact point on the floor,
   the foot turned as the method turns it, eased from the method's ankle by the weight, and never
   lower than the support points allow (`sole_lift`, `above`: the skin stays above the floor,
   planted or not).
5. `pelvis_drop`: where a planted foot is out of the leg's reach (an avatar whose root rides too
   high: AvatarGo's eye-height scaling, long-legged users), the pelvis comes down as much as
   needed, weighted like the feet.

Everything is an array over frames (the places: one step per stance); the stances of the whole
recording are found once (they need the frames on both sides of a chunk's ends). `CausalStance`
finds them frame by frame for a live stream.
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
RELEASE = 2.0  # a contact eases out over this many BLEND_S (`rolling`: the offset the plant made at its end fades
# out; over 0.12 s the ankle's acceleration p95 was 1.17x the source's at worst on 131_01, over 0.24 s 1.12x)
FOLLOW = 0.25  # of BLEND_S (3 frames at 90 Hz): how soon a pinned point off its contact moves as the method's, and
# how soon a point that has left the floor stops counting in the pivot's share (`eased`'s lead)
SHARE_OUTER = 0.1  # how much the stances' outer weights count in the pivot's share (`pivot_share`)
FLOOR_BLEND = 0.075  # of the heel's depth under the ankle (6 mm on an adult): how softly `above` keeps the sole up
SAME_PLACE = 0.01  # m: two contacts a short gap apart are one only if the foot comes down this near where it went up
DRIFT = 0.03  # m over the floor: an estimated foot's point standing again this far from where its stance came
# down has stepped (`detect`; a slow short step within the hold's speed and height was one stance at its average)
PIVOT_HEIGHT = 0.02  # m: the ankle of a foot turning in place stays within this of its height at the reference time
# (`detect_pivot`; a foot held just off the floor, as in the calibration's knee flexes, keeps it 3-4 cm higher)


@dataclass
class Stance:
    weight: np.ndarray  # (F,) in [0, 1]
    label: np.ndarray  # (F,) int: the stance a frame belongs to, -1 outside
    count: int
    inner: np.ndarray | None = None  # (F,) in [0, 1]: eased in and out over the stance's own first and last frames
    lead: np.ndarray | None = None  # (F,) `weight` before and in the stances, after them eased out over
    # FOLLOW of an easing (not the whole easing out: a point easing out has left the floor)


def _smoothstep(s: np.ndarray) -> np.ndarray:
    """3s^2 - 2s^3 of s in [0, 1]: the easings' C1 ramp."""
    return s * s * (3.0 - 2.0 * s)


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


def detect(ankle: np.ndarray, time: np.ndarray, ref_height: float, drift: float | None = None) -> Stance:
    """Stance of one foot from the user's ankle (F, 3) carried by its foot tracker. With `drift`
    (m; an estimated foot's, `DRIFT`), a stance is cut where the point stands again that far from
    where it came down (`_held_in_place`)."""
    F = len(ankle)
    if F < 3:
        return Stance(np.zeros(F), np.full(F, -1), 0, np.zeros(F))
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
        shortest = max(2, int(round(MIN_STANCE_S * fps)))
        a, b = first[for_runs], stops[for_runs]
        if drift is not None:
            a, b = _held_in_place(smooth[:, :2], enter, a, b, shortest, drift)
        keep = (b - a) >= shortest
        a, b = a[keep], b[keep]
        d = np.zeros(F + 1, int)
        np.add.at(d, a, 1)
        np.add.at(d, b, -1)
        stance = np.cumsum(d[:-1]) > 0
    return eased(stance, blend_frames(fps))


def _held_in_place(xy: np.ndarray, enter: np.ndarray, a: np.ndarray, b: np.ndarray, shortest: int, drift: float
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Stances [a, b) cut in two where the point (F, 2) over the floor has moved `drift` from where
    the stance came down and then stands again, slow and low (`enter`), for at least `shortest`
    frames before the stance ends: the foot stepped inside one stance's hold. A three-point kit's
    stepper lifts a foot 2 cm: a short step at under 0.4 m/s stays within the hysteresis's hold,
    and held as one stance it was placed at its average, the avatar's foot standing still (and
    turning on its heel) while the performer's stepped. A point that drifts off as its foot leaves
    (a heel rising at toe-off) stands nowhere again and keeps its stance as it was. Only for an
    estimated foot, which moves only when the stepper steps it: a tracked foot's points drift
    within what the hold calls one stance (the foot rolling, a slow shuffle: up to 25 cm in the CMU
    sessions' calibrations), and cutting those is another question (not measured). A loop over the
    stances and their cuts, not over frames."""
    starts = np.flatnonzero(enter)
    out_a, out_b = [], []
    for s, e in zip(a.tolist(), b.tolist(), strict=True):
        while True:
            far = np.flatnonzero(np.linalg.norm(xy[s:e] - xy[s], axis=1) > drift)
            k = np.searchsorted(starts, s + int(far[0])) if len(far) else len(starts)
            again = int(starts[k]) if k < len(starts) else e
            if again >= e or e - again < shortest:
                out_a.append(s)
                out_b.append(e)
                break
            out_a.append(s)
            out_b.append(s + int(far[0]))
            s = again
    return np.array(out_a, int), np.array(out_b, int)


def detect_pivot(ankle: np.ndarray, time: np.ndarray, ref_height: float) -> Stance:
    """Stance of the performer's ankle (F, 3) itself, slow and low (within PIVOT_HEIGHT of its
    height `ref_height` at the reference time; otherwise `detect`'s measures): a foot turning in
    place about its ankle (a dancer's pivot) moves both its heel and its ball points, and `detect`
    finds no stance of either (`with_pivots`)."""
    return detect(ankle, time, ref_height - (STANCE_HEIGHT - PIVOT_HEIGHT))


def with_pivots(heel: Stance, ball: Stance, ankle: Stance, n: int) -> Stance:
    """The heel's Stance with the ankle's stances (`detect_pivot`) during which neither the heel
    nor the ball is down, eased over `n` frames: the foot turns in place, and what it stands on is
    under its ankle, its heel (the pivot of `rolling`). An ankle stance that shares a frame with a
    heel or ball stance adds nothing (a walk: rare, DESIGN.md §6 "Planted feet")."""
    inside = [st.weight >= 1.0 for st in (heel, ball, ankle)]  # `eased` weighs a stance's own frames 1
    starts, stops = _runs(inside[2])
    add = np.zeros_like(inside[2])
    for a, b in zip(starts, stops):
        add[a:b] = not (inside[0][a:b].any() or inside[1][a:b].any())
    return eased(inside[0] | add, n) if add.any() else heel


def blend_frames(fps: float) -> int:
    """BLEND_S in frames at `fps`."""
    return max(1, int(round(BLEND_S * fps)))


def eased(stance: np.ndarray, n: int, n_out: int | None = None) -> Stance:
    """The Stance of the frames `stance` (F,) bool: weights eased over `n` frames (`n_out` after a
    stance, default `n`)."""
    n_out = n if n_out is None else n_out
    F = len(stance)
    starts, stops = _runs(stance)
    label = np.full(F, -1)
    weight, inner = np.zeros(F), np.zeros(F)
    if len(starts):
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
        # Between two stances closer than two easings each eases over half the gap, so the weight
        # is 0 where the planted place changes from one stance's to the next (it jumped there).
        span = np.where((t >= stops[k]) & (k + 1 < len(starts)), starts[k2] - stops[k], 2 * n)
        span = np.where(t < starts[0], 2 * n, span)
        near_next = before < np.where(t < starts[0], np.iinfo(np.int64).max, after)
        length = np.where(near_next | stance, n, n_out)
        s = np.clip(1.0 - gap / (np.minimum(length, span // 2) + 1.0), 0.0, 1.0)
        weight = _smoothstep(s)
        # inside a stance: frames to its nearer end
        depth = np.where(stance, np.minimum(t - starts[k] + 1, stops[k] - t), 0)
        s = np.clip(depth / (n + 1.0), 0.0, 1.0)
        inner = _smoothstep(s)
        # the stance each frame eases toward (inside: its own)
        label = np.where(weight > 0, np.where(near_next & ~stance, k2, k), -1)
        label = np.where(t < starts[0], np.where(weight > 0, 0, -1), label)
        # the weight easing in and in the stance; after it a point has left the floor, but its weight
        # fades over a few frames rather than stopping (`pivot_share` counts it: a step there was a
        # step in the pivot; over the whole easing out it pulled the pivot toward a lifted point)
        s = np.clip(1.0 - after / (max(1, int(round(n * FOLLOW))) + 1.0), 0.0, 1.0)
        lead = np.where(near_next | stance | (t < starts[0]), weight, _smoothstep(s))
        return Stance(weight, label, len(starts), inner, lead)
    return Stance(weight, label, len(starts), inner, weight)


def rolling_places(heel_ref: np.ndarray, ball_ref: np.ndarray, heel: Stance, ball: Stance
                   ) -> tuple[np.ndarray, np.ndarray]:
    """(heel's place (F, 2), ball's place (F, 2), NaN where not planted) of a rolling foot, from
    where the method puts the avatar's heel and ball contact points (F, 3) and the two stances.

    A stance that begins while the other point is down takes its place from that point's, plus the
    avatar's own heel-to-ball offset (its foot turned as in the frames both are down, averaged): a
    heel strike then the ball coming down, a toe-off, a foot turning on its heel or its ball, each
    hands the pivot over between places that agree with the foot, so nothing slides. A stance that
    begins alone (a heel strike, a ball landing first) is placed by the mean of its own reference.
    One step per stance (a few per second of a walk), not per frame."""
    refs, stances = (heel_ref, ball_ref), (heel, ball)
    places = [np.full((max(st.count, 0), 2), np.nan) for st in stances]
    inside = [(st.weight >= 1.0) & (st.label >= 0) for st in stances]
    runs = []
    for kind, st in enumerate(stances):
        if st.count == 0:
            continue
        starts, stops = _runs(inside[kind])
        total = np.bincount(st.label[inside[kind]], minlength=st.count)
        for a, b in zip(starts, stops):
            runs.append((int(a), int(b), kind, int(st.label[a])))
        for k in range(2):
            mean = np.bincount(st.label[inside[kind]], refs[kind][inside[kind], k], st.count) / np.maximum(total, 1)
            places[kind][:, k] = np.where(total > 0, mean, np.nan)
    for a, b, kind, lab in sorted(runs):
        other = 1 - kind
        o_st = stances[other]
        if not (o_st.count and inside[other][a]):
            continue  # begins alone: its own mean
        o_lab = int(o_st.label[a])
        both = np.flatnonzero(inside[kind][a:b] & (o_st.label[a:b] == o_lab) & inside[other][a:b]) + a
        offset = (refs[kind][both, :2] - refs[other][both, :2]).mean(axis=0)
        places[kind][lab] = places[other][o_lab] + offset
    out = []
    for kind, st in enumerate(stances):
        at = np.full((len(st.label), 2), np.nan)
        on = st.label >= 0
        if st.count:
            at[on] = places[kind][st.label[on]]
        out.append(at)
    return out[0], out[1]


def sole_lift(foot_frames: np.ndarray, sole_local: np.ndarray) -> np.ndarray:
    """(F,) the ankle's height above the lowest of the sole points (K, 3) (local to the canonical
    foot frames (F, 3, 3)): where the ankle stands when that point is on the floor."""
    z = np.einsum("fj,kj->fk", foot_frames[:, 2, :], sole_local)  # the points' heights below the ankle
    return -z.min(axis=1)


@dataclass
class Contact:
    """The avatar's foot on the floor, in its canonical foot frame about the ankle: the heel's and
    the ball's contact points (3,) and the skin points that may touch the floor (K, 3)."""
    heel: np.ndarray
    ball: np.ndarray
    support: np.ndarray

    @property
    def floor_blend(self) -> float:
        """(m) how softly the sole is kept above the floor (`above`): FLOOR_BLEND of the heel's
        depth under the ankle, so an avatar scaled up keeps its feet as the same avatar does."""
        return FLOOR_BLEND * float(np.linalg.norm(self.heel))


def foot_points(ankle: np.ndarray, turn: np.ndarray, rest_ankle: np.ndarray, rest_points: np.ndarray) -> np.ndarray:
    """(F, P, 3) points rigid on a foot, from where they are at rest (P, 3): the ankle (F, 3) plus
    the foot's rotation since rest (F, 3, 3) applied to their rest offsets from the ankle."""
    return ankle[:, None] + np.einsum("fij,pj->fpi", turn, np.asarray(rest_points, float) - rest_ankle)


def rolling(heel: Stance, ball: Stance, n: int, heel_at: np.ndarray, ball_at: np.ndarray,
            heel_ref: np.ndarray | None = None, ball_ref: np.ndarray | None = None
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(weight (F,), ball share (F,), heel's place (F, 2), ball's place (F, 2)) of a rolling foot
    from its heel's and its ball's stances and places: the foot is planted while either is down (a
    contact: `eased` over `n` frames around the union of the two); it pivots about the heel where
    only the heel is down (the strike), about the ball where only the ball is (the toe-off), about
    both where both are (flat). The share blends by the stances' inner weights (eased inside
    them): a point hands its pivot over while it is still down, so the foot never turns about a
    point that has left the floor. Outside a contact the share holds what it began or ended with;
    it eases out over RELEASE times as long as it eases in. Two contacts less than two
    easings apart with the foot down within SAME_PLACE of where it went up (a foot lifted for a
    moment, a stance's detection broken for a few frames) are one: across the gap the share and the
    places go smoothly from the first's end to the second's start, so the ankle never dips to the
    method's and back in a few frames. A quick short step (the foot down elsewhere) is a step: held
    on the floor across its gap, the foot slid to its next place.

    Outside a contact each place starts from the one at the contact's nearer edge and moves from
    there over the floor as the method's contact point does (`heel_ref` / `ball_ref` (F, 3): where
    the method puts it), taking the method's velocity up smoothly over FOLLOW of an easing: the
    ankle then eases from the plant's offset at the edge to the method's, and keeps the method's
    speed (a place held still while the method's point swung away left a gap growing with the
    swing, which the easing closed late and fast: the ankle's acceleration p95 up to 1.36x the
    source's, DESIGN.md §6 "Planted feet"). The places stay on the floor: following the method's
    height too was rougher (the method's point already rising or falling at the contact's edge,
    taken up in 3 frames) and landed the foot later (its descent is the smoothed devices', rounded
    off near the floor). Without references the places hold still off the contact."""
    share = pivot_share(heel.inner, ball.inner, heel.lead, ball.lead)
    down = (heel.weight >= 1.0) | (ball.weight >= 1.0)
    starts, stops = _runs(down)
    t = np.arange(len(share))
    if len(starts) > 1:
        # a short gap is bridged only where the foot comes down where it went up: across a step the
        # bridge held the foot on the floor and slid it to its next place (11-13 cm in 0.13-0.22 s
        # on the real A-Frame takes)
        moved = _moved(heel_at, ball_at, stops[:-1] - 1, starts[1:])
        short = ((starts[1:] - stops[:-1]) < 2 * n) & (moved <= SAME_PLACE)
        prev, nxt = stops[:-1][short] - 1, starts[1:][short]  # the edges of each short gap
        d = np.zeros(len(share) + 1, int)
        np.add.at(d, prev + 1, 1)
        np.add.at(d, nxt, -1)
        gap = np.cumsum(d[:-1]) > 0
        g = np.clip(np.searchsorted(prev, t, side="right") - 1, 0, max(len(prev) - 1, 0))
        if gap.any():
            a, b = prev[g], nxt[g]
            u = np.clip((t - a) / np.maximum(b - a, 1), 0.0, 1.0)
            u = _smoothstep(u)

            def across(x):
                p, q = x[a], x[b]
                p, q = np.where(np.isnan(p), q, p), np.where(np.isnan(q), p, q)
                return p + (u[:, None] if x.ndim > 1 else u) * (q - p)

            share = np.where(gap, across(share), share)
            heel_at = np.where(gap[:, None], across(heel_at), heel_at)
            ball_at = np.where(gap[:, None], across(ball_at), ball_at)
            down = down | gap
            starts, stops = _runs(down)
    union = eased(down, n, int(round(n * RELEASE)))
    on = union.weight >= 1.0
    if len(starts):
        k = np.clip(np.searchsorted(starts, t, side="right") - 1, 0, len(starts) - 1)
        before_first = t < starts[0]
        ended = (t >= stops[k]) & ~before_first
        nxt = np.clip(k + 1, 0, len(starts) - 1)
        # off the contact: its nearer end's (the union's label says which contact)
        toward_next = union.label > k
        edge = np.where(before_first, starts[0], np.where(ended & toward_next, starts[nxt], stops[k] - 1))
        share = np.where(on, share, share[edge])
        follow = _follow_weights(t, edge, max(1, int(round(n * FOLLOW))))
        heel_at, ball_at = (_off_contact(at, ref, on, edge, follow) for at, ref in ((heel_at, heel_ref),
                                                                                   (ball_at, ball_ref)))
    return union.weight, share, heel_at, ball_at


def _moved(heel_at: np.ndarray, ball_at: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(G,) how far the heel's or the ball's place moves from frames `a` to `b` (G,), the farther
    of the two (a point not placed at both ends does not count; neither placed: 0)."""
    d = [np.linalg.norm(at[b] - at[a], axis=-1) for at in (heel_at, ball_at)]
    return np.fmax(np.nan_to_num(d[0], nan=0.0), np.nan_to_num(d[1], nan=0.0))


def _off_contact(at: np.ndarray, ref: np.ndarray | None, on: np.ndarray, edge: np.ndarray, follow: np.ndarray
                 ) -> np.ndarray:
    """(F, 2) a point's places `at` in the contact (`on`), and off it its place at the contact's
    `edge` (F,) moved as the method moves the point over the floor (`ref` (F, 3); None: held still)
    from the edge on, each step by its `follow` weight (`_follow_weights`): what the easing takes
    away is then the offset the plant made at the edge, not a gap growing with the foot's swing."""
    held = at[edge]
    if ref is not None:
        moved = np.cumsum(np.nan_to_num(np.diff(ref[:, :2], axis=0, prepend=ref[:1, :2])) * follow[:, None], axis=0)
        held = held + moved - moved[edge]
    return np.where(on[:, None], at, held)


def _follow_weights(t: np.ndarray, edge: np.ndarray, m: int) -> np.ndarray:
    """(F,) how much of the step from frame t-1 to t a pinned point off its contact takes from the
    method's: 0 at the contact's `edge` (F,), rising smoothly to 1 `m` frames from it (the step's
    frame further from the edge counts: t after the edge, t-1 before it)."""
    u = np.clip(np.abs(t - edge) / float(m), 0.0, 1.0)
    r = _smoothstep(u)
    return np.where(t > edge, r, np.concatenate([r[:1], r[:-1]]))


def pivot_share(heel_inner: np.ndarray, ball_inner: np.ndarray, heel: np.ndarray, ball: np.ndarray) -> np.ndarray:
    """(F,) the ball's share of the pivot from the stances' inner weights, and their outer weights
    counted SHARE_OUTER as much where neither is inside (a bake counts a stance's easing in, and its
    easing out only over its first frames: a point easing out has left the floor; a live stream has
    the outer weights only)."""
    hi = heel_inner + SHARE_OUTER * heel
    bi = ball_inner + SHARE_OUTER * ball
    total = hi + bi
    return np.divide(bi, total, out=np.zeros_like(total), where=total > 0)


def roll(ankle: np.ndarray, heel_at: np.ndarray, ball_at: np.ndarray, weight: np.ndarray, share: np.ndarray,
         foot_frames: np.ndarray, contact: Contact) -> np.ndarray:
    """(F, 3) the ankle target of a rolling foot: the method's `ankle` (F, 3) eased by `weight` (F,)
    onto where the ankle stands with the heel's contact point on the floor at `heel_at` (F, 2) and
    the ball's at `ball_at` (F, 2) (NaN: not planted), blended by the ball's `share` (F,), the foot
    turned as `foot_frames` (F, 3, 3) say; never lower than `sole_lift` (no skin under the floor)."""
    def stand(at, local):  # the ankle with that contact point at `at` on the floor
        pinned = np.concatenate([np.nan_to_num(at), np.zeros((len(at), 1))], axis=1)
        return pinned - np.einsum("fij,j->fi", foot_frames, local)

    share = np.where(np.isfinite(ball_at[:, 0]), np.where(np.isfinite(heel_at[:, 0]), share, 1.0), 0.0)
    on_heel = stand(heel_at, contact.heel)
    place = on_heel + share[:, None] * (stand(ball_at, contact.ball) - on_heel)
    w = np.where(np.isfinite(heel_at[:, 0]) | np.isfinite(ball_at[:, 0]), weight, 0.0)[:, None]
    lift = sole_lift(foot_frames, contact.support)
    # The place itself stands on the floor (a foot pitched past its ball stands on its toes' tips),
    # so that easing away from it never meets the guard below (a kink: an acceleration spike).
    blend = contact.floor_blend
    place[:, 2] = above(place[:, 2], lift, blend)
    out = ankle + w * (place - ankle)
    # both ends above the floor, so is their blend (guarding the blend again raised a pinned foot twice)
    out[:, 2] = w[:, 0] * place[:, 2] + (1.0 - w[:, 0]) * above(ankle[:, 2], lift, blend)
    return out


def above(z: np.ndarray, floor: np.ndarray, blend: float) -> np.ndarray:
    """`z` kept above `floor` (F,) without a kink where it meets it (a hard max turned a foot
    lifting off its guard into an acceleration spike): within `blend` either side of the floor a
    parabola joins the two smoothly (C1), so a point pinned exactly on the floor stands a quarter
    of `blend` above it; `z` further up is kept as it is."""
    d, e = z - floor, max(float(blend), 1e-9)
    return np.where(d >= e, z, floor + np.where(d <= -e, 0.0, (d + e) ** 2 / (4.0 * e)))


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


class CausalStance:
    """Stance detection frame by frame, from the frames so far only (a live stream; `detect` looks
    at the whole take): the same ankle measures and thresholds, with three changes that need no
    future frame:

    - the ankle is averaged over the SMOOTH_S before each frame (`detect`: centred on it) and its
      speed is the backward difference;
    - a stance counts once it has lasted MIN_STANCE_S (`detect` drops shorter ones, which it can
      only know at their end): the foot is planted from then on, its place the mean of the
      `reference` over those first frames (`detect`: over the whole stance);
    - the weight eases in over the BLEND_S after that (`detect`: before the stance), from whatever
      the last stance's ease-out has left, and out over the BLEND_S after the stance ends.

    So a foot is planted MIN_STANCE_S plus about half of BLEND_S later than a bake plants it, and
    held as long after it lifts (benchmarks/bench_live_solver.py measures both). `update` takes
    the frames in order, any number at a time: the result does not depend on how the take is
    split (the state carried from one block to the next is the frame-by-frame state).

    With `drift` (m; an estimated foot's, `DRIFT`, as `detect`'s) a stance ends on the frame its
    averaged point is that far over the floor from where the stance came down, moving (not slow
    and low: a point that gets there slow and low goes on standing, measured from there, as in
    `detect`), and the next stance begins where the point is slow and low again (after at least
    one frame out of it, so the plant eases out from the old place and into the new one). `detect`
    cuts there only if the point then stands again for MIN_STANCE_S before the hold ends
    (`_held_in_place`), which a stream cannot know yet: a point that drifts off and never stands
    again (a foot leaving) is released here at the drift rather than where its hold ends
    (DESIGN.md §6 "Planted feet")."""

    def __init__(self, ref_height: float, fps: float, drift: float | None = None):
        fps = float(fps) if fps and np.isfinite(fps) and fps > 0 else 90.0
        self.ref_height = float(ref_height)
        self.drift = None if drift is None else float(drift)
        self._origin = (0.0, 0.0)  # the averaged point's xy where the stance it is in came down (with `drift`)
        self.n_smooth = max(1, int(round(SMOOTH_S * fps)))
        self.n_min = max(2, int(round(MIN_STANCE_S * fps)))
        self.n_blend = max(1, int(round(BLEND_S * fps)))
        self.frames = 0  # frames taken in
        self._tail = None  # the last n_smooth - 1 ankles (the average's window)
        self._last = None  # (time, averaged ankle) of the last frame
        self._start = None  # the first frame of the stance the foot is in (None: none)
        self._sum = np.zeros(2)  # the reference summed over that stance's first frames
        self._mode = ("none",)  # ("in", confirmed at, place, starting weight) | ("out", left at, weight, place)

    def update(self, ankle: np.ndarray, time: np.ndarray, reference: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The next frames: the user's ankle (K, 3), their times (K,), where the method puts the
        ankle (K, 3). Returns (weight (K,) in [0, 1], planted xy (K, 2), NaN where not planted)."""
        ankle, time, reference = (np.asarray(a, float) for a in (ankle, time, reference))
        k = len(time)
        if not k:
            return np.zeros(0), np.zeros((0, 2))
        enter, hold, xy = self._measures(ankle, time)
        stance, starts = self._stances(enter, hold) if self.drift is None else self._drifting(enter, hold, xy)
        weight, planted = np.zeros(k), np.full((k, 2), np.nan)
        self.lead = np.zeros(k)  # the weight while a stance holds, 0 while it eases out (feet.rolling's lead)
        for i in range(k):  # a few frames at a time in a stream; only the stance bookkeeping is per frame
            self._step(i, stance[i], starts[i], reference[i], weight, planted)
        self.frames += k
        return weight, planted

    def _measures(self, ankle, time) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(enter, hold, xy) per frame: the averaged ankle slow and low (to enter a stance, to stay
        in), and where it is over the floor (K, 2)."""
        n = self.n_smooth
        tail = np.repeat(ankle[:1], n - 1, axis=0) if self._tail is None else self._tail
        padded = np.concatenate([tail, ankle])
        if len(ankle) == 1:  # a stream's frame: its one window is the padded block itself (the same sums)
            smooth = padded.T[None].sum(axis=-1) / n
        else:
            smooth = np.lib.stride_tricks.sliding_window_view(padded, n, axis=0).sum(axis=-1) / n
        self._tail = padded[len(padded) - (n - 1):]
        t_prev, s_prev = self._last if self._last is not None else (time[0], smooth[0])
        if len(ankle) == 1:
            prev_t, prev_s = t_prev, s_prev[None]
        else:
            prev_t = np.concatenate([[t_prev], time[:-1]])
            prev_s = np.concatenate([s_prev[None], smooth[:-1]])
        dt = time - prev_t
        step = smooth - prev_s
        speed = np.sqrt(np.add.reduce(step * step, axis=1)) / np.where(dt > 0, dt, 1.0)  # np.linalg.norm's
        self._last = (time[-1], smooth[-1])
        height = smooth[:, 2] - self.ref_height
        return (speed < STANCE_SPEED) & (height < STANCE_HEIGHT), (speed < EXIT_SPEED) & (height < EXIT_HEIGHT), \
            smooth[:, :2]

    def _stances(self, enter, hold) -> tuple[np.ndarray, np.ndarray]:
        """(in a stance, the frame it started) per frame, with `detect`'s hysteresis: a run of `hold`
        frames is a stance from its first `enter` frame on (a stance carried in from the last block
        goes on while the run does)."""
        k = len(hold)
        if k == 1:  # a stream's frame: its run is itself (the loop below, without the runs' search)
            start = None
            if hold[0]:
                start = self._start if self._start is not None else (self.frames if enter[0] else None)
            self._start = start
            return np.array([start is not None]), np.array([-1 if start is None else start])
        stance, starts = np.zeros(k, bool), np.full(k, -1)
        run_starts, run_stops = _runs(hold)
        for a, b in zip(run_starts, run_stops):
            if a == 0 and self._start is not None:
                first = 0
                start = self._start
            else:
                entering = np.flatnonzero(enter[a:b])
                if not len(entering):
                    continue
                first = a + int(entering[0])
                start = self.frames + first
            stance[first:b] = True
            starts[first:b] = start
        self._start = int(starts[-1]) if stance[-1] else None
        return stance, starts

    def _drifting(self, enter, hold, xy) -> tuple[np.ndarray, np.ndarray]:
        """`_stances` with the drift cut, frame by frame (the cut moves where the next stance may
        begin): a stance ends on the first frame its point is `drift` from where it came down
        unless the point is slow and low there (`detect` then cuts it in two stances that touch:
        one stance, measured from there on), and a new one begins on a later `enter` frame of the
        same hold."""
        k = len(hold)
        stance, starts = np.zeros(k, bool), np.full(k, -1)
        start, (ox, oy), d2 = self._start, self._origin, self.drift * self.drift
        for i in range(k):  # Python floats: a stream's frame is one of these (no numpy call per frame)
            x, y = float(xy[i, 0]), float(xy[i, 1])
            if not hold[i]:
                start = None
                continue
            if start is not None:
                if (x - ox) * (x - ox) + (y - oy) * (y - oy) > d2:
                    if not enter[i]:  # it has stepped: out for this frame
                        start = None
                        continue
                    ox, oy = x, y  # still slow and low there: `detect`'s two stances touch, and are one
            elif enter[i]:
                start, ox, oy = self.frames + i, x, y
            else:
                continue
            stance[i], starts[i] = True, start
        self._start, self._origin = start, (ox, oy)
        return stance, starts

    def _step(self, i, in_stance, start, reference, weight, planted) -> None:
        """One frame of the weight and the planted place, from the stance it is in (if any)."""
        t = self.frames + i
        mode = self._mode
        if in_stance and t - start < self.n_min:  # not a stance yet: sum the reference for its place
            self._sum = (np.zeros(2) if t == start else self._sum) + reference[:2]
        if in_stance and t - start == self.n_min - 1:  # it is one now: planted from here on
            w0 = self._weight_out(t) if mode[0] == "out" else 0.0
            mode = self._mode = ("in", t, self._sum / self.n_min, w0)
        elif not in_stance and mode[0] == "in":  # it has ended: ease out from the last weight
            mode = self._mode = ("out", t, self._weight_in(t - 1), mode[2])
        if mode[0] == "in":
            weight[i], planted[i] = self._weight_in(t), mode[2]
            self.lead[i] = weight[i]
        elif mode[0] == "out":
            weight[i] = self._weight_out(t)
            planted[i] = mode[3] if weight[i] > 0 else np.nan
            if weight[i] <= 0:
                self._mode = ("none",)

    def _weight_in(self, t: int) -> float:
        _, at, _, w0 = self._mode
        s = min(max((t - at + 1) / (self.n_blend + 1.0), 0.0), 1.0)
        return w0 + (1.0 - w0) * s * s * (3.0 - 2.0 * s)

    def _weight_out(self, t: int) -> float:
        _, left, w_exit, _ = self._mode
        s = min(max(1.0 - (t - left + 1) / (self.n_blend + 1.0), 0.0), 1.0)
        return w_exit * s * s * (3.0 - 2.0 * s)
