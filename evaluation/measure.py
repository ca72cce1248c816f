"""Figures of a retargeted animation against the source clip it was recorded from (lab frame =
the engine's internal frame: Z up, metres, floor at z = 0). Numpy only; every input is an array
with a leading frame axis restricted by the caller to the frames that count (the clip).

- joint-centre error: a calibrated joint's world position at the reference time vs the clip's;
- sole height during stance: the avatar's lowest sole point in the source's stance frames;
- hip-line angle: the horizontal angle between the avatar's hip line and the source's;
- the floor a clip walks on: how much it rises along the walk (a capture's floor is not always
  level: the CMU walk 02_01's rises 4-5 cm over its 3.6 m).
- the pelvis's error split in the clip's body frame: its constant forward / left / up, the motion
  about it, and what its p95 tail is (the trunk's lean the clip has there beyond ours).

The figures a bake's review also flags (foot slide, wrist / ankle acceleration, when a source's
foot is down, the limb ratios) are the engine's, `bodycal_addon/output/metrics.py`, which the
benchmarks call: one definition each (this package itself imports nothing of the engine).
"""

from __future__ import annotations

import numpy as np


def joint_errors_mm(model_joints: dict, truth_names: list[str], truth_at_ref: np.ndarray) -> dict[str, float]:
    out = {}
    for k, name in enumerate(truth_names):
        if name in model_joints:
            out[name] = round(float(np.linalg.norm(np.asarray(model_joints[name]) - truth_at_ref[k])) * 1000, 1)
    return out


def sole_height_mm(sole_points: np.ndarray, stance: np.ndarray) -> dict:
    """sole_points (F, K, 3); stance (F,) bool."""
    low = sole_points[..., 2].min(axis=-1)[stance] * 1000
    if low.size == 0:
        return {"median": None, "worst": None}
    return {"median": round(float(np.median(low)), 1), "worst": round(float(low.min()), 1),
            "p5": round(float(np.percentile(low, 5)), 1)}


def hip_line_deg(avatar_l, avatar_r, source_l, source_r) -> dict:
    def yaw(v):
        return np.arctan2(v[:, 1], v[:, 0])

    d = yaw(avatar_l - avatar_r) - yaw(source_l - source_r)
    d = np.degrees(np.abs((d + np.pi) % (2 * np.pi) - np.pi))
    return {"p95": round(float(np.percentile(d, 95)), 1), "max": round(float(d.max()), 1)}


def landings(foot: np.ndarray, fps: float, speed: float = 0.3, hold_s: float = 0.12) -> int:
    """How many times a foot lands over a clip: the stances (its points, (F, 3) or (F, K, 3): the
    ankle and the ball, all slower than `speed` m/s over the floor for at least `hold_s`) that
    begin after the clip's first frame. The same rule for the source and a retargeted body, so the
    two counts compare."""
    return int(sum(a > 0 for a, _ in _stances(foot.reshape(len(foot), -1, 3), fps, speed, hold_s)))  # a JSON number


def _stances(foot: np.ndarray, fps: float, speed: float, hold_s: float) -> list[tuple[int, int]]:
    """[(start, stop)] the frames a foot's points (F, K, 3) all stay slower than `speed` m/s over the
    floor, for at least `hold_s` (`landings`' rule)."""
    v = np.linalg.norm(np.gradient(foot[..., :2], axis=0), axis=-1).max(axis=-1) * fps
    slow = np.concatenate([[0], (v < speed).astype(int), [0]])
    edges = np.flatnonzero(np.diff(slow))
    return [(a, b) for a, b in zip(edges[::2], edges[1::2], strict=True) if b - a >= hold_s * fps]


def floor_along(feet: list[np.ndarray], fps: float, speed: float = 0.3, hold_s: float = 0.12):
    """(axis (2,), slope, extent): the floor under a walk, from each foot's points (F, K, 3), the last
    of them the lowest (the ball): the lowest of that point in every stance (the `landings` rule),
    its height fitted against the distance along the stances' main direction over the floor
    (`axis`): `slope` metres up per metre along `axis`, `extent` the metres the stances span along
    it. (None, 0.0, 0.0) with fewer than three stances."""
    lows = []
    for foot in feet:
        foot = foot.reshape(len(foot), -1, 3)
        for a, b in _stances(foot, fps, speed, hold_s):
            lows.append(foot[a + int(np.argmin(foot[a:b, -1, 2])), -1])
    if len(lows) < 3:
        return None, 0.0, 0.0
    lows = np.array(lows)
    xy = lows[:, :2] - lows[:, :2].mean(axis=0)
    axis = np.linalg.svd(xy, full_matrices=False)[2][0]
    along = xy @ axis
    slope = float(np.polyfit(along, lows[:, 2], 1)[0])
    if slope < 0.0:  # the axis pointing up the floor: the slope reads as a rise
        axis, along, slope = -axis, -along, -slope
    return axis, slope, float(np.ptp(along))


