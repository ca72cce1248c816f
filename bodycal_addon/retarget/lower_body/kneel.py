"""Kneeling on one knee (DESIGN.md §6 "A lower body from head and hands"): a pelvis lower than a
crouch takes (`KNEEL_FROM` of its standing height) puts one knee on the floor, the shin along it
and the foot's toes tucked under, and the other foot flat in front, its shin upright under the
knee (`FRONT_FOOT` of the thigh ahead of its hip). It blends in over `KNEEL_BLEND` of the standing
height, so a crouch that deepens turns into a kneel, and back.

The knee that goes down is the one whose foot stood further back when the kneel began.
"""

from __future__ import annotations

import numpy as np

from .body_path import BodyPath
from .shape import LowerBodyShape, body_axes

KNEEL_FROM = 0.6  # x the standing pelvis height
KNEEL_BLEND = 0.12  # x the standing pelvis height
KNEE_ABOVE_FLOOR = 0.03  # x stature: the knee joint's centre when the knee rests on the floor
TOES_DOWN = np.radians(60.0)
FRONT_FOOT = 0.9  # x the thigh: the front foot ahead of its hip


def kneel_weight(shape: LowerBodyShape, pelvis_z: np.ndarray) -> np.ndarray:
    """(F,) 0 standing or crouching, 1 kneeling, smooth between."""
    u = np.clip((KNEEL_FROM * shape.pelvis_height - pelvis_z) / (KNEEL_BLEND * shape.pelvis_height), 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


class Kneeling:
    """Applies the kneel to the feet a `Stepper` planted: `apply` changes `feet` (F, 2, 3) in
    place over the frames of `path` and returns the feet's pitch toes down (F, 2); the choice of
    knee carries over calls (live: one frame at a time)."""

    def __init__(self, shape: LowerBodyShape):
        self.shape = shape
        self.knee: int | None = None  # the foot kneeling (0 left, 1 right) while a kneel lasts

    def apply(self, path: BodyPath, feet: np.ndarray, headings: np.ndarray) -> np.ndarray:
        shape = self.shape
        w = kneel_weight(shape, path.pelvis[:, 2])
        pitch = np.zeros(feet.shape[:2])
        if not w.any():
            self.knee = None
            return pitch
        axes = body_axes(path.heading)
        forward = axes[:, :, 1]
        if len(w) == 1:  # live: one frame
            which = np.array([self._choose(feet[0], path.pelvis[0], forward[0], w[0])])
        else:
            which = self._episodes(w, feet, path.pelvis, forward)
        rows = np.arange(len(w))
        hip = path.pelvis + np.einsum("fij,fj->fi", axes, shape.hip[which])
        knee_z = KNEE_ABOVE_FLOOR * shape.stature
        reach = np.sqrt(np.maximum(shape.thigh ** 2 - (hip[:, 2] - knee_z) ** 2, 0.0))
        knee = hip + forward * reach[:, None]
        knee[:, 2] = knee_z
        back = np.sqrt(max(shape.shin ** 2 - (shape.ankle_height - knee_z) ** 2, 0.0))
        ankle = knee - forward * back
        ankle[:, 2] = shape.ankle_height
        planted = feet[rows, which]
        feet[rows, which] = planted + w[:, None] * (ankle - planted)
        pitch[rows, which] = w * TOES_DOWN
        other = 1 - which
        hip = path.pelvis + np.einsum("fij,fj->fi", axes, shape.hip[other])
        front = hip + forward * FRONT_FOOT * shape.thigh
        front[:, 2] = shape.ankle_height
        planted = feet[rows, other]
        feet[rows, other] = planted + w[:, None] * (front - planted)
        return pitch

    def _choose(self, feet, pelvis, forward, w) -> int:
        if w <= 0.0:
            self.knee = None
        elif self.knee is None:
            self.knee = int(np.argmin((feet[:, :2] - pelvis[:2]) @ forward[:2]))
        return 0 if self.knee is None else self.knee

    def _episodes(self, w, feet, pelvis, forward) -> np.ndarray:
        """(F,) the kneeling foot of each run of frames with a kneel (0 elsewhere)."""
        which = np.zeros(len(w), np.intp)
        on = np.concatenate([[0], (w > 0).astype(np.int8), [0]])
        edges = np.flatnonzero(np.diff(on))
        for a, b in zip(edges[::2], edges[1::2]):  # a loop over kneels, not frames
            which[a:b] = int(np.argmin((feet[a, :, :2] - pelvis[a, :2]) @ forward[a, :2]))
        return which


def pitch_down(angle) -> np.ndarray:
    """(..., 3, 3) a foot's turn toes down by `angle` about its right axis."""
    a = np.asarray(angle, float)
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, s], -1), np.stack([z, -s, c], -1)], -2)
