"""A simple VRIK-like lower body, the baseline `benchmarks/bench_three_point.py` sets beside
BodyCal's (retarget/lower_body): the pelvis at a fixed offset under the head, turned with the
head's heading (the offset of the reference time, in the head's heading frame), and each foot
planted until it is further than `STEP_DISTANCE` from its place under its hip (or turned more than
`STEP_TURN`), then moved there over `STEP_S` (one foot at a time, the further first). What a
three-point avatar system does when it does nothing more: no lean, no balance, no look-ahead, no
kneel. It fills the same estimated devices, so the rest of the pipeline is the same.
"""

from __future__ import annotations

import numpy as np

from bodycal_addon.body.bodymodel import BodyModel
from bodycal_addon.recording.model import Recording
from bodycal_addon.retarget import lower_body
from bodycal_addon.retarget.lower_body.body_path import BodyPath, neck_and_head
from bodycal_addon.retarget.lower_body.shape import LowerBodyShape, body_axes, wrap

STEP_DISTANCE = 0.25  # m
STEP_TURN = np.radians(45.0)
STEP_S = 0.35


def complete(recording: Recording, user: BodyModel) -> Recording:
    roles = lower_body.estimated_roles(recording, user)
    shape = LowerBodyShape.of(user)
    t = np.asarray(recording.time, float)
    head_pos, head_rot = lower_body.filled_pose(recording, "head")
    _, heading, _ = neck_and_head(shape, head_pos, head_rot)
    # the pelvis's offset from the HMD at the reference, in the heading frame
    tpose = user.extra["tpose"]
    ref = np.asarray(user.joints["pelvis"].world, float) - np.asarray(tpose["head"][:3], float)
    local = body_axes(shape.heading0).T @ ref
    axes = body_axes(heading)
    pelvis = head_pos + np.einsum("fij,j->fi", axes, local)
    feet, headings = _feet(shape, t, pelvis, heading)
    path = BodyPath(pelvis, heading, np.zeros(len(t)), pelvis, axes, np.zeros(len(t)), np.zeros((len(t), 2)))
    poses = lower_body.device_poses(shape, roles, path, feet, headings, np.zeros((len(t), 2)))
    return lower_body.with_devices(recording, roles, poses, "the lower body of the VRIK-like baseline")


def _feet(shape: LowerBodyShape, t: np.ndarray, pelvis: np.ndarray, heading: np.ndarray):
    """(F, 2, 3) ankles and (F, 2) headings: planted, stepping on distance or turn (a loop over
    frames: a baseline, not the product)."""
    n = len(t)
    fps = (n - 1) / max(t[-1] - t[0], 1e-9) if n > 1 else 90.0
    steps = max(2, int(round(STEP_S * fps)))
    ideal = pelvis[:, None] + np.einsum("fij,sj->fsi", body_axes(heading), shape.ankle)
    ideal[..., 2] = shape.ankle_height
    ideal_h = heading[:, None] + shape.foot_turn
    feet, heads = np.empty((n, 2, 3)), np.empty((n, 2))
    cur, cur_h = ideal[0].copy(), ideal_h[0].copy()
    swing = None
    for k in range(n):
        if swing is None:
            miss = np.linalg.norm((ideal[k] - cur)[:, :2], axis=1)
            turn = np.abs(wrap(ideal_h[k] - cur_h))
            due = (miss > STEP_DISTANCE) | (turn > STEP_TURN)
            if due.any():
                s = int(np.argmax(miss + turn * 0.3))
                swing = (s, k, cur[s].copy(), ideal[min(k + steps, n - 1), s].copy(), cur_h[s],
                         cur_h[s] + wrap(ideal_h[min(k + steps, n - 1), s] - cur_h[s]))
        if swing is not None:
            s, k0, p0, p1, h0, h1 = swing
            u = min(1.0, (k - k0) / steps)
            e = u * u * (3 - 2 * u)
            cur[s] = p0 + e * (p1 - p0)
            cur[s, 2] = shape.ankle_height + 0.05 * np.sin(np.pi * u)
            cur_h[s] = h0 + e * (h1 - h0)
            if u >= 1.0:
                swing = None
        feet[k], heads[k] = cur, cur_h
    return feet, heads
