"""Feet that stay planted and step when balance needs it (DESIGN.md §6 "A lower body from head and
hands"): the estimated feet of a kit without foot trackers.

Both feet stand still until one of these, whichever comes first, checked on every frame at once
over the stretch both feet stand (a loop over steps, not frames):
- balance: the capture point (the body's mass centre over the floor plus its velocity over
  omega = sqrt(g / h), where a body falling like an inverted pendulum comes to rest) leaves the
  support, the area the feet span from their ankles to their middles widened by `SUPPORT_REACH`
  (a standing body's mass centre stands over the rear of its feet), and (offline, the path
  ahead known) is still out of it when a step taken then would land: a body back over its feet by
  then sways on them. The mass centre is `BodyPath.centre` (body_path.centre_of: between the
  pelvis and the skull base; a squat's pelvis goes back as the trunk leans, its mass centre stays
  over the feet), the pelvis where the path has none;
- a turn: the body's heading is more than `TURN_STEP` off a foot's;
- reach: a hip is further from its ankle, over the floor, than `REACH` of the leg (the leg then
  slants about 30 degrees), or so far behind that its heel, rising on the ball to keep it in
  reach (heel.py), rises more than `RISE_STEP` (a toe-off);
- crossing: the feet, seen across the body, closer than `MIN_WIDTH` or on the wrong sides;
- a kneel: the pelvis below `kneel.KNEEL_FROM` of its standing height (kneel.py). The foot further
  back steps to its kneeling place (toes tucked, pitched `kneel.TOES_DOWN`), then the other to its
  place in front; while the body kneels no other step is due; once the pelvis is back above that
  height the feet step as a standing body's, each foot due to step back under the body, the
  knee's (its toes still tucked) first, the front foot next unless it stands there already.
  A kneel's feet step like any others (lifted, moved, planted): a planted foot never slides.
Then the foot further from where it should stand steps: it lands where the body will be once the
step is done (offline the body path at that frame; live its velocity carried forward), under its
hip and `LEAD_S` of the body's velocity ahead, turned with the body (no more than `SPLAY` from the
other foot), no further than `MAX_STRIDE` and never across the other foot (bowing out around it
on the way when it starts on the wrong side, after a turn). The swing lasts `SWING_S` (faster with
speed, pendulum-scaled by the leg's length; quicker, down to `SHORTEST_SWING_S`, when the standing
foot would otherwise run out of reach before it may step itself, after the swing and the
`DOUBLE_SUPPORT` that follows it), lifts `LIFT_PER_LENGTH` of its length
(within `LIFT`), on a minimum-jerk path;
both feet then stand at least `DOUBLE_SUPPORT` of the swing (a gait's double support: of its cycle
the stance takes 60 %, the swing 40 %, so each time both feet stand is 10 %, a quarter of a swing;
Perry & Burnfield 2010). A walk's capture point stays ahead of the feet (walking is a fall caught
step by step), so this sets a walk's cadence. While the body is off the floor (`BodyPath.lift`) both
feet hang under it, carried with the pelvis, and land where they are.

Offline the same code sees the whole path (each step's landing looks ahead); live it sees the
frames so far, one at a time.
"""

from __future__ import annotations

from itertools import combinations

import numpy as np

from . import heel, kneel
from .body_path import LOWEST_PELVIS, BodyPath
from .shape import LowerBodyShape, body_axes, wrap

