"""The touch steps of a six-device user (FORMATS.md §2.4), performed by the clip's skeleton: each
controller's tip found by a pivot step, then the wrists, elbows, knees and ankles touched on the
skin with a controller's tip. Nothing here comes from the engine.

The controller's tip is a point of the controller (its front, past the thumb side of the fist),
fixed in the hand's frame for a session (`tip_in_hand`); where it sits in the controller's own
frame follows from the capture's random mounting, so nothing tells the engine where it is: the
pivot step is there to find it. In the pivot the performer holds the tip on one spot of a table in
front of them and circles the controller around it, tilted 17-33 degrees, turning it about its
own axis as the wrist finds easiest (the tip slips `SLIP_MM` on the table).

A touch puts the tip on a landmark of the skin, not on the joint: the two epicondyles of the knee
and of the elbow, the two malleoli, the back and the front of the wrist, each half the joint's
breadth from its centre along its axis (adult sizes scaled by the performer's leg, +-10 % per
session); their midpoint is off the BVH's joint by an anatomical few millimetres (`LANDMARK_MM`
per axis: where the skeleton's fit put the joint is not where a hand finds the bones); each touch
is placed with a person's imprecision (`PLACEMENT_MM` per axis across the skin, at most a
centimetre, pressed 0-3 mm into it) and held a second with a millimetre of tremor, the segment
reaching a little into the hand's coming and going.

The touching arm is placed by inverse kinematics on the clip's own bones (`reach`): of the hand
orientations that point the tip into the skin (within 40 degrees of straight in) the one whose
wrist the arm's inverse kinematics bends least (`_best_hand`: at most 60 degrees), turned 3-8
degrees at random; the wrist follows from the tip, the elbow from the two bone lengths (in the
pivot, the controller turns about its axis the way the wrist bends least as the turns go on).
Wrists and elbows are touched by the other hand, the touched arm's upper arm 35 degrees forward
and in, its elbow bent 90 degrees (the forearm across the front of the body). Knees and ankles
are touched with that foot up on a chair (the thigh 65-90 degrees up, the shin about upright, the
foot flat), the inner side by the other hand and the outer by the same side's; the trunk bends
forward at the hips, turns toward the touched side and the standing knee bends, each as little
as lets the hand reach (`touch_pose` tries them in that order: knees 30-60 degrees of bend,
ankles 60-100). The trunk above the pelvis keeps its rest shape (the clavicles do not move).
"""

from __future__ import annotations

import numpy as np

from . import rot
from .performer import FORWARD, LEFT, SIDES, UP, Performer, Pose, _smooth_noise, hanging

ADULT_LEG_M = 0.85  # capture.ADULT_LEG_M: the sizes below are an adult's
HALF_BREADTH = {"knee": 0.050, "ankle": 0.035, "elbow": 0.032, "wrist": 0.019}  # m, adult, centre to skin
TIP_FROM_GRIP = (0.075, 0.105)  # m, adult: the controller's front past the thumb side of the fist
PLACEMENT_MM = 4.0  # a person's scatter placing the tip, per axis across the skin ...
PLACEMENT_MAX_MM = 10.0  # ... at most this
PRESS_MM = (0.0, 3.0)  # into the skin
LANDMARK_MM = 3.0  # the two landmarks' midpoint vs the skeleton's joint, per axis (at most 6 mm)
TREMOR_MM = 1.0  # the held tip's tremor
SLIP_MM = 1.5  # the tip's slip on the table during the pivot
WOBBLE_DEG = 1.5  # hands and feet in these postures (a foot on a chair, an arm held out to be touched)
TIP_TILT_STEPS_DEG = (20.0, 40.0)  # the touching tip may come in this far off straight into the skin ...
WRIST_BEND_MAX_DEG = 60.0  # ... for a hand whose wrist bends at most this (flexion reaches ~80°, deviation ~30°)
HAND_TURN_DEG = (3.0, 8.0)  # then turned at random this much (nobody holds a controller the same way twice)
PIVOT_S = 6.0
TOUCH_HOLD_S = 1.0
TOUCH_SEGMENT_PAD_S = 0.2  # a touch's segment reaches this far into the motion before and after the hold
OTHER = {"l": "r", "r": "l"}


