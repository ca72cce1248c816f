"""Shared state of one user calibration: device poses (vectorised over frames), the reference
time, robust reference poses and the per-step report. Each step module reads a `Session` and
writes what it measured into its `State`; `calibrate_user` assembles the body model from it."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core import transforms as tf
from ..core.errors import BodyCalError
from ..core.geometry import robust_mean, running_median
from ..recording.led_gloves import led_hand_frame
from ..recording.model import ROLES_LIST, Recording, Segment

REF_HALF_WINDOW = 0.1  # s: device poses at the reference time are robust means over this window
SPIKE_WINDOW_S = 0.07  # running median window for glitch detection
SPIKE_M = 0.015  # a device farther than this from its running median is a glitch frame
MIN_STEP_FRAMES = 20  # a motion step (flex / swing) needs at least this many tracked frames


def other(side: str) -> str:
    return "r" if side == "l" else "l"


def side_of(name: str) -> str | None:
    if name.endswith("_l"):
        return "l"
    if name.endswith("_r"):
        return "r"
    return None


def glitch_frames(pos: np.ndarray, valid: np.ndarray, fps: float) -> np.ndarray:
    """Frames where a device jumps away from its own running median (tracking glitches). A smooth
    trajectory is its own running median on monotonic stretches, so only isolated jumps (and
    violent turns) stand out; they are dropped before any fit, the 2-sigma passes handle the rest."""
    w = max(3, int(round(SPIKE_WINDOW_S * max(fps, 1.0))) | 1)
    idx = np.nonzero(valid)[0]
    out = np.zeros(len(pos), bool)
    if len(idx) < w:
        return out
    p = pos[idx]
    out[idx] = np.linalg.norm(p - running_median(p, w), axis=1) > SPIKE_M
    return out


STANDING_BAND_M = 0.03  # the HMD within this of its standing height ...
STANDING_SPEED = 0.15  # m/s ... and this slow: the performer stands still and straight


def standing_moment(time: np.ndarray, head: np.ndarray, valid: np.ndarray) -> int | None:
    """The frame nearest the middle of a recording without a tpose or stand step at which the
    performer stands still and straight: the HMD within `STANDING_BAND_M` of its standing height
    (the 90th percentile of its height: a take of people who crouch, sit or bow now and then
    stands most of the time) and moving slower than `STANDING_SPEED`. None: never so."""
    idx = np.nonzero(valid)[0]
    if len(idx) < 3:
        return None
    z = head[idx, 2]
    speed = np.linalg.norm(np.gradient(head[idx], time[idx], axis=0), axis=1)
    ok = (np.abs(z - np.percentile(z, 90)) < STANDING_BAND_M) & (speed < STANDING_SPEED)
    if not ok.any():
        return None
    middle = 0.5 * (time[0] + time[-1])
    cand = idx[ok]
    return int(cand[np.argmin(np.abs(time[cand] - middle))])


@dataclass
class State:
    """What the steps measured. Positions are local to a tracker role unless named `world`."""

    local: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)  # joint -> {role: local}
    world: dict[str, np.ndarray] = field(default_factory=dict)  # joint -> world at the reference time
    radii: dict[str, float] = field(default_factory=dict)  # "wrist_l", "elbow_l", "finger_index_l", ...
    hinge_right: dict[str, tuple[str, np.ndarray]] = field(default_factory=dict)  # bone -> (role, right local)
    palm_planes: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)  # hand_s -> (point, normal)
    palm_points: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)  # side -> {palm_k_s: local hand}
    sole_points: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)  # side -> {sole_k_s: local foot}
    jaw: dict[str, np.ndarray] = field(default_factory=dict)  # local to head (HMD)
    skull: tuple[np.ndarray, float] | None = None  # centre local to head (HMD), radius
    torso_world: dict[str, np.ndarray] = field(default_factory=dict)  # torso points, world at reference
    extra: dict = field(default_factory=dict)

    def set_local(self, joint: str, role: str, local: np.ndarray):
        self.local.setdefault(joint, {})[role] = np.asarray(local, float)


class Session:
    """A recording prepared for calibration."""

    def __init__(self, rec: Recording, *, robust: bool = True, despike: bool = True, anchor: str = "rigid"):
        self.rec = rec
        self.source = rec.source or rec.name
        self.robust = robust
        self.despike = despike
        self.anchor = anchor  # "rigid" (limbs.py decision) or "sphere" (Delahaye 2023 as written)
        self.spikes: dict[str, int] = {}
        self._poses: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self._ref: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self.quality: dict[str, dict] = {}
        self.steps_used: list[str] = []
        self.defaulted: dict[str, str] = {}
        self.missing: list[str] = []
        self.warnings: list[str] = []  # steps left out and why, one line each
        # estimated devices (estimated_devices.py): role -> reference pose (their poses in _poses)
        self.estimated: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        self.reference_time, self.reference_step = self._reference_time()

    # --- devices -------------------------------------------------------------------------------

    def has(self, role: str) -> bool:
        if self.rec.has_role(role) or role in self.estimated:
            return True
        if role.startswith("hand_"):
            s = role[-1]
            return all(f"hand_led{k}_{s}" in self.rec.marker_names for k in (1, 2, 3))
        return False

    def kind(self, role: str) -> str | None:
        if role in self.estimated:
            return "estimated"
        for d in self.rec.devices:
            if d.role == role:
                return d.kind
        return "led_glove" if self.has(role) else None

    def pose(self, role: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(positions (F, 3), rotations (F, 4), valid (F,)) of a tracker role; hands without a
        device pose are built from the glove's three LEDs (synthetic_api / FORMATS.md §2.1)."""
        if role not in self._poses:
            if self.rec.has_role(role):
                pos, rot, valid = self.rec.pose(role)
            elif self.has(role):
                pos, rot, valid = self._led_hand(role[-1])
            else:
                raise BodyCalError(f"the recording has no '{role}' tracker", source=self.source,
                                   hint=f"assign the role '{role}' to a device ({ROLES_LIST}) or record "
                                        "without this step")
            if self.despike:
                spikes = glitch_frames(pos, valid, self.rec.fps)
                self.spikes[role] = int(spikes.sum())
                valid = valid & ~spikes
            self._poses[role] = (pos, rot, valid)
        return self._poses[role]

    def _led_hand(self, s: str):
        leds = [self.rec.marker(f"hand_led{k}_{s}") for k in (1, 2, 3)]
        origin, q, ok = led_hand_frame(*(p for p, _ in leds))
        ok = ok & leds[0][1] & leds[1][1] & leds[2][1]
        return origin, q, ok

    # --- time ----------------------------------------------------------------------------------

    def _reference_time(self) -> tuple[float, str]:
        """FORMATS.md §3: the middle of the tpose segment, else of stand, else the standing moment
        nearest the middle of the recording (`standing_moment`)."""
        for step in ("tpose", "stand"):
            segs = self.rec.segments_of(step)
            if segs:
                return 0.5 * (segs[0].start + segs[0].end), step
        t = self.rec.time
        middle = float(0.5 * (t[0] + t[-1]))
        if self.rec.has_role("head"):
            pos, _, valid = self.rec.pose("head")
            k = standing_moment(t, pos, valid)
            if k is not None:
                return float(t[k]), "standing moment"
        return middle, "middle of the recording"

    def frames(self, segs: list[Segment]) -> np.ndarray:
        if not segs:
            return np.zeros(0, int)
        return np.unique(np.concatenate([self.rec.frames(s.start, s.end) for s in segs]))

    def window(self, t: float, half: float = REF_HALF_WINDOW) -> np.ndarray:
        idx = self.rec.frames(t - half, t + half)
        if len(idx) < 3:
            centre = int(np.clip(np.searchsorted(self.rec.time, t), 0, self.rec.frame_count - 1))
            idx = np.arange(max(centre - 1, 0), min(centre + 2, self.rec.frame_count))
        return idx

    def pose_at(self, role: str, t: float, half: float = REF_HALF_WINDOW) -> tuple[np.ndarray, np.ndarray]:
        """Robust pose of a role around time t: the frames whose position is within 2 cm (or three
        times the typical spread) of the window's mean and whose rotation is within 10 degrees of
        the mean rotation (outlier frames dropped), positions averaged, quaternions averaged after
        aligning their signs. Means, not coordinate-wise medians: the reference pose must turn and
        move with the recording (a median per axis does not, by a tenth of a millimetre)."""
        pos, rot, valid = self.pose(role)
        idx = self.window(t, half)
        idx = idx[valid[idx]]
        if len(idx) == 0:
            idx = np.nonzero(valid)[0]
            if len(idx) == 0:
                raise BodyCalError(f"the '{role}' tracker is never tracked", source=self.source)
            idx = idx[np.argsort(np.abs(self.rec.time[idx] - t))[:5]]
        p, q = pos[idx], rot[idx]
        d = np.linalg.norm(p - p.mean(axis=0), axis=1)
        keep = d <= max(0.02, 3.0 * np.median(d))
        p, q = p[keep], q[keep]
        q = np.where((q @ q[0])[:, None] < 0, -q, q)
        # rotation outliers: keep quaternions within 10 degrees of the mean rotation
        qm = tf.normalize(q.mean(axis=0))
        close = tf.quat_angle(tf.quat_mul(tf.quat_conj(qm), q)) < np.radians(10)
        if close.any():
            p, q = p[close], q[close]
        return p.mean(axis=0), tf.quat_normalize(q.mean(axis=0))

    def estimate(self, role: str, position: np.ndarray, rotation: np.ndarray, poses: tuple) -> None:
        """Adds the estimated device `role` (estimated_devices.py): its reference pose and its poses
        (positions (F, 3), rotations (F, 4), valid (F,)) over the recording."""
        self.estimated[role] = self._ref[role] = (np.asarray(position, float), tf.quat_normalize(rotation))
        self._poses[role] = poses

    def ref_pose(self, role: str) -> tuple[np.ndarray, np.ndarray]:
        """Pose at the reference time. The performer holds the reference pose (T-pose / stand)
        still, so the pose is averaged over the middle half of that segment: soft-tissue wobble
        (0.2-1.5 Hz) averages out over a second or more, not over a few frames."""
        if role not in self._ref:
            half = REF_HALF_WINDOW
            segs = self.rec.segments_of(self.reference_step) if self.reference_step in ("tpose", "stand") else []
            if segs:
                half = max(REF_HALF_WINDOW, 0.25 * (segs[0].end - segs[0].start))
            self._ref[role] = self.pose_at(role, self.reference_time, half)
        return self._ref[role]

    def to_world(self, role: str, local: np.ndarray) -> np.ndarray:
        p, q = self.ref_pose(role)
        return tf.transform_points(p, q, local)

    def to_local(self, role: str, world: np.ndarray) -> np.ndarray:
        p, q = self.ref_pose(role)
        return tf.inverse_transform_points(p, q, world)

    # --- motion steps --------------------------------------------------------------------------

    def relative_track(self, step: str, frame_role: str, point_role: str,
                       idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """`point_role`'s origin in `frame_role`'s frame over frames `idx` (tracked in both);
        returns (points (N, 3), frame indices (N,))."""
        for role in (frame_role, point_role):
            if not self.has(role):
                raise BodyCalError(f"needs the '{role}' tracker, the recording has none", source=self.source,
                                   field=step, hint=f"assign the role '{role}' to a device ({ROLES_LIST}), "
                                                    f"or drop the {step} step")
        fp, fq, fv = self.pose(frame_role)
        pp, _, pv = self.pose(point_role)
        ok = idx[fv[idx] & pv[idx]]
        if len(ok) < MIN_STEP_FRAMES:
            raise BodyCalError(f"'{frame_role}' and '{point_role}' are tracked together in only {len(ok)} of "
                               f"{len(idx)} frames, at least {MIN_STEP_FRAMES} needed", source=self.source,
                               field=step, hint="keep both trackers visible and record the step again")
        return tf.inverse_transform_points(fp[ok], fq[ok], pp[ok]), ok

    def carry(self, joint_local: np.ndarray, from_role: str, to_role: str, idx: np.ndarray) -> np.ndarray:
        """A joint fixed in `from_role`'s frame, expressed in `to_role`'s frame: robust mean over
        the frames `idx` (the joint is rigid in both when it sits between their two bones)."""

        ap, aq, av = self.pose(from_role)
        bp, bq, bv = self.pose(to_role)
        ok = idx[av[idx] & bv[idx]]
        if len(ok) == 0:
            ok = np.array([int(np.argmin(np.abs(self.rec.time - self.reference_time)))])
        w = tf.transform_points(ap[ok], aq[ok], joint_local)
        return robust_mean(tf.inverse_transform_points(bp[ok], bq[ok], w))[0]

    def use(self, step: str, quality: dict | None = None):
        if step not in self.steps_used:
            self.steps_used.append(step)
        if quality is not None:
            self.quality[step] = quality

    def default(self, what: str, how: str):
        self.defaulted[what] = how

    def warn(self, line: str):
        if line not in self.warnings:
            self.warnings.append(line)