G = 9.81
SUPPORT_REACH = 0.04  # x stature beyond the support: the feet from their ankles to their middles
MIDDLE = 0.4  # x the foot's length (ankle to toe joint): a foot's middle ahead of its ankle
TURN_STEP = np.radians(35.0)
SPLAY = np.radians(50.0)  # the most a step turns a foot from the other (their rest turn apart)
REACH = 0.5
RISE_STEP = np.radians(35.0)  # a heel risen this far on its ball (heel.py) lifts the foot: a toe-off
SHORTEST_SWING_S = 0.25  # a swing hurried so the standing foot is not left out of reach
LAND_REACH = 1.0  # x the leg: the most a landing foot is from its hip (the leg straight at heel strike)
MIN_WIDTH = 0.06  # x stature between the ankles, across the body (a shin and a half)
LEAD_S = 0.3
MAX_STRIDE = 1.4  # x leg
SWING_S = (0.45, 0.36)  # at rest, at FAST_MPS and beyond, for a 0.85 m leg
FAST_MPS = 1.6
LIFT_PER_LENGTH = 0.15
LIFT = (0.012, 0.05)  # x stature
DOUBLE_SUPPORT = 0.25  # x the swing: both feet stand after a step (a gait's stance 60 %, swing 40 %)
BOTTOM = 0.01  # x stature: a kneel's pelvis this close to its lowest is down (kneel.py)
IN_PLACE = 0.01  # x stature: a foot this close to its place needs no step to it
TURN_COST_M = 0.25  # metres of misplacement a radian of a foot's misturn is worth in choosing the foot


def _outside(points: np.ndarray, corners: np.ndarray, reach: float) -> np.ndarray:
    """(F,) bool: `points` (F, 2) further than `reach` from the convex hull of `corners` (C, 2): out
    of every triangle of three corners, and that far from every segment between two (outside the
    hull its nearest point is on an edge, and every other segment lies inside it)."""
    inside = np.zeros(len(points), bool)
    gap = np.full(len(points), np.inf)
    for a, b in combinations(corners, 2):
        ab = b - a
        u = np.clip(((points - a) @ ab) / max(ab @ ab, 1e-12), 0.0, 1.0)
        gap = np.minimum(gap, np.linalg.norm(points - (a + u[:, None] * ab), axis=1))
    for tri in combinations(corners, 3):
        edges = np.roll(np.array(tri), -1, axis=0) - tri
        rel = points[:, None] - np.array(tri)
        cross = edges[:, 0] * rel[..., 1] - edges[:, 1] * rel[..., 0]
        inside |= (cross >= 0.0).all(axis=1) | (cross <= 0.0).all(axis=1)
    return ~inside & (gap > reach)


def body_velocity(path: BodyPath) -> np.ndarray:
    """(F, 2) the body's velocity over the floor: its mass centre's (the pelvis's when not known)."""
    return path.velocity if path.centre_velocity is None else path.centre_velocity


def min_jerk(u: np.ndarray) -> np.ndarray:
    return u * u * u * (10.0 - 15.0 * u + 6.0 * u * u)