def _k(perf: Performer) -> float:
    return perf.leg_length / ADULT_LEG_M


def _lateral(s: str) -> np.ndarray:
    return LEFT * (1.0 if s == "l" else -1.0)


def hand_axes(perf: Performer, s: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(along the hand toward the fingers, out of the palm, toward the thumb) in the hand's frame."""
    along = rot.unit(perf.child_offset(perf.j(f"wrist_{s}")))
    palm = perf.palm_normal_rest(s)
    palm = rot.unit(palm - (palm @ along) * along)
    return along, palm, np.cross(along, palm) * (-1.0 if s == "l" else 1.0)


def tip_in_hand(perf: Performer, s: str, rng) -> np.ndarray:
    """The controller's tip in the hand's (wrist joint's) frame: the middle of capture.py's grip
    carried past the thumb side of the fist."""
    k = _k(perf)
    along, palm, thumb = hand_axes(perf, s)
    grip = along * 0.062 * k + palm * 0.027 * k
    return grip + thumb * rng.uniform(*TIP_FROM_GRIP) * k + along * rng.uniform(0.0, 0.03) * k


_ARMS: dict[tuple[int, str], tuple] = {}


def _arm(perf: Performer, s: str):
    """(elbow in the upper arm's frame, wrist in the forearm's, hinge axis, elbow angles, the
    shoulder-to-wrist span at each angle) of arm `s` on the clip's bones."""
    key = (id(perf), s)
    if key not in _ARMS or _ARMS[key][0] is not perf:
        _ARMS[key] = (perf, _arm_table(perf, s))
    return _ARMS[key][1]


def _arm_table(perf: Performer, s: str):
    off_e = perf.child_offset(perf.j(f"shoulder_{s}"))
    off_w = perf.child_offset(perf.j(f"elbow_{s}"))
    axis0 = perf.hinge[f"elbow_{s}"][0]
    table = np.radians(np.arange(0.0, 160.0, 0.05))
    span = np.linalg.norm(off_e[None] + np.einsum("nij,j->ni", rot.axis_angle(axis0, table), off_w), axis=1)
    return off_e, off_w, axis0, table, span


def _solve_arm(arm, shoulder: np.ndarray, wrist: np.ndarray, elbow_toward: np.ndarray):
    """(upper arm's world rotation (n, 3, 3), elbow angle (n,), reachable (n,)) for `reach`."""
    off_e, off_w, axis0, table, span = arm
    d = np.linalg.norm(wrist - shoulder, axis=1)
    ok = (d <= 0.985 * span[0]) & (d >= 1.02 * span[-1])
    angle = np.interp(d, span[::-1], table[::-1])
    v = off_e[None] + np.einsum("nij,j->ni", rot.axis_angle(axis0, angle), off_w)
    bend = off_e[None] - np.sum(off_e[None] * rot.unit(v), -1, keepdims=True) * rot.unit(v)
    return rot.basis(v, bend, wrist - shoulder, elbow_toward), angle, ok


def reach(perf: Performer, s: str, shoulder: np.ndarray, wrist: np.ndarray, elbow_toward: np.ndarray):
    """Inverse kinematics of arm `s` on the clip's bones: (world rotation (n, 3, 3) of the upper arm,
    elbow angle (n,)) putting the wrist joint at `wrist` (n, 3) from the shoulder joint at
    `shoulder`, the elbow off the shoulder-wrist line toward `elbow_toward` (n, 3). Raises
    ValueError when the wrist is out of reach."""
    g1, angle, ok = _solve_arm(_arm(perf, s), shoulder, wrist, elbow_toward)
    if not ok.all():
        d = np.linalg.norm(wrist - shoulder, axis=1)
        raise ValueError(f"arm {s} cannot reach: {d.min():.3f}-{d.max():.3f} m")
    return g1, angle


def _tremor(n: int, fps: float, rng, rms_mm: float) -> np.ndarray:
    return _smooth_noise(rng, n, fps, 3, rms_mm / 1000.0 / np.sqrt(3), 0.5, 3.0)


def _placement(rng, normal: np.ndarray) -> np.ndarray:
    """A person's placement of the tip on a spot whose outward skin normal is `normal` (3,)."""
    e = np.clip(rng.normal(0.0, PLACEMENT_MM, 3), -PLACEMENT_MAX_MM, PLACEMENT_MAX_MM) / 1000.0
    e -= (e @ normal) * normal
    return e - normal * rng.uniform(*PRESS_MM) / 1000.0


def _best_hand(perf: Performer, s: str, tip: np.ndarray, normal: np.ndarray, shoulder: np.ndarray,
               tip_hand: np.ndarray, elbow_toward: np.ndarray) -> np.ndarray | None:
    """The world rotation (3, 3) of hand `s` holding its controller's tip on `tip` (3,) with the tip
    pointing into the skin (within `TIP_TILT_DEG` of straight in, against the outward `normal`) that
    the arm reaches with the wrist bent least (the hand's axis against the forearm's, by the arm's
    inverse kinematics); None when no such hand leaves the wrist bent under `WRIST_BEND_MAX_DEG`."""
    h_along, _, h_thumb = hand_axes(perf, s)
    ref = rot.unit(np.cross(normal, UP if abs(normal @ UP) < 0.9 else LEFT))
    tilt = np.concatenate([[0.0], np.repeat(np.radians(TIP_TILT_STEPS_DEG), 8)])
    az = np.concatenate([[0.0], np.tile(np.radians(np.arange(0.0, 360.0, 45.0)), len(TIP_TILT_STEPS_DEG))])
    side = np.einsum("kij,j->ki", rot.axis_angle(np.broadcast_to(-normal, (len(az), 3)), az), ref)
    intos = -normal[None] * np.cos(tilt)[:, None] + side * np.sin(tilt)[:, None]
    rolls = np.radians(np.arange(0.0, 360.0, 30.0))
    into = np.repeat(intos, len(rolls), axis=0)
    cost = np.repeat(np.degrees(tilt) / 3.0, len(rolls))
    across = rot.unit(np.cross(into, ref))
    along = np.einsum("kij,kj->ki", rot.axis_angle(into, np.tile(rolls, len(intos))), across)
    G = rot.basis(np.broadcast_to(h_thumb, into.shape), np.broadcast_to(h_along, into.shape), into, along)
    wrist = tip[None] - np.einsum("kij,j->ki", G, tip_hand)
    arm = _arm(perf, s)
    g1, _, ok = _solve_arm(arm, np.broadcast_to(shoulder, wrist.shape), wrist, np.broadcast_to(elbow_toward,
                                                                                                 wrist.shape))
    elbow = shoulder[None] + np.einsum("kij,j->ki", g1, arm[0])
    forearm = rot.unit(wrist - elbow)
    bend = np.degrees(np.arccos(np.clip(np.sum(forearm * np.einsum("kij,j->ki", G, h_along), -1), -1.0, 1.0)))
    score = np.where(ok & (bend <= WRIST_BEND_MAX_DEG), bend + cost, np.inf)
    k = int(np.argmin(score))
    return G[k] if np.isfinite(score[k]) else None


def _hand_turned(perf: Performer, s: str, into: np.ndarray, along: np.ndarray, rng, n: int) -> np.ndarray:
    """World rotations (n, 3, 3) of hand `s` holding its controller with the tip (past the thumb)
    pointing `into` (n, 3) and the fingers as close to `along` (n, 3) as that allows, turned at
    random by 10-25 degrees (nobody holds a controller the same way twice)."""
    h_along, _, h_thumb = hand_axes(perf, s)
    base = rot.basis(np.broadcast_to(h_thumb, (n, 3)), np.broadcast_to(h_along, (n, 3)), into, along)
    return base @ rot.axis_angle(rot.unit(rng.normal(size=3)), np.radians(rng.uniform(10.0, 25.0)))


class _Body:
    """What the touch postures share: the standing pose's parameters, the session's rng, the
    session's joint breadths and landmark offsets."""

    def __init__(self, perf: Performer, rng, fps: float, lift: np.ndarray, stance: float, bends):
        self.perf, self.rng, self.fps = perf, rng, fps
        self.lift, self.stance, self.bends = lift, stance, bends
        k = _k(perf)
        self.breadth = {j: w * k * rng.uniform(0.9, 1.1) for j, w in HALF_BREADTH.items()}
        self.landmark_mid = {f"{j}_{s}": np.clip(rng.normal(0.0, LANDMARK_MM, 3), -6.0, 6.0) / 1000.0
                             for j in HALF_BREADTH for s in SIDES}

    def arm_down(self, n: int, s: str):
        fps, rng = self.fps, self.rng
        d, f = hanging(np.radians(8.0) + _smooth_noise(rng, n, fps, 1, np.radians(2.0))[:, 0],
                       np.full(n, np.radians(90.0)), s, FORWARD)
        return d, f, np.radians(10.0) + _smooth_noise(rng, n, fps, 1, np.radians(3.0))[:, 0]

    def posed(self, n: int, *, arm=None, leg=None, pitch_deg: float = 0.0, yaw_deg: float = 0.0,
              knee_deg: float = 0.0) -> Pose:
        """A pose with the trunk bent `pitch_deg` forward at the hips and turned `yaw_deg` to the
        left, a standing leg (one not in `leg`) bent `knee_deg` at the knee with its shin upright,
        the root placed so that the standing feet stay where they stand in `stand`."""
        perf = self.perf
        turn = rot.axis_angle(UP, np.radians(yaw_deg)) @ rot.axis_angle(LEFT, np.radians(pitch_deg))
        kw = dict(stance_deg=self.stance, bends_deg=self.bends)
        standing = [s for s in SIDES if s not in (leg or {})] or list(SIDES)
        legs = dict(leg or {})
        if knee_deg:
            b = np.radians(knee_deg)
            for s in standing:
                out = np.radians(self.stance) * (1 if s == "l" else -1)
                d = rot.axis_angle(FORWARD, -out) @ (-UP * np.cos(b) + FORWARD * np.sin(b))
                legs[s] = (np.broadcast_to(d, (n, 3)), np.broadcast_to(-FORWARD, (n, 3)), np.full(n, b))
        stand = perf.positions(perf.pose(1, root_offset=self.lift, **kw))
        pose = perf.pose(n, arm=arm, leg=legs, root_offset=self.lift, rng=self.rng,
                         root_rot=np.broadcast_to(turn, (n, 3, 3)), wobble_deg=WOBBLE_DEG, **kw)
        first = perf.positions(Pose(pose.G[:1], pose.root[:1]))
        shift = np.mean([stand[0, perf.j(f"ankle_{s}")] - first[0, perf.j(f"ankle_{s}")] for s in standing], axis=0)
        return Pose(pose.G, pose.root + shift)

    def with_reach(self, pose: Pose, s: str, tip_world: np.ndarray, hand_rot: np.ndarray, tip_hand: np.ndarray,
                   elbow_toward: np.ndarray) -> Pose:
        """`pose` with arm `s` reaching so that the tip (`tip_hand` in the hand's frame) is at
        `tip_world` (n, 3), the hand turned `hand_rot` (n, 3, 3); the joints below the wrist follow
        it at rest. Raises ValueError when the arm cannot reach."""
        perf = self.perf
        shoulder = perf.positions(pose)[:, perf.j(f"shoulder_{s}")]
        wrist = tip_world - np.einsum("nij,j->ni", hand_rot, tip_hand)
        g1, angle = reach(perf, s, shoulder, wrist, elbow_toward)
        G = pose.G.copy()
        wj = perf.j(f"wrist_{s}")
        G[:, perf.j(f"shoulder_{s}")] = g1
        G[:, perf.j(f"elbow_{s}")] = g1 @ rot.axis_angle(perf.hinge[f"elbow_{s}"][0], angle)
        G[:, wj] = hand_rot
        below = {wj}
        for j, p in enumerate(perf.parents):  # a parent comes before its children in a BVH
            if p in below:
                below.add(j)
                G[:, j] = G[:, p]
        out = Pose(G, pose.root)
        got = perf.positions(out)[:, wj] + np.einsum("nij,j->ni", hand_rot, tip_hand)
        err = float(np.linalg.norm(got - tip_world, axis=1).max())
        if err > 1e-4:
            raise ValueError(f"the {s} controller's tip missed its spot by {err * 1000:.1f} mm")
        return out


def pivot_pose(body: _Body, s: str, tip_hand: np.ndarray) -> Pose:
    """`pivot_tip_<s>`: the tip held on a spot of a table in front, the controller circled around it
    (about two turns, tilted 17-33 degrees from pointing straight down), turning about its own
    axis as the wrist finds easiest."""
    perf, rng, fps = body.perf, body.rng, body.fps
    n = int(round(PIVOT_S * fps))
    pose = body.posed(n, arm={a: body.arm_down(n, a) for a in SIDES})
    shoulder = perf.positions(pose)[0, perf.j(f"shoulder_{s}")]
    spot = shoulder + (FORWARD * 0.35 - UP * 0.30 + _lateral(s) * 0.04) * _k(perf)
    t = np.arange(n) / fps
    azimuth = 2 * np.pi * rng.uniform(0.3, 0.4) * t + rng.uniform(0, 2 * np.pi)
    tilt = np.radians(25.0 + 8.0 * np.sin(2 * np.pi * rng.uniform(0.15, 0.25) * t + rng.uniform(0, 2 * np.pi)))
    horiz = np.cos(azimuth)[:, None] * FORWARD + np.sin(azimuth)[:, None] * LEFT
    into = -UP * np.cos(tilt)[:, None] + horiz * np.sin(tilt)[:, None]  # the tip points down into the table
    fingers = rot.unit(np.broadcast_to(FORWARD + 0.3 * _lateral(OTHER[s]), (n, 3)))
    base = _hand_turned(perf, s, into, fingers, rng, n)
    elbow = np.broadcast_to(rot.unit(_lateral(s) * 0.6 - 0.2 * UP - 0.8 * FORWARD), (n, 3))
    tip = spot + _tremor(n, fps, rng, SLIP_MM)
    # the controller turned about its tip the way the wrist bends least as the turns go on (a
    # path through the rolls, changing it slowly: `_roll_path`), `_best_hand`'s measure
    arm, h_along = _arm(perf, s), hand_axes(perf, s)[0]
    rolls = np.radians(np.arange(0.0, 360.0, 10.0))
    bends = np.empty((n, len(rolls)))
    for k, roll in enumerate(rolls):
        turned = rot.axis_angle(into, np.full(n, roll)) @ base
        wrist = tip - np.einsum("nij,j->ni", turned, tip_hand)
        g1, _, ok = _solve_arm(arm, np.broadcast_to(shoulder, wrist.shape), wrist, elbow)
        forearm = rot.unit(wrist - shoulder - np.einsum("nij,j->ni", g1, arm[0]))
        cos = np.sum(forearm * np.einsum("nij,j->ni", turned, h_along), -1)
        bends[:, k] = np.where(ok, np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))), 1e6)
    roll = _roll_path(bends, rolls, fps)
    hand = rot.axis_angle(into, roll) @ base
    return body.with_reach(pose, s, tip, hand, tip_hand, elbow)


