"""Kneeling on one knee (DESIGN.md §6 "A lower body from head and hands"): a pelvis lower than a
crouch takes (`KNEEL_FROM` of its standing height) puts one knee on the floor, the shin along it
and the foot's toes tucked under, and the other foot flat in front, its shin upright under the
knee (`FRONT_FOOT` of the thigh ahead of its hip).

The feet get there by steps (stepping.py: lifted, moved, planted, never slid along the floor):
from a balanced stance the foot that stood further back steps back to its kneeling place, then the
other steps to its place in front. Once the pelvis rises (`RISE` above its lowest, or back above
`KNEEL_FROM`) or the body moves on (its capture point out of the feet's support), the feet step
as a standing body's, the knee's foot first due. This module says where the kneeling feet stand.
"""

from __future__ import annotations

import numpy as np

from .shape import LowerBodyShape, body_axes

KNEEL_FROM = 0.6  # x the standing pelvis height
KNEEL_BLEND = 0.12  # x the standing pelvis height: `kneel_weight` from 0 to 1 below KNEEL_FROM
KNEE_ABOVE_FLOOR = 0.03  # x stature: the knee joint's centre when the knee rests on the floor
TOES_DOWN = np.radians(60.0)
FRONT_FOOT = 0.9  # x the thigh: the front foot ahead of its hip
RISE = 0.06  # x the standing pelvis height: kneeling, a pelvis risen this far above its lowest stands up


def kneel_weight(shape: LowerBodyShape, pelvis_z: np.ndarray) -> np.ndarray:
    """(F,) 0 standing or crouching, 1 kneeling (the pelvis `KNEEL_BLEND` below `KNEEL_FROM`),
    smooth between; above 0 a kneel is due."""
    u = np.clip((KNEEL_FROM * shape.pelvis_height - pelvis_z) / (KNEEL_BLEND * shape.pelvis_height), 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def knee_foot(feet: np.ndarray, pelvis: np.ndarray, heading: float) -> int:
    """The foot (0 left, 1 right) whose knee goes down: the one further back, `feet` (2, 3)."""
    forward = body_axes(heading)[:2, 1]
    return int(np.argmin((feet[:, :2] - pelvis[:2]) @ forward))


def kneeling_places(shape: LowerBodyShape, pelvis: np.ndarray, heading: float,
                    knee: int) -> tuple[np.ndarray, np.ndarray]:
    """(3,) the ankle of the knee's foot, its knee on the floor with the pelvis at `pelvis` (3,)
    turned to `heading` (the kneel's deepest: higher, the knee stays above the floor), and (3,)
    the other ankle in front."""
    axes = body_axes(heading)
    forward = axes[:, 1]
    hip = pelvis + axes @ shape.hip[knee]
    reach = np.sqrt(max(shape.thigh ** 2 - (hip[2] - KNEE_ABOVE_FLOOR * shape.stature) ** 2, 0.0))
    ankle = hip + forward * (reach - shin_on_floor(shape))
    ankle[2] = shape.ankle_height
    front = pelvis + axes @ shape.hip[1 - knee] + forward * FRONT_FOOT * shape.thigh
    front[2] = shape.ankle_height
    return ankle, front


def shin_on_floor(shape: LowerBodyShape) -> float:
    """How far ahead of its ankle a kneeling knee rests on the floor, over the floor."""
    knee_z = KNEE_ABOVE_FLOOR * shape.stature
    return float(np.sqrt(max(shape.shin ** 2 - (shape.ankle_height - knee_z) ** 2, 0.0)))


def pitch_down(angle) -> np.ndarray:
    """(..., 3, 3) a foot's turn toes down by `angle` about its right axis."""
    a = np.asarray(angle, float)
    c, s = np.cos(a), np.sin(a)
    z, o = np.zeros_like(a), np.ones_like(a)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, s], -1), np.stack([z, -s, c], -1)], -2)