class Stepper:
    """The feet of `shape`'s body along a `BodyPath`, planted and stepping (the module docstring).
    `advance` fills frames [start, stop) of `out_pos` (., 2, 3) ankles, `out_heading` (., 2)
    feet headings and `out_pitch` (., 2) their toes-down pitch (a kneel), from the path's frames up
    to `available` (offline: all; live: `stop`); the path's and the outputs' first row is frame
    `base` (live: the frame itself)."""

    def __init__(self, shape: LowerBodyShape, fps: float):
        self.shape, self.fps = shape, float(fps)
        self.feet: np.ndarray | None = None  # (2, 3) planted ankles
        self.headings = np.zeros(2)
        self.pitches = np.zeros(2)  # the planted feet's toes-down pitch (a kneeling foot's)
        self.swing: tuple | None = None  # (foot, k0, k1, p0, p1, heading0, heading1, height, bow out, pitch0, pitch1)
        self.kneel: int | None = None  # the knee's foot while the body kneels (or steps into it)
        self.front_due = False  # kneeling, the front foot's step still to come
        self.rising = 0  # up from a kneel: how many feet are still to step back under the body
        self.kneel_low = 0.0  # kneeling, the pelvis's lowest so far
        self.air: tuple | None = None  # (the pelvis over the floor at take-off, the feet's carry so far)
        self.ready_at = 0
        self.steps = 0
        self.base = 0

    # --- where the feet should stand --------------------------------------------------------------

    def ideal(self, pelvis: np.ndarray, heading: float, velocity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(2, 3) ankles under the hips, led by the velocity, and (2,) their headings."""
        axes = body_axes(heading)
        feet = pelvis + (axes @ self.shape.ankle.T).T
        feet[:, :2] += LEAD_S * velocity
        feet[:, 2] = self.shape.ankle_height
        return feet, heading + self.shape.foot_turn

    def start(self, path: BodyPath, k: int) -> None:
        self.feet, self.headings = self.ideal(path.pelvis[k], path.heading[k], np.zeros(2))

    # --- the loop over steps ----------------------------------------------------------------------

    def advance(self, path: BodyPath, start: int, stop: int, out_pos: np.ndarray, out_heading: np.ndarray,
                available: int | None = None, base: int = 0, out_pitch: np.ndarray | None = None) -> None:
        available = stop if available is None else available
        self.base = base
        self.out_pitch = np.zeros(out_heading.shape) if out_pitch is None else out_pitch
        if self.feet is None:
            self.start(path, start - base)
        k = start
        while k < stop:
            if self.swing is not None:
                k0, k = k, self._swing(k, stop, out_pos, out_heading)
                if self.kneel is not None:
                    self.kneel_low = min(self.kneel_low, float(path.pelvis[k0 - base:k - base, 2].min()))
            elif self.air is not None or path.lift[k - base] > 0.0:
                k = self._airborne(path, k, stop, out_pos, out_heading)
            else:
                k = self._stand(path, k, stop, out_pos, out_heading, available)

    def _stand(self, path, k, stop, out_pos, out_heading, available) -> int:
        """Both feet planted from frame k until a step is due (planned then) or the body leaves the
        floor; returns the frame it stops at."""
        b = self.base
        off = np.flatnonzero(path.lift[k - b:stop - b] > 0.0)
        end = k + int(off[0]) if len(off) else stop
        due = self.triggers(path, k - b, end - b)
        due[:max(0, self.ready_at - k)] = False
        hit = np.flatnonzero(due)
        until = k + int(hit[0]) if len(hit) else end
        out_pos[k - b:until - b] = self.feet
        out_heading[k - b:until - b] = self.headings
        self.out_pitch[k - b:until - b] = self.pitches
        if self.kneel is not None and until > k:
            self.kneel_low = min(self.kneel_low, float(path.pelvis[k - b:until - b, 2].min()))
        if until < end:
            self._plan(path, until, available)
        return until

    def triggers(self, path: BodyPath, i: int, end: int) -> np.ndarray:
        """(end - i,) bool: a step is due at the path's rows [i, end) with the feet where they stand."""
        if end <= i:
            return np.zeros(0, bool)
        z = path.pelvis[i:end, 2]
        if self.kneel is not None:  # kneeling: the front foot's step; up as the pelvis rises or the body moves on
            return self._rising(z) | self.front_due | self._off_kneeling_support(path, i, end)
        # up from a kneel, each foot steps back under the body (the knee's, toes still tucked, first)
        rising = self.pitches.any() or self.rising > 0
        return self._standing_triggers(path, i, end) | (kneel.kneel_weight(self.shape, z) > 0.0) | rising

    def _capture(self, path: BodyPath, i: int, end: int) -> np.ndarray:
        """(end - i, 2) the capture point of the path's rows [i, end): the body's mass centre over the
        floor (`body_path.centre_of`) plus its velocity over omega (the module docstring)."""
        shape = self.shape
        centre = path.pelvis[i:end, :2] if path.centre is None else path.centre[i:end]
        return centre + body_velocity(path)[i:end] / np.sqrt(G / max(shape.pelvis_height, 0.3))

    def _off_support(self, path: BodyPath, i: int, end: int) -> np.ndarray:
        """(end - i,) bool: the capture point (the module docstring) further than `SUPPORT_REACH`
        from the feet's support: the quadrilateral of the ankles and the feet's middles (each foot
        from its ankle forward to `MIDDLE` of its length), the area the feet span between them."""
        shape, feet = self.shape, self.feet
        capture = self._capture(path, i, end)
        along = np.stack([np.cos(self.headings), np.sin(self.headings)], 1)
        corners = np.concatenate([feet[:, :2], feet[:, :2] + MIDDLE * shape.foot_length * along])
        return _outside(capture, corners, SUPPORT_REACH * shape.stature)

    def _off_support_lasting(self, path: BodyPath, i: int, end: int) -> np.ndarray:
        """(end - i,) bool: the capture point out of the feet's support and, where the path ahead is
        known (offline), still out when a step taken now would land (a swing at rest): a body back
        over its feet by then sways on them rather than steps."""
        n = int(round(SWING_S[0] * np.sqrt(self.shape.leg / 0.85) * self.fps))
        stop = min(end + n, len(path.pelvis))
        off = self._off_support(path, i, stop)
        ahead = np.minimum(np.arange(i, end) + n, stop - 1) - i
        return off[:end - i] & off[ahead]

    def _off_kneeling_support(self, path: BodyPath, i: int, end: int) -> np.ndarray:
        """(end - i,) bool: kneeling, the capture point further than `SUPPORT_REACH` outside the
        triangle the body kneels on: the knee's foot, its knee on the floor, the front foot's middle."""
        shape, feet, knee = self.shape, self.feet, self.kneel
        capture = self._capture(path, i, end)
        along = np.stack([np.cos(self.headings), np.sin(self.headings)], 1)
        corners = np.stack([feet[knee, :2], feet[knee, :2] + along[knee] * kneel.shin_on_floor(shape),
                            feet[1 - knee, :2] + MIDDLE * shape.foot_length * along[1 - knee]])
        return _outside(capture, corners, SUPPORT_REACH * shape.stature)

    def _standing_triggers(self, path: BodyPath, i: int, end: int) -> np.ndarray:
        """(end - i,) bool: a standing body's step due: balance, a turn, reach or crossing."""
        shape, feet = self.shape, self.feet
        pelvis, heading = path.pelvis[i:end], path.heading[i:end]
        off_support = self._off_support_lasting(path, i, end)
        turned = (np.abs(wrap(heading[:, None] + shape.foot_turn - self.headings)) > TURN_STEP).any(axis=1)
        axes = body_axes(heading)
        hips = pelvis[:, None] + np.einsum("fij,sj->fsi", axes, shape.hip)
        stretched = (np.linalg.norm((hips - feet)[..., :2], axis=2) > REACH * shape.leg).any(axis=1)
        # a heel that would have to rise more than RISE_STEP to keep its hip in reach (heel.py)
        stretched |= (heel.rise(shape, hips, np.broadcast_to(feet, hips.shape),
                                np.broadcast_to(self.headings, hips.shape[:2]))[0] > RISE_STEP).any(axis=1)
        across = (feet[0] - feet[1]) @ axes[:, :, 0].T  # left foot minus right along the body's right
        crossed = across > -MIN_WIDTH * shape.stature
        return off_support | turned | stretched | crossed

    def _plan(self, path: BodyPath, k: int, available: int) -> None:
        """Plans the step due at frame k: which foot, where it lands, how long and how high."""
        shape, i = self.shape, k - self.base
        speed = float(np.linalg.norm(path.velocity[i]))
        seconds = np.interp(speed, (0.0, FAST_MPS), SWING_S) * np.sqrt(shape.leg / 0.85)
        n = max(2, int(round(seconds * self.fps)))
        if self.kneel is None:  # a kneel from a balanced stance; a body moving on steps as it walks
            if kneel.kneel_weight(shape, path.pelvis[i, 2]) > 0.0 and not self._standing_triggers(path, i, i + 1)[0]:
                self._plan_kneel(path, k, n, available)
                return
        elif self.front_due and not (self._rising(path.pelvis[i:i + 1, 2])
                                     | self._off_kneeling_support(path, i, i + 1))[0]:
            self._plan_kneel(path, k, n, available)
            return
        if self.kneel is not None:  # up from a kneel: both feet step under the body, the pitched foot first
            self.rising = 2
        self.kneel = None
        pelvis, heading, velocity = self._landing(path, k, n, available)
        ideal, headings = self.ideal(pelvis, heading, velocity)
        miss = np.linalg.norm((ideal - self.feet)[:, :2], axis=1) + TURN_COST_M * np.abs(wrap(headings - self.headings))
        foot = int(np.argmax(miss))
        quick = self._stance_lasts(path, k, n, 1 - foot, available)
        if quick < n:  # the standing foot would run out of reach first: a quicker swing
            n = quick
            pelvis, heading, velocity = self._landing(path, k, n, available)
            ideal, headings = self.ideal(pelvis, heading, velocity)
        k1 = k + n
        target = self._within_reach(self._keep_apart(ideal[foot], foot, heading), foot, pelvis, heading)
        if self.rising:  # a foot standing up from a kneel that already stands under the body stays
            self.rising -= 1
            if not self._standing_triggers(path, i, i + 1)[0] and \
                    np.linalg.norm((target - self.feet[foot])[:2]) < IN_PLACE * shape.stature:
                self.rising = 0
                return
        move = target - self.feet[foot]
        length = float(np.linalg.norm(move[:2]))
        if length > MAX_STRIDE * shape.leg:
            target = self.feet[foot] + move * (MAX_STRIDE * shape.leg / length)
            length = MAX_STRIDE * shape.leg
        lo, hi = LIFT
        height = float(np.clip(LIFT_PER_LENGTH * length, lo * shape.stature, hi * shape.stature))
        # no more than SPLAY between the feet: a fast turn takes a few steps, the feet never point apart
        other = self.headings[1 - foot] + shape.foot_turn[foot] - shape.foot_turn[1 - foot]
        turned = other + np.clip(wrap(headings[foot] - other), -SPLAY, SPLAY)
        self.swing = (foot, k, k1, self.feet[foot].copy(), target, self.headings[foot],
                      self.headings[foot] + wrap(turned - self.headings[foot]), height,
                      self._around(foot, target, heading), self.pitches[foot], 0.0)
        self.steps += 1

    def _plan_kneel(self, path: BodyPath, k: int, n: int, available: int) -> None:
        """Plans a kneel's step due at frame k (a swing of `n` frames): down (the foot further back
        to its kneeling place), then the front foot's."""
        shape, i = self.shape, k - self.base
        pelvis, heading, _ = self._landing(path, k, n, available)
        if self.kneel is None:  # down: the knee of the foot further back
            foot = self.kneel = kneel.knee_foot(self.feet, path.pelvis[i], path.heading[i])
            self.front_due, self.kneel_low = True, float(path.pelvis[i, 2])
            target, _ = kneel.kneeling_places(shape, *self._deepest(path, i, (pelvis, heading)), foot)
            pitch = kneel.TOES_DOWN
        else:  # the front foot
            foot, self.front_due = 1 - self.kneel, False
            target = kneel.kneeling_places(shape, pelvis, heading, self.kneel)[1]
            pitch = 0.0
            if np.linalg.norm((target - self.feet[foot])[:2]) < IN_PLACE * shape.stature:
                return  # it stands there already
        length = float(np.linalg.norm((target - self.feet[foot])[:2]))
        lo, hi = LIFT
        height = float(np.clip(LIFT_PER_LENGTH * length, lo * shape.stature, hi * shape.stature))
        turned = heading + shape.foot_turn[foot]
        self.swing = (foot, k, k + n, self.feet[foot].copy(), target, self.headings[foot],
                      self.headings[foot] + wrap(turned - self.headings[foot]), height,
                      self._around(foot, target, heading), self.pitches[foot], pitch)
        self.steps += 1

    def _rising(self, z: np.ndarray) -> np.ndarray:
        """(F,) bool: kneeling, the pelvis at heights `z` (F,) on its way up: risen `kneel.RISE` above
        its lowest so far, or out of the kneel's heights (standing up starts as the pelvis rises)."""
        low = np.minimum.accumulate(np.minimum(z, self.kneel_low))
        return (z > low + kneel.RISE * self.shape.pelvis_height) | (kneel.kneel_weight(self.shape, z) <= 0.0)

    def _deepest(self, path: BodyPath, i: int, landing: tuple) -> tuple:
        """(pelvis (3,), heading) at the deepest of the kneel starting at the path's row i: offline
        the path's at the middle of the frames its pelvis is within `BOTTOM` of its lowest before
        it rises above `kneel.KNEEL_FROM` (a kneel held; the pelvis still settles as it gets
        there); live (the path not known
        past the present) the `landing` pelvis as low as it can come down (`LOWEST_PELVIS`), so the
        knee never goes through the floor."""
        z = path.pelvis[i:, 2]
        up = np.flatnonzero(kneel.kneel_weight(self.shape, z) <= 0.0)
        if len(z) > 1:  # the path ahead is known: the middle of its time at the bottom
            z = z[:up[0]] if len(up) else z
            j = i + int(np.median(np.flatnonzero(z <= z.min() + BOTTOM * self.shape.stature)))
            return path.pelvis[j], path.heading[j]
        pelvis, heading = landing
        return np.array([pelvis[0], pelvis[1], LOWEST_PELVIS * self.shape.pelvis_height]), heading

    def _landing(self, path: BodyPath, k: int, n: int, available: int):
        """(pelvis, heading, velocity) when a swing of `n` frames from frame k lands: offline the
        path's there, live the present carried on at its velocity."""
        i, k1 = k - self.base, k + n
        if k1 < available:
            j = k1 - self.base
            return path.pelvis[j], path.heading[j], path.velocity[j]
        pelvis = path.pelvis[i].copy()
        pelvis[:2] += path.velocity[i] * n / self.fps
        return pelvis, path.heading[i], path.velocity[i]

    def _stance_lasts(self, path: BodyPath, k: int, n: int, foot: int, available: int) -> int:
        """How many frames from k (up to n) a swing may last for the standing `foot` to keep its hip
        within the reach its heel can give (`RISE_STEP`, heel.py) until it may step itself: through
        the swing and the `DOUBLE_SUPPORT` after it (a walk at its quickest cadence steps as soon as
        that allows, the hip walking on from the foot behind meanwhile); the path known (offline);
        at least `SHORTEST_SWING_S`."""
        stop = min(k + n + int(round(DOUBLE_SUPPORT * n)), available)
        shortest = max(2, int(round(SHORTEST_SWING_S * self.fps)))
        if stop - k <= shortest:
            return n
        rows = np.arange(k, stop) - self.base
        hips = path.pelvis[rows, None] + np.einsum("fij,sj->fsi", body_axes(path.heading[rows]), self.shape.hip)
        angle, _ = heel.rise(self.shape, hips, np.broadcast_to(self.feet, hips.shape),
                             np.broadcast_to(self.headings, hips.shape[:2]))
        out = np.flatnonzero(angle[:, foot] > RISE_STEP)
        if not len(out):
            return n
        # the swing and its double support end by the frame the standing heel rises past RISE_STEP
        quick = int(out[0] / (1.0 + DOUBLE_SUPPORT))
        quick -= quick + int(round(DOUBLE_SUPPORT * quick)) > out[0]
        return max(shortest, min(n, quick))

    def _within_reach(self, target: np.ndarray, foot: int, pelvis: np.ndarray, heading: float) -> np.ndarray:
        """`target` drawn toward its hip, over the floor, until the leg reaches it landing (within
        `heel.REACH` of its length): a step lands no further than the leg can reach."""
        shape = self.shape
        hip = pelvis + body_axes(heading) @ shape.hip[foot]
        drop = max(hip[2] - target[2], 0.0)
        most = np.sqrt(max((LAND_REACH * shape.leg) ** 2 - drop * drop, 0.0))
        off = target[:2] - hip[:2]
        far = float(np.linalg.norm(off))
        if far > most:
            target = target.copy()
            target[:2] = hip[:2] + off * (most / far)
        return target

    def _keep_apart(self, target: np.ndarray, foot: int, heading: float) -> np.ndarray:
        """`target` moved across the body, if needed, to stand MIN_WIDTH on its side of the other foot."""
        right = body_axes(heading)[:, 0]
        other = self.feet[1 - foot]
        side = -1.0 if foot == 0 else 1.0  # the left foot stands toward -right
        across = (target - other) @ right * side
        need = MIN_WIDTH * self.shape.stature
        if across < need:
            target = target + right * side * (need - across)
        return target

    def _around(self, foot: int, target: np.ndarray, heading: float) -> np.ndarray:
        """(3,) how far the swing bows out to pass the standing foot MIN_WIDTH apart across the body
        (at mid-swing; nothing when the straight path keeps that far): a step after a turn starts
        on the other foot's side."""
        right = body_axes(heading)[:, 0]
        side = -1.0 if foot == 0 else 1.0
        other = self.feet[1 - foot]
        start, end = (self.feet[foot] - other) @ right * side, (target - other) @ right * side
        need = MIN_WIDTH * self.shape.stature
        return right * side * max(0.0, need - min(start, end))

    def _swing(self, k, stop, out_pos, out_heading) -> int:
        foot, k0, k1, p0, p1, h0, h1, height, around, pitch0, pitch1 = self.swing
        until = min(k1, stop)
        u = (np.arange(k, until) - k0) / max(k1 - k0, 1)
        s = min_jerk(u)
        # the bow out starts and ends at rest (sin squared): a foot leaves and meets the floor without sliding
        pos = p0 + s[:, None] * (p1 - p0) + (np.sin(np.pi * u) ** 2)[:, None] * around
        pos[:, 2] += height * np.sin(np.pi * u)
        rows = slice(k - self.base, until - self.base)
        out_pos[rows] = self.feet
        out_pos[rows, foot] = pos
        out_heading[rows] = self.headings
        out_heading[rows, foot] = h0 + s * (h1 - h0)
        self.out_pitch[rows] = self.pitches
        self.out_pitch[rows, foot] = pitch0 + s * (pitch1 - pitch0)
        if until == k1:
            self.feet[foot], self.headings[foot], self.pitches[foot] = p1, h1, pitch1
            self.swing = None
            self.ready_at = k1 + int(round(DOUBLE_SUPPORT * (k1 - k0)))
        return until

    def _airborne(self, path, k, stop, out_pos, out_heading) -> int:
        """Both feet under the body while it is off the floor, carried with the pelvis; they land
        where they are."""
        b = self.base
        if self.air is None:
            self.air = (path.pelvis[k - b, :2].copy(), np.zeros(2))
        takeoff, carried_last = self.air
        down = np.flatnonzero(path.lift[k - b:stop - b] <= 0.0)
        until = k + int(down[0]) if len(down) else stop
        rows = slice(k - b, until - b)
        carried = path.pelvis[rows, :2] - takeoff
        out_pos[rows] = self.feet
        out_pos[rows, :, :2] += carried[:, None]
        out_pos[rows, :, 2] += path.lift[rows, None]
        out_heading[rows] = self.headings
        self.out_pitch[rows] = self.pitches
        if len(carried):
            carried_last = carried[-1]
        self.air = (takeoff, carried_last)
        if len(down):  # landed at `until`
            self.feet[:, :2] += carried_last
            self.air = None
            self.ready_at = until
        return until