def _roll_path(cost: np.ndarray, rolls: np.ndarray, fps: float, change: float = 2.0) -> np.ndarray:
    """(n,) a roll per frame through `rolls` (K,) minimising the summed `cost` (n, K) plus `change`
    per step to a neighbouring roll (one step per frame at most: dynamic programming), then
    smoothed over 0.3 s so the controller turns, not jumps."""
    n, k = cost.shape
    total, back = cost[0].copy(), np.zeros((n, k), int)
    for f in range(1, n):
        stay = np.stack([total, np.roll(total, 1) + change, np.roll(total, -1) + change])
        pick = np.argmin(stay, axis=0)
        back[f] = (np.arange(k) - np.array([0, 1, -1])[pick]) % k
        total = stay[pick, np.arange(k)] + cost[f]
    path = np.empty(n, int)
    path[-1] = int(np.argmin(total))
    for f in range(n - 1, 0, -1):
        path[f - 1] = back[f, path[f]]
    angle = np.unwrap(rolls[path])
    w = max(1, int(round(0.3 * fps)))
    padded = np.concatenate([np.full(w, angle[0]), angle, np.full(w, angle[-1])])
    return np.convolve(padded, np.ones(2 * w + 1) / (2 * w + 1), mode="same")[w:-w]


def _touched_arm(n: int, s: str):
    """The touched arm: the upper arm 35 degrees forward and toward the body's middle, the elbow
    bent 90 degrees, the forearm across the front of the body."""
    inward = rot.axis_angle(UP, np.radians(35.0) * (-1.0 if s == "l" else 1.0)) @ FORWARD
    d, f = hanging(np.full(n, np.radians(35.0)), np.full(n, np.radians(-35.0)), s, inward)
    return d, f, np.full(n, np.radians(90.0))


