"""A whole session of a performer (`performer.Performer`): the calibration steps of FORMATS.md §2.4
(no touches; with `touches`, then a six-device user's controller pivots and touches, `touching`)
then the clip itself as the `motion`, with smooth transitions, placed anywhere in the play area and
facing any way.

Each step is performed by the clip's skeleton the way a person does it, never perfectly: the
body sways, the limb that should stay still wanders a few degrees, the straight limb of a swing
bends a little.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import rot, touching
from .performer import FORWARD, SIDES, TRUTH_JOINTS, Performer, Pose, _smooth_noise, hanging

STEP_SECONDS = {"tpose": 3.0, "stand": 2.5, "flex_elbow": 5.0, "swing_shoulder": 6.0, "flex_knee": 5.0,
                "swing_hip": 6.0}
TRANSITION_S = 1.0
SEGMENT_MARGIN_S = 0.4  # a step's segment leaves out the settling at its ends


@dataclass
class Session:
    fps: float
    G: np.ndarray  # (F, J, 3, 3) world rotations, lab frame
    P: np.ndarray  # (F, J, 3) world positions
    truth: np.ndarray  # (F, len(TRUTH_JOINTS), 3)
    segments: list[dict]
    motion: tuple[int, int]  # frame range of the clip
    stance: dict[str, np.ndarray]  # side -> (F,) bool, the source's stance (False outside the clip)
    yaw: float
    origin: np.ndarray  # (3,) where the session's body frame sits in the lab
    notes: dict = field(default_factory=dict)

    @property
    def frame_count(self) -> int:
        return self.G.shape[0]


def _cycle(n, fps, freq, lo, hi, phase=0.0):
    t = np.arange(n) / fps
    return lo + (hi - lo) * (0.5 - 0.5 * np.cos(2 * np.pi * freq * t + phase))


def calibration_poses(perf: Performer, rng, fps: float, touches: bool = False,
                      notes: dict | None = None) -> list[tuple]:
    """The calibration steps in the body frame: [(step, pose)]; with `touches`, then the pivots and
    touches of a six-device user (`touching`: [(step, pose, segment fields)]; the controller tips
    in the hands' frames go to `notes["controller_tip_hand"]`)."""
    h = perf.standing_root_height()
    lift = np.array([0.0, 0.0, h])
    out = []
    stance = rng.uniform(0.0, 4.0)  # feet a little apart, not under the hips
    bends = (rng.uniform(2.0, 10.0), rng.uniform(0.0, 6.0))  # nobody locks elbows and knees straight

    def n_of(step):
        return int(round(STEP_SECONDS[step] * fps))

    def arm_down(n, s, rng):
        d, f = hanging(np.radians(8.0) + _smooth_noise(rng, n, fps, 1, np.radians(2.0))[:, 0],
                        np.full(n, np.radians(90.0)), s, FORWARD)
        return d, f, np.radians(10.0) + _smooth_noise(rng, n, fps, 1, np.radians(3.0))[:, 0]

    n = n_of("tpose")
    out.append(("tpose", perf.pose(n, root_offset=lift, rng=rng, stance_deg=stance, bends_deg=bends)))
    n = n_of("stand")
    out.append(("stand", perf.pose(n, arm={s: arm_down(n, s, rng) for s in SIDES}, root_offset=lift, rng=rng,
                                   stance_deg=stance, bends_deg=bends)))
    for s in SIDES:
        n = n_of("flex_elbow")
        wob = _smooth_noise(rng, n, fps, 2, np.radians(3.0))
        d, f = hanging(np.radians(15.0) + wob[:, 0], np.radians(25.0) + wob[:, 1], s, FORWARD)
        angle = _cycle(n, fps, 0.8, np.radians(12.0), np.radians(125.0))
        arms = {s: (d, f, angle), ("r" if s == "l" else "l"): arm_down(n, "r" if s == "l" else "l", rng)}
        out.append((f"flex_elbow_{s}", perf.pose(n, arm=arms, root_offset=lift, rng=rng)))
    for s in SIDES:
        n = n_of("swing_shoulder")
        t = np.arange(n) / fps
        theta = np.radians(45.0 + 30.0 * np.sin(2 * np.pi * 0.35 * t))
        alpha = np.radians(30.0 + 60.0 * np.sin(2 * np.pi * 0.23 * t + 1.0))
        d, f = hanging(theta, alpha, s, FORWARD)
        bend = np.radians(10.0) + _smooth_noise(rng, n, fps, 1, np.radians(4.0))[:, 0]
        arms = {s: (d, f, bend), ("r" if s == "l" else "l"): arm_down(n, "r" if s == "l" else "l", rng)}
        out.append((f"swing_shoulder_{s}", perf.pose(n, arm=arms, root_offset=lift, rng=rng)))
    for s in SIDES:
        n = n_of("flex_knee")
        wob = _smooth_noise(rng, n, fps, 2, np.radians(3.0))
        d, f = hanging(np.radians(20.0) + wob[:, 0], wob[:, 1], s, -FORWARD)
        angle = _cycle(n, fps, 0.6, np.radians(8.0), np.radians(100.0))
        arms = {a: arm_down(n, a, rng) for a in SIDES}
        out.append((f"flex_knee_{s}", perf.pose(n, arm=arms, leg={s: (d, f, angle)}, root_offset=lift, rng=rng)))
    for s in SIDES:
        n = n_of("swing_hip")
        t = np.arange(n) / fps
        theta = np.radians(25.0 + 15.0 * np.sin(2 * np.pi * 0.5 * t))
        alpha = np.radians(60.0 + 100.0 * np.sin(2 * np.pi * 0.33 * t + 0.5))
        d, f = hanging(theta, alpha, s, -FORWARD)
        bend = np.radians(8.0) + _smooth_noise(rng, n, fps, 1, np.radians(4.0))[:, 0]
        arms = {a: arm_down(n, a, rng) for a in SIDES}
        out.append((f"swing_hip_{s}", perf.pose(n, arm=arms, leg={s: (d, f, bend)}, root_offset=lift, rng=rng)))
    if touches:
        tips = {s: touching.tip_in_hand(perf, s, rng) for s in SIDES}
        out += touching.touch_poses(perf, rng, fps, lift, stance, bends, tips)
        if notes is not None:
            notes["controller_tip_hand"] = tips
    return out


def _transition(perf: Performer, a: Pose, b: Pose, n: int) -> Pose:
    """From a's last frame to b's first: every joint's world rotation along its geodesic, the root
    along a line, eased in and out."""
    t = np.linspace(0.0, 1.0, n + 2)[1:-1]
    e = t * t * (3 - 2 * t)
    J = a.G.shape[1]
    G = rot.interpolate(np.broadcast_to(a.G[-1], (n, J, 3, 3)), np.broadcast_to(b.G[0], (n, J, 3, 3)),
                        np.broadcast_to(e[:, None], (n, J)))
    root = a.root[-1] + e[:, None] * (b.root[0] - a.root[-1])
    return Pose(G, root)


def build_session(perf: Performer, *, seed: int = 0, yaw: float | None = None, origin=None,
                  fps: float | None = None, touches: bool = False) -> Session:
    """The calibration steps then the clip, turned by `yaw` (radians about +Z; default random) and
    moved to `origin` (default random in a 3 m x 3 m play area). At yaw 0 the T-pose faces -Y;
    at yaw pi it faces +Y, FORMATS.md's forward (SteamVR's -Z). With `touches`, the steps end with
    the six-device user's controller pivots and touches (`touching`): the steps before them and
    the session's facing, place and mountings are those of the same seed without."""
    rng = np.random.default_rng(seed)
    fps = perf.clip.fps if fps is None else fps
    if abs(fps - perf.clip.fps) > 1e-6:
        raise ValueError("resample the clip first (bvh.Clip.resampled)")
    yaw = rng.uniform(-np.pi, np.pi) if yaw is None else float(yaw)
    origin = np.append(rng.uniform(-1.5, 1.5, 2), 0.0) if origin is None else np.asarray(origin, float)
    clip = perf.clip
    # The calibration stands at the body frame's origin facing -Y; the clip is brought there
    # (its first heading turned to -Y, its first position over the origin).
    h0 = perf.heading[0]
    start = np.array([clip.root[0, 0], clip.root[0, 1], 0.0])
    notes = {"truth_joints": list(TRUTH_JOINTS), "clip": clip.name}
    pieces = [p if len(p) == 3 else (*p, None) for p in calibration_poses(perf, rng, fps, touches, notes)]
    clip_pose = Pose(np.einsum("ji,fkjl->fkil", h0, perf._clip_G), (clip.root - start) @ h0)
    pieces.append(("motion", clip_pose, None))
    n_tr = int(round(TRANSITION_S * fps))
    poses, segments, t0 = [], [], 0
    motion = (0, 0)
    for k, (step, pose, fields) in enumerate(pieces):
        if k:
            tr = _transition(perf, pieces[k - 1][1], pose, n_tr)
            poses.append(tr)
            t0 += len(tr)
        n = len(pose)
        if step == "touch":  # the hold, and a little of the hand's coming and going
            margin = -int(round(touching.TOUCH_SEGMENT_PAD_S * fps))
        else:
            margin = 0 if step == "motion" else int(round(SEGMENT_MARGIN_S * fps))
        segments.append({"step": step, "start": (t0 + margin) / fps, "end": (t0 + n - 1 - margin) / fps,
                         **(fields or {})})
        if step == "motion":
            motion = (t0, t0 + n)
        poses.append(pose)
        t0 += n
    G = np.concatenate([p.G for p in poses])
    root = np.concatenate([p.root for p in poses])
    P = perf.positions(Pose(G, root))
    # Place the session: turn about the vertical through the lab origin, then move.
    Y = rot.yaw(yaw)
    G = np.einsum("ij,fkjl->fkil", Y, G)
    P = P @ Y.T + origin
    stance = {}
    for s in SIDES:
        st = np.zeros(len(G), bool)
        st[motion[0]:motion[1]] = perf.stance[s]
        stance[s] = st
    return Session(fps, G, P, perf.truth_positions(P), segments, motion, stance, yaw, origin, notes)