def pelvis_split(ours: dict, theirs: dict, fps: float) -> dict:
    """The pelvis's error split in the clip's body frame (forward, left, up). `ours` {pelvis,
    skull_base} and `theirs` {pelvis, skull_base, hip_l, hip_r, ankle_l, ankle_r, toe_l, toe_r}:
    (F, 3) joint centres. The frame: the clip's hips' line over the floor, forward the way its toes
    point. Gives the constant part (the medians, mm: a calibration's table against the clip's
    skeleton, or a posture held all through), the motion about it (median and p95 of what is left,
    mm), and what the frames of the tail (the error at or past its p95) are: how much further
    forward the clip's trunk leans there than ours (degrees from the vertical, pelvis to skull base,
    past a right angle in a deep bow) and how much further to its left it tilts (degrees out of
    the plane across its left), the share of them moving (the clip's pelvis over 0.3 m/s) and
    turning (its hips' line over 60 degrees/s). And the error split by its source (`by_source`,
    median and p95 mm): the pelvis our skull base and our trunk would give with the clip's trunk
    length (only the direction ours: what the path model's lean, tilt and turn leave) and with the
    clip's trunk direction (only the length ours: what the calibration's proportions leave)."""
    T = {k: np.asarray(v, float) for k, v in theirs.items()}
    left = T["hip_l"] - T["hip_r"]
    left[:, 2] = 0.0
    left /= np.maximum(np.linalg.norm(left, axis=1, keepdims=True), 1e-9)
    forward = np.stack([-left[:, 1], left[:, 0], np.zeros(len(left))], axis=1)
    toes = (T["toe_l"] - T["ankle_l"]) + (T["toe_r"] - T["ankle_r"])
    if np.median(np.einsum("fi,fi->f", toes, forward)) < 0:
        forward = -forward
    d = np.asarray(ours["pelvis"], float) - T["pelvis"]
    parts = np.stack([np.einsum("fi,fi->f", d, forward), np.einsum("fi,fi->f", d, left), d[:, 2]], axis=1)
    offset = np.median(parts, axis=0)
    motion = np.linalg.norm(parts - offset, axis=1) * 1000
    e = np.linalg.norm(d, axis=1)
    tail = e >= np.percentile(e, 95)

    def lean(trunk):
        return np.degrees(np.arctan2(np.einsum("fi,fi->f", trunk, forward), trunk[:, 2]))

    def tilt(trunk):
        return np.degrees(np.arcsin(np.clip(np.einsum("fi,fi->f", trunk, left)
                                            / np.maximum(np.linalg.norm(trunk, axis=1), 1e-9), -1.0, 1.0)))

    theirs_trunk = T["skull_base"] - T["pelvis"]
    ours_trunk = np.asarray(ours["skull_base"], float) - np.asarray(ours["pelvis"], float)
    speed = np.linalg.norm(np.gradient(T["pelvis"][:, :2], axis=0), axis=1) * fps
    turn = np.abs(np.degrees(np.gradient(np.unwrap(np.arctan2(forward[:, 1], forward[:, 0]))))) * fps
    lean_missed = (lean(theirs_trunk) - lean(ours_trunk))[tail]
    tilt_missed = (tilt(theirs_trunk) - tilt(ours_trunk))[tail]
    ours_length = np.linalg.norm(ours_trunk, axis=1, keepdims=True)
    theirs_length = np.linalg.norm(theirs_trunk, axis=1, keepdims=True)

    def stats(trunk):  # the pelvis our skull base and this trunk give, against the clip's (mm)
        x = np.linalg.norm(np.asarray(ours["skull_base"], float) - trunk - T["pelvis"], axis=1) * 1000
        return {"median": round(float(np.median(x)), 1), "p95": round(float(np.percentile(x, 95)), 1)}

    by_source = {"path_only": stats(ours_trunk / np.maximum(ours_length, 1e-9) * theirs_length),
                 "calibration_only": stats(theirs_trunk / np.maximum(theirs_length, 1e-9) * ours_length)}
    return {"offset_mm": {k: round(float(v) * 1000, 1) for k, v in zip(("forward", "left", "up"), offset)},
            "motion_mm": {"median": round(float(np.median(motion)), 1),
                          "p95": round(float(np.percentile(motion, 95)), 1)},
            "tail": {"frames": int(tail.sum()),
                     "lean_forward_missed_deg": round(float(np.median(lean_missed)), 1),
                     "tilt_left_missed_deg": round(float(np.median(tilt_missed)), 1),
                     "moving_share": round(float(np.mean(speed[tail] > 0.3)), 2),
                     "turning_share": round(float(np.mean(turn[tail] > 60.0)), 2)},
            "by_source": by_source}