def _leg_up(n: int, s: str, hip_flex_deg: float):
    """The leg of side `s` with its foot up on a chair: the thigh `hip_flex_deg` up from hanging
    and 10 degrees out, the knee bent as much, the shin about upright."""
    a = np.radians(hip_flex_deg)
    d, f = hanging(np.full(n, a), np.full(n, np.radians(10.0)), s, -FORWARD)
    return d, f, np.full(n, a)


def _lateral_now(perf: Performer, pose: Pose, s: str, joint: str) -> np.ndarray:
    """(n, 3) the lateral side of `joint`_`s` in `pose`: away from the body's middle, carried from
    the standing leg by the thigh; for the elbow, up in the T-pose (the arm out to the side with
    the elbow flexing forward, the lateral epicondyle is on top), carried by the upper arm."""
    if joint == "elbow":
        prox, g0, ref = "shoulder", perf._segment_rotation(f"shoulder_{s}", _lateral(s), FORWARD), UP
    else:
        prox, g0, ref = "hip", perf._segment_rotation(f"hip_{s}", -UP, -FORWARD), _lateral(s)
    return np.einsum("nij,j->ni", pose.G[:, perf.j(f"{prox}_{s}")] @ g0.T, ref)


def landmarks(body: _Body, pose: Pose, joint: str, s: str) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """{point: (spot (n, 3), outward skin normal (n, 3))} of a joint's two touch points in `pose`."""
    perf = body.perf
    P = perf.positions(pose)
    w = body.breadth[joint]
    centre = P[:, perf.j(f"{joint}_{s}")] + body.landmark_mid[f"{joint}_{s}"]
    if joint == "wrist":
        back = -np.einsum("nij,j->ni", pose.G[:, perf.j(f"wrist_{s}")], hand_axes(perf, s)[1])
        return {f"wrist_top_{s}": (centre + back * w, back), f"wrist_bottom_{s}": (centre - back * w, -back)}
    # the hinge's axis (the malleoli: across the shin, as the knee's axis turns with it)
    carrier = {"elbow": "shoulder", "knee": "hip", "ankle": "knee"}[joint]
    axis = np.einsum("nij,j->ni", pose.G[:, perf.j(f"{carrier}_{s}")],
                     perf.hinge[("elbow" if joint == "elbow" else "knee") + f"_{s}"][0])
    axis = axis * np.sign(np.sum(axis * _lateral_now(perf, pose, s, joint), -1))[:, None]
    return {f"{joint}_out_{s}": (centre + axis * w, axis), f"{joint}_in_{s}": (centre - axis * w, -axis)}


