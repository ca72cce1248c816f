"""The upper trunk's turn (DESIGN.md §6 "A lower body from head and hands"): the estimated chest,
which carries the shoulders, turns about the vertical from the body's heading as far as keeps both
hands within their arms' reach (the wrists ride on the controllers: an arm estimated too short
for where a controller is leaves the avatar's hand short of it). A walker's shoulders swing
against the head's steady heading, a reach across the body turns them.

Each frame takes the smallest turn (of `TURNS`) that keeps both wrists within `REACH` of their
shoulders, the cost of a turn `TURN_COST` (m² per rad²) against the over-reach's square;
vectorised over frames and candidate turns.
"""

from __future__ import annotations

import numpy as np

from .shape import LowerBodyShape, body_axes, lean

TURNS = np.radians(np.arange(-45.0, 46.0, 3.0))
REACH = 0.98  # x the arm (shoulder to elbow to wrist)
TURN_COST = 0.0004  # m² per rad²: 20 degrees of turn weigh as a centimetre over reach


def chest_turn(shape: LowerBodyShape, neck: np.ndarray, heading: np.ndarray, phi: np.ndarray,
               wrists: np.ndarray) -> np.ndarray:
    """(F,) the chest's turn from `heading` (radians) for the skull base `neck` (F, 3), the trunk's
    lean `phi` (F,) and the wrists (F, 2, 3) where the controllers put them."""
    axes = body_axes(heading[:, None] + TURNS) @ lean(phi)[:, None]  # (F, K, 3, 3)
    shoulders = neck[:, None, None] + np.einsum("fkij,sj->fksi", axes, shape.shoulders)  # (F, K, 2, 3)
    over = np.linalg.norm(wrists[:, None] - shoulders, axis=-1) - REACH * shape.arms  # (F, K, 2)
    cost = (np.maximum(over, 0.0) ** 2).sum(-1) + TURN_COST * TURNS ** 2
    return TURNS[np.argmin(cost, axis=1)]
