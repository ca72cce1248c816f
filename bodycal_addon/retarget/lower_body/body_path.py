"""The body's path under the head (DESIGN.md §6 "A lower body from head and hands"): the skull
base carried by the HMD, the body's heading, the trunk's lean and the pelvis under it, vectorised
over frames.

- Heading: the HMD's turn about the vertical since the reference time (the twist of its rotation),
  smoothed (a person looks around without turning the body) and kept within `MAX_NECK_TWIST` of
  the head (nobody turns the head further than that from the trunk for long). Offline the
  smoothing looks both ways (a Gaussian over `HEADING_SMOOTH_S`); live it is a forward exponential
  with the same time scale, which lags.
- Lean: the trunk bends forward with the head's pitch beyond a looking-down range, no more than
  a bow with straight legs would take the skull base down to its height; the rest of a drop is
  a squat (the knees bend): a bow looks down, a squat keeps the head up (`trunk_lean`). The pelvis takes
  `PELVIS_SHARE` of the lean (lumbopelvic rhythm), the spine the rest (the spine IK, aimed at the
  skull base).
- Bow or squat (`bow_weight`): a lean that starts where the head stood upright (an episode: the
  head pitched past `LOOK_DOWN` or low) is a bow, a hinge at hips that stay at their standing height
  over the feet (`hinge_lean`), once the head has both looked back under the body (pitched past
  the vertical, `HINGE_PITCH`) and travelled forward further than a body balanced over the feet it
  stood on can carry it by leaning (`balanced_reach`: the mass centre stays over the support, so the
  hips go back as the trunk leans, `centre_of`). A squat's head stays within that reach. Offline
  the episode's whole course decides (looking ahead), live the episode so far (forward only). A
  bow bends at the hips: its pelvis takes the lean past `BOW_SPINE`, and its hips stay over the
  planted feet while the head swings ahead (`bow_follow`).
- Pelvis: the skull base less the trunk turned by the heading and leaned toward where the head
  looks (the head's own heading: a bow after a quick turn bends toward what the eyes look down
  at, which the smoothed body heading reaches late); it drops as the head
  drops (the knees bend) and rises with it off the floor (`lift`: both feet leave the floor, a hop)
  once above its standing height by more than `LIFT_FROM`.
- Seated (`seat_height`): the pelvis on the seat under the trunk, moving over the floor only as a
  chair does (`SEAT_FOLLOW_S`); the trunk leans toward the head through the spine.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...core import transforms as tf
from .shape import LowerBodyShape, body_axes, lean, wrap

HEADING_SMOOTH_S = 0.8
MAX_NECK_TWIST = np.radians(50.0)
KNEES_FIRST = 0.05  # x stature: a drop of the skull base this small is the knees' (a walk's bob)
LOOK_DOWN = np.radians(20.0)
LEAN_PER_PITCH = 0.7
MAX_LEAN = np.radians(110.0)
LOWEST_PELVIS = 0.35  # x the standing pelvis height: kneeling, sitting back on a heel
PELVIS_SHARE = 0.35
BOW_SPINE = 0.0  # a bow's spine bends this much at most; its hips (the pelvis) take the rest (a hip hinge
# keeps the spine neutral: all the lean at the hips)
BOW_FOLLOW_S = 0.5  # a bow's pelvis follows its place over the floor this slowly (`bow_follow`)
LIFT_FROM = 0.02  # x stature above the standing pelvis height
HIP_ABOVE_SEAT = 0.055  # x stature: the hip joints above the seat (the ischial tuberosities below them)
SEAT_FOLLOW_S = 1.5
VELOCITY_SMOOTH_S = 0.06
HINGE_PITCH = np.radians((80.0, 100.0))  # the head's pitch down over which a bow's tell ramps in (about the
# vertical: the eyes look back under the body, toward feet the head has gone far ahead of)
HINGE_NEARER = (0.5, 1.0)  # of the way from the squat's balanced travel to the bow's: the ramp of its tell
HINGE_GAP = 0.1  # x `balanced_reach`: the least gap between the two travels (where they agree)
DEPTH_PITCH = np.radians(20.0)  # past `LOOK_DOWN`: a bow's weight fades in over this pitch (`depth`)


@dataclass
class BodyPath:
    """Frames' body path: (F, 3) `neck` (skull base), (F,) `heading`, (F,) `lean` (trunk, radians),
    (F, 3) `pelvis`, (F, 3, 3) `pelvis_rot` (the estimated pelvis device's rotation), (F,) `lift`
    (how far both feet leave the floor), (F, 2) `velocity` (the pelvis over the floor, m/s)."""

    neck: np.ndarray
    heading: np.ndarray
    lean: np.ndarray
    pelvis: np.ndarray
    pelvis_rot: np.ndarray
    lift: np.ndarray
    velocity: np.ndarray
    centre: np.ndarray | None = None  # (F, 2) the body's mass centre over the floor (None: the pelvis)
    centre_velocity: np.ndarray | None = None  # (F, 2) its velocity (None: the pelvis's)


def centre_of(shape: LowerBodyShape, neck: np.ndarray, pelvis: np.ndarray) -> np.ndarray:
    """(F, 2) the body's mass centre over the floor: `shape.centre_share` of the way from the pelvis
    to the skull base (a squat's pelvis goes back as its trunk leans forward; its mass centre
    stays over the feet)."""
    return pelvis[..., :2] + shape.centre_share * (neck[..., :2] - pelvis[..., :2])


def over_the_floor(shape: LowerBodyShape, time: np.ndarray, neck: np.ndarray, pelvis: np.ndarray,
                   on_pelvis: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(F, 2) the pelvis's velocity over the floor, (F, 2) the body's mass centre there (`on_pelvis`:
    the pelvis's place, as when seated, the seat bearing the trunk) and (F, 2) its velocity, along a
    whole take (the velocities smoothed over `VELOCITY_SMOOTH_S` both ways)."""
    centre = pelvis[:, :2].copy() if on_pelvis else centre_of(shape, neck, pelvis)
    if len(time) < 2:
        return np.zeros((len(time), 2)), centre, np.zeros((len(time), 2))
    fps = (len(time) - 1) / max(time[-1] - time[0], 1e-9)
    velocity, centre_velocity = (gaussian(np.gradient(x, time, axis=0), VELOCITY_SMOOTH_S * fps)
                                 for x in (pelvis[:, :2], centre))
    return velocity, centre, centre_velocity


def neck_and_head(shape: LowerBodyShape, head_pos: np.ndarray, head_rot: np.ndarray):
    """(F, 3) the skull base, (F,) the head's heading and (F,) its pitch down (radians), both
    measured from the reference time's body axes carried by the HMD: the pitch from the head's
    forward and up together (unambiguous past a right angle, a deep bow), the heading from the
    forward the head has once that pitch is taken out (well defined looking down at the feet)."""
    neck = head_pos + np.einsum("fij,j->fi", head_rot, shape.neck_in_hmd)
    axes0 = shape.hmd_ref.T @ body_axes(shape.heading0)
    forward = np.einsum("fij,j->fi", head_rot, axes0[:, 1])
    up = np.einsum("fij,j->fi", head_rot, axes0[:, 2])
    pitch = np.arctan2(-forward[:, 2], up[:, 2])
    level = np.cos(pitch)[:, None] * forward + np.sin(pitch)[:, None] * up
    return neck, np.unwrap(np.arctan2(level[:, 1], level[:, 0])), pitch


def clamp_heading(body: np.ndarray, head: np.ndarray) -> np.ndarray:
    """The body's heading kept within MAX_NECK_TWIST of the head's."""
    return head + np.clip(wrap(body - head), -MAX_NECK_TWIST, MAX_NECK_TWIST)


def leaning(shape: LowerBodyShape, neck_z: np.ndarray, pitch_down: np.ndarray) -> np.ndarray:
    """(F,) bool: the frames of a lean or a drop (an episode `bow_weight` reads): the head pitched
    down past `LOOK_DOWN` or its skull base more than `KNEES_FIRST` below its standing height."""
    standing = shape.pelvis_height + shape.trunk[2]
    return (pitch_down > LOOK_DOWN) | (neck_z < standing - KNEES_FIRST * shape.stature)


def depth(shape: LowerBodyShape, neck_z: np.ndarray, pitch_down: np.ndarray) -> np.ndarray:
    """(F,) 0..1 how far into its episode (`leaning`) a frame is: 0 at its edges (the head back at
    `LOOK_DOWN` and the skull base `KNEES_FIRST` low), 1 from `LOOK_DOWN` + `DEPTH_PITCH` or
    twice `KNEES_FIRST` low; a bow's weight fades in and out with it (no jump at the edges)."""
    standing = shape.pelvis_height + shape.trunk[2]
    drop = (standing - neck_z) / (KNEES_FIRST * shape.stature)
    return np.maximum(_ramp(pitch_down, LOOK_DOWN, LOOK_DOWN + DEPTH_PITCH), _ramp(drop, 1.0, 2.0))


def balanced_reach(shape: LowerBodyShape) -> float:
    """How far forward of where it stood upright a body balanced over the same feet carries its
    skull base per unit of sin(lean), squat or bow alike: its mass centre (`centre_of`) stays over
    the feet, so the pelvis goes back `centre_share` of the trunk's horizontal reach u sin(lean)
    and the head forward the rest, (1 - centre_share) u sin(lean)."""
    return (1.0 - shape.centre_share) * float(shape.trunk[2])


def hinge_tell(shape: LowerBodyShape, travel: np.ndarray, pitch_down: np.ndarray, squat: np.ndarray,
               bow: np.ndarray) -> np.ndarray:
    """(F,) 0..1 how surely a frame is a bow: the head pitched past the vertical (`HINGE_PITCH`)
    and its skull base carried forward since its episode began (`travel`, m) nearer the bow's
    balanced travel than the squat's (`balanced_reach` times the sine of each reading's lean,
    `squat` and `bow`; `HINGE_NEARER` of the way, the gap between them at least `HINGE_GAP` of the
    reach: where the two agree, a head well beyond the squat's is the bow's)."""
    reach = max(balanced_reach(shape), 1e-9)
    at_squat = reach * np.sin(squat)
    gap = np.maximum(reach * np.sin(bow) - at_squat, HINGE_GAP * reach)
    return _ramp(pitch_down, *HINGE_PITCH) * _ramp((travel - at_squat) / gap, *HINGE_NEARER)


def _ramp(x, lo, hi):
    u = np.clip((np.asarray(x, float) - lo) / (hi - lo), 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def bow_weight(shape: LowerBodyShape, neck: np.ndarray, pitch_down: np.ndarray, squat: np.ndarray) -> np.ndarray:
    """(F,) 0 a squat, 1 a bow, along a whole take (the module docstring): per episode (`leaning`),
    its surest frame's `hinge_tell` (`squat` (F,) the lean `trunk_lean` reads), the head's travel
    measured from the skull base at the frame before the episode (the take's first if it begins
    leaning), faded in and out at the episode's edges (`depth`). Looks ahead: the whole episode is
    a bow once any of it is (`LivePath`: so far)."""
    on = leaning(shape, neck[:, 2], pitch_down)
    n = len(on)
    if not on.any():
        return np.zeros(n)
    frames = np.arange(n)
    before = np.maximum.accumulate(np.where(on, 0, frames))  # each frame's last upright frame
    travel = np.linalg.norm(neck[:, :2] - neck[before, :2], axis=1)
    tell = np.where(on, hinge_tell(shape, travel, pitch_down, squat, hinge_lean(shape, neck[:, 2])), 0.0)
    episode = np.cumsum(~on)
    most = np.zeros(episode[-1] + 1)
    np.maximum.at(most, episode, tell)
    return np.where(on, most[episode], 0.0) * depth(shape, neck[:, 2], pitch_down)


def hinge_lean(shape: LowerBodyShape, neck_z: np.ndarray) -> np.ndarray:
    """(F,) the lean of a bow: the hips at their standing height, the trunk bent down to the skull
    base (legs straight, no knees first: the knees are what a bow does not bend), within MAX_LEAN."""
    return np.minimum(np.arccos(np.clip((neck_z - shape.pelvis_height) / shape.trunk[2], -1.0, 1.0)), MAX_LEAN)


def bowed(shape: LowerBodyShape, neck_z: np.ndarray, squat: np.ndarray, weight) -> np.ndarray:
    """(F,) the lean `squat` (`trunk_lean`) taken `weight` (F,) of the way to the bow's (`hinge_lean`,
    never less)."""
    return squat + weight * np.maximum(hinge_lean(shape, neck_z) - squat, 0.0)


def trunk_lean(shape: LowerBodyShape, neck_z: np.ndarray, pitch_down: np.ndarray) -> np.ndarray:
    """(F,) the trunk's forward lean (the module docstring): `LEAN_PER_PITCH` of the head's pitch
    down beyond `LOOK_DOWN` (the eyes and the neck take that much), and no more than a bow with
    straight legs would take the skull base down to its height (the first `KNEES_FIRST` of the drop
    left to the knees): a bow looks down, a squat keeps the head up. And at least what keeps the
    pelvis `LOWEST_PELVIS` of its standing height above the floor (kneeling, sitting back on a
    heel): a head lower than that is a bow however it looks."""
    up = shape.trunk[2]

    def lean_for(pelvis_z):  # the lean that puts the pelvis at this height (`trunk_at`)
        return np.arccos(np.clip((neck_z - pelvis_z) / up, -1.0, 1.0))

    bow = lean_for(shape.pelvis_height - KNEES_FIRST * shape.stature)
    floor = lean_for(LOWEST_PELVIS * shape.pelvis_height)
    lean = np.minimum(bow, LEAN_PER_PITCH * (pitch_down - LOOK_DOWN))
    return np.clip(np.maximum(lean, floor), 0.0, MAX_LEAN)


def trunk_at(shape: LowerBodyShape, phi: np.ndarray) -> np.ndarray:
    """(F, 3) the pelvis -> skull base vector in body axes leaned forward by `phi`: its upright
    part turned toward forward, its small rest offset forward or back kept (so the skull base only
    ever comes down as the lean grows: a turn of the whole tilted trunk first raises it)."""
    r, f, u = shape.trunk
    phi = np.asarray(phi, float)
    return np.stack([np.full_like(phi, r), f + u * np.sin(phi), u * np.cos(phi)], axis=-1)


def pelvis_under(shape: LowerBodyShape, neck: np.ndarray, heading: np.ndarray, phi: np.ndarray,
                 toward: np.ndarray | None = None) -> np.ndarray:
    """(F, 3) the pelvis: the skull base less the trunk turned by the body's `heading` and leaned
    by `phi` toward the heading `toward` (F,) (where the head looks: a bow bends toward what the
    eyes look down at, which a quick turn reaches before the smoothed body heading does), the
    body's own when None."""
    v = trunk_at(shape, phi)
    if toward is None:
        return neck - np.einsum("fij,fj->fi", body_axes(heading), v)
    bow = np.zeros_like(v)
    bow[:, 1] = shape.trunk[2] * np.sin(phi)  # the lean's part of `trunk_at`, along `toward`
    return (neck - np.einsum("fij,fj->fi", body_axes(heading), v - bow)
            - np.einsum("fij,fj->fi", body_axes(toward), bow))


def bow_follow(under: np.ndarray, slow: np.ndarray, bow) -> np.ndarray:
    """(F, 2) a bow's pelvis over the floor: `bow` (F,) of the way from where the trunk puts it under
    the head (`under`, `pelvis_under`) to where a whole bow's (`bowed`, weight 1) puts it followed
    slowly (`slow`, `BOW_FOLLOW_S`; offline both ways, live forward only from the frame the
    bow is told). Its
    legs straight and planted, a bow's hips stay over the standing foot while the head spots and
    swings ahead (the CMU dancer's head turns ~30 degrees ahead of its trunk as it spins): the trunk's
    0.5 m reach turned with the head swung the pelvis at 2 m/s, its planted foot out of reach
    on its toes (heel.py)."""
    w = np.asarray(bow, float)[..., None]
    return under + w * (slow - under)


def pelvis_rotation(heading: np.ndarray, phi: np.ndarray, bow=0.0) -> np.ndarray:
    """(F, 3, 3) the estimated pelvis device's rotation: the body's axes tilted by its share, in a
    bow (`bow` (F,) its weight) all the lean past `BOW_SPINE` (a hinge bends at the hips)."""
    tilt = PELVIS_SHARE * phi
    return body_axes(heading) @ lean(tilt + bow * np.maximum(phi - BOW_SPINE - tilt, 0.0))


def lift_of(shape: LowerBodyShape, pelvis_z: np.ndarray) -> np.ndarray:
    return np.maximum(pelvis_z - shape.pelvis_height - LIFT_FROM * shape.stature, 0.0)


def gaussian(x: np.ndarray, sigma_frames: float) -> np.ndarray:
    """`x` (F, ...) smoothed along frames by a Gaussian, the ends held (zero phase)."""
    if sigma_frames < 0.5 or len(x) < 3:
        return x.copy()
    half = int(np.ceil(3 * sigma_frames))
    k = np.exp(-0.5 * (np.arange(-half, half + 1) / sigma_frames) ** 2)
    k /= k.sum()
    pad = np.concatenate([np.repeat(x[:1], half, 0), x, np.repeat(x[-1:], half, 0)])
    flat = pad.reshape(len(pad), -1)
    out = np.stack([np.convolve(flat[:, c], k, mode="valid") for c in range(flat.shape[1])], axis=1)
    return out.reshape(x.shape)


def offline_path(shape: LowerBodyShape, time: np.ndarray, head_pos: np.ndarray, head_rot: np.ndarray,
                 seat_height: float | None = None) -> BodyPath:
    """The whole take's body path, looking both ways in time."""
    fps = (len(time) - 1) / max(time[-1] - time[0], 1e-9) if len(time) > 1 else 90.0
    neck, head_heading, pitch = neck_and_head(shape, head_pos, head_rot)
    heading = clamp_heading(gaussian(head_heading, HEADING_SMOOTH_S * fps), head_heading)
    if seat_height is None:
        squat = trunk_lean(shape, neck[:, 2], pitch)
        bow = bow_weight(shape, neck, pitch, squat)
        phi = bowed(shape, neck[:, 2], squat, bow)
        pelvis = pelvis_under(shape, neck, heading, phi, head_heading)
        if bow.any():
            hinged = pelvis_under(shape, neck, heading, bowed(shape, neck[:, 2], squat, 1.0), head_heading)[:, :2]
            pelvis[:, :2] = bow_follow(pelvis[:, :2], gaussian(hinged, BOW_FOLLOW_S * fps), bow)
    else:
        bow = 0.0
        pelvis, phi = _seated(shape, neck, heading, seat_height, lambda x: gaussian(x, SEAT_FOLLOW_S * fps))
    velocity, centre, centre_velocity = over_the_floor(shape, time, neck, pelvis, on_pelvis=seat_height is not None)
    lift = lift_of(shape, pelvis[:, 2]) if seat_height is None else np.zeros(len(time))
    return BodyPath(neck, heading, phi, pelvis, pelvis_rotation(heading, phi, bow), lift, velocity, centre,
                    centre_velocity)


def _seated(shape: LowerBodyShape, neck: np.ndarray, heading: np.ndarray, seat_height: float, follow):
    """(pelvis (F, 3), lean (F,)) on a seat `seat_height` high: the pelvis where the upright trunk
    would put it, followed slowly (`follow`), at the seat's height; the lean the trunk then has."""
    upright = pelvis_under(shape, neck, heading, np.zeros(len(neck)))
    pelvis = follow(upright)
    pelvis[:, 2] = seat_height + HIP_ABOVE_SEAT * shape.stature
    up = neck - pelvis
    forward = body_axes(heading)[:, :, 1]
    phi = np.arctan2(np.einsum("fi,fi->f", up, forward), up[:, 2]) - np.arctan2(shape.trunk[1], shape.trunk[2])
    return pelvis, np.clip(phi, 0.0, MAX_LEAN)


class LivePath:
    """The body path one frame at a time, from the frames so far only (the module docstring:
    forward smoothing)."""

    def __init__(self, shape: LowerBodyShape, seat_height: float | None = None):
        self.shape, self.seat_height = shape, seat_height
        self._heading = None
        self._seat = None
        self._last = None  # (time, pelvis xy, mass centre xy)
        self._velocity = np.zeros(2)
        self._centre_velocity = np.zeros(2)
        self._upright = None  # the skull base over the floor at the last frame before the episode (`bow_weight`)
        self._bow = 0.0  # the episode's bow weight so far
        self._slow = None  # the pelvis over the floor followed by `BOW_FOLLOW_S` (`bow_follow`)

    def _bow_so_far(self, neck: np.ndarray, pitch: np.ndarray, squat: np.ndarray) -> float:
        """`bow_weight` forward only: the most sure frame of the episode so far."""
        if not leaning(self.shape, neck[2:3], pitch)[0]:
            self._upright, self._bow = neck[:2].copy(), 0.0
            return 0.0
        if self._upright is None:  # the stream begins leaning: its first frame stands for upright
            self._upright = neck[:2].copy()
        travel = np.linalg.norm(neck[:2] - self._upright)[None]
        tell = hinge_tell(self.shape, travel, pitch, squat, hinge_lean(self.shape, neck[2:3]))
        self._bow = max(self._bow, float(tell[0]))
        return self._bow * float(depth(self.shape, neck[2:3], pitch)[0])

    def step(self, t: float, head_pos: np.ndarray, head_rot: np.ndarray) -> BodyPath:
        shape = self.shape
        neck, head_heading, pitch = neck_and_head(shape, head_pos[None], head_rot[None])
        dt = 0.0 if self._last is None else max(t - self._last[0], 1e-6)
        if self._heading is None:
            heading = head_heading
        else:
            a = 1.0 - np.exp(-dt / HEADING_SMOOTH_S)
            heading = self._heading + a * wrap(head_heading - self._heading)
        heading = clamp_heading(heading, head_heading)
        self._heading = heading
        bow = 0.0
        if self.seat_height is None:
            squat = trunk_lean(shape, neck[:, 2], pitch)
            bow = self._bow_so_far(neck[0], pitch, squat)
            phi = bowed(shape, neck[:, 2], squat, bow)
            pelvis = pelvis_under(shape, neck, heading, phi, head_heading)
            if bow > 0.0:  # followed from where the whole bow puts it when the bow is told
                hinged = pelvis_under(shape, neck, heading, bowed(shape, neck[:, 2], squat, 1.0), head_heading)[0, :2]
                a = 1.0 if self._slow is None else 1.0 - np.exp(-dt / BOW_FOLLOW_S)
                self._slow = hinged if self._slow is None else self._slow + a * (hinged - self._slow)
                pelvis[0, :2] = bow_follow(pelvis[0, :2], self._slow, bow)
            else:
                self._slow = None
        else:
            def follow(upright, _self=self, _dt=dt):
                if _self._seat is None:
                    _self._seat = upright[0].copy()
                else:
                    _self._seat += (1.0 - np.exp(-_dt / SEAT_FOLLOW_S)) * (upright[0] - _self._seat)
                return _self._seat[None].copy()
            pelvis, phi = _seated(shape, neck, heading, self.seat_height, follow)
        centre = pelvis[0, :2].copy() if self.seat_height is not None else centre_of(shape, neck[0], pelvis[0])
        if self._last is not None:
            a = 1.0 - np.exp(-dt / VELOCITY_SMOOTH_S)
            self._velocity = self._velocity + a * ((pelvis[0, :2] - self._last[1]) / dt - self._velocity)
            self._centre_velocity = self._centre_velocity + a * ((centre - self._last[2]) / dt - self._centre_velocity)
        self._last = (t, pelvis[0, :2].copy(), centre)
        lift = lift_of(shape, pelvis[:, 2]) if self.seat_height is None else np.zeros(1)
        return BodyPath(neck, heading, phi, pelvis, pelvis_rotation(heading, phi, bow), lift,
                        self._velocity[None].copy(),
                        centre[None], self._centre_velocity[None].copy())


def tracked_path(shape: LowerBodyShape, time: np.ndarray, tracker_pos: np.ndarray, tracker_rot: np.ndarray,
                 pelvis_local: np.ndarray, tracker_ref: np.ndarray, velocity=None) -> BodyPath:
    """The body path of a kit with a pelvis tracker (only the feet estimated): the pelvis joint
    rigid on it, the heading its turn about the vertical since the reference. `velocity`: the
    pelvis's over the floor when known (live), else from the frames (offline, both ways)."""
    pelvis = tracker_pos + np.einsum("fij,j->fi", tracker_rot, pelvis_local)
    rel = tf.matrix_to_quat(tracker_rot @ tracker_ref.T)
    heading = np.unwrap(shape.heading0 + 2.0 * np.arctan2(rel[:, 3], rel[:, 0]))
    if velocity is None:
        fps = (len(time) - 1) / max(time[-1] - time[0], 1e-9) if len(time) > 1 else 90.0
        grad = np.gradient(pelvis[:, :2], time, axis=0) if len(time) > 1 else np.zeros((len(time), 2))
        velocity = gaussian(grad, VELOCITY_SMOOTH_S * fps)
    zero = np.zeros(len(time))
    return BodyPath(pelvis + np.einsum("fij,j->fi", body_axes(heading), shape.trunk), heading, zero, pelvis,
                    tracker_rot, lift_of(shape, pelvis[:, 2]), velocity)