def touch_pose(body: _Body, point: str, by: str, tip_hand: np.ndarray) -> Pose:
    """One touch held `TOUCH_HOLD_S`: the posture its point needs (module docstring), the
    toucher's tip on the spot."""
    perf, rng, fps = body.perf, body.rng, body.fps
    n = int(round(TOUCH_HOLD_S * fps))
    joint, s, t = point.split("_")[0], point[-1], by[-1]
    arms = {a: body.arm_down(n, a) for a in SIDES}
    toward = 1.0 if t == "r" else -1.0  # a turn to the left brings the right shoulder forward
    if joint in ("wrist", "elbow"):
        arms[s] = _touched_arm(n, s)
        leg = None
        tries = [(p, y * toward, 0.0) for y in (0.0, 15.0, 30.0) for p in (0.0, 10.0, 20.0)]
    else:
        leg = {s: _leg_up(n, s, rng.uniform(65.0, 80.0) if joint == "knee" else rng.uniform(80.0, 90.0))}
        yaws = (0.0, 15.0, 30.0) if t != s else (0.0, -15.0)
        pitches = (30.0, 40.0, 50.0, 60.0) if joint == "knee" else (60.0, 70.0, 80.0, 90.0, 100.0)
        tries = [(p, y * toward, b) for b in (0.0, 20.0, 35.0, 45.0) for y in yaws for p in pitches]
    place = None
    for pitch, yaw, bend in tries:
        pose = body.posed(n, arm=arms, leg=leg, pitch_deg=pitch + rng.uniform(-3.0, 3.0), yaw_deg=yaw, knee_deg=bend)
        spot, normal = landmarks(body, pose, joint, s)[point]
        if place is None:
            place = _placement(rng, normal[0])
        tip_world = spot + place + _tremor(n, fps, rng, TREMOR_MM)
        shoulder = perf.positions(pose)[:, perf.j(f"shoulder_{t}")]
        elbow = rot.unit(_lateral(t) - 0.6 * UP)
        best = _best_hand(perf, t, tip_world[0], normal[0], shoulder[0], tip_hand, elbow)
        if best is None:
            continue
        turn = rot.axis_angle(rot.unit(rng.normal(size=3)), np.radians(rng.uniform(*HAND_TURN_DEG)))
        hand = np.broadcast_to(best @ turn, (n, 3, 3))
        try:
            return body.with_reach(pose, t, tip_world, hand, tip_hand, np.broadcast_to(elbow, (n, 3)))
        except ValueError:
            continue
    raise ValueError(f"{by} cannot reach {point} of {perf.clip.name}")


def toucher(point: str) -> str:
    """The controller tip that touches `point`: the other hand's on an arm and on the inner side of
    a leg, the same side's on the outer side of a knee or an ankle."""
    s = point[-1]
    return f"controller_tip_{s if point.startswith(('knee_out', 'ankle_out')) else OTHER[s]}"


# (point, by) in the order they are performed: both arms, then both legs (one posture each)
TOUCHES = tuple((f"{p}_{s}", toucher(f"{p}_{s}")) for points in (("wrist_top", "wrist_bottom", "elbow_in", "elbow_out"),
                                                                  ("knee_in", "knee_out", "ankle_in", "ankle_out"))
                for s in SIDES for p in points)


def touch_poses(perf: Performer, rng, fps: float, lift, stance: float, bends, tips: dict[str, np.ndarray]):
    """[(step, pose, segment fields)]: both pivots, then every touch of `TOUCHES`."""
    body = _Body(perf, rng, fps, lift, stance, bends)
    out = [(f"pivot_tip_{s}", pivot_pose(body, s, tips[s]), {}) for s in SIDES]
    for point, by in TOUCHES:
        out.append(("touch", touch_pose(body, point, by, tips[by[-1]]), {"point": point, "by": by}))
    return out
