"""The heel rises at the end of a stance (DESIGN.md §6 "A lower body from head and hands"): a foot
that stands behind or under a hip that walks on (or rises: tiptoes) rolls up onto its ball once
the hip is further from it than
standing (the calibration's rest, its knee a little bent, and `SWAY`) or `REACH` of the leg,
whichever is more, so the leg never stretches past its length (the pelvis of a walker moves 0.8 m
over a foot's stance; with the foot flat the ankle was 1.15 legs from the hip, out of the avatar's
reach). A foot ahead of its hip lands on its heel instead: the step never lands out of reach
(stepping.py).

The foot turns toes down about its ball (the toe joint, which stays on the floor) as far as that
takes, up to `MOST`; the stepper lifts it once that is more than `stepping.RISE_STEP`. Vectorised
over frames and feet.
"""

from __future__ import annotations

import numpy as np

from .shape import LowerBodyShape

REACH = 0.97  # x the leg
SWAY = 0.01  # m beyond the rest's hip-to-ankle distance before a heel rises (a standing body straightens)
AHEAD = 0.05  # m: an ankle further ahead of its hip than this does not rise (it is landing)
MOST = np.radians(70.0)  # toe-off: the toes bend up to about 70 degrees
_STEPS = np.linspace(0.0, MOST, 71)
UP = np.array([0.0, 0.0, 1.0])


def rise(shape: LowerBodyShape, hips: np.ndarray, feet: np.ndarray, headings: np.ndarray):
    """The heel rise a flat foot needs: (angle (..., 2) radians toes down, 0 where none (MOST where
    not even that is enough), ankles (..., 2, 3) raised by it) for hips (..., 2, 3), flat feet's
    ankles (..., 2, 3) and headings (..., 2)."""
    forward = np.stack([np.cos(headings), np.sin(headings), np.zeros_like(headings)], -1)
    toe_drop = shape.ankle_height - shape.toe_height
    ball = feet + forward * shape.foot_length
    ball[..., 2] = feet[..., 2] - toe_drop

    def ankle_at(a):  # the ankle (back, up) of the ball turned toes down by a about the foot's right
        a = np.asarray(a, float)[..., None]
        along = -shape.foot_length * np.cos(a) + toe_drop * np.sin(a)
        up = shape.foot_length * np.sin(a) + toe_drop * np.cos(a)
        return along, up

    along, up = ankle_at(_STEPS)  # (K, 1)
    cand = ball[..., None, :] + forward[..., None, :] * along + UP * up  # (..., 2, K, 3)
    reach = np.linalg.norm(hips[..., None, :] - cand, axis=-1)  # falls with the angle
    standing = np.linalg.norm(shape.hip - shape.ankle, axis=1) + SWAY
    limit = np.maximum(REACH * shape.leg, standing)  # (2,)
    # a foot under its hip too (tiptoes); one ahead of it lands on its heel instead
    behind = np.einsum("...i,...i->...", hips - feet, forward) > -AHEAD
    over = (reach[..., 0] > limit) & behind
    within = reach <= limit[:, None]
    k = np.where(within.any(-1), np.clip(np.argmax(within, axis=-1), 1, len(_STEPS) - 1), len(_STEPS) - 1)
    r0 = np.take_along_axis(reach, (k - 1)[..., None], -1)[..., 0]
    r1 = np.take_along_axis(reach, k[..., None], -1)[..., 0]
    u = np.clip((r0 - limit) / np.maximum(r0 - r1, 1e-12), 0.0, 1.0)
    angle = np.where(over, _STEPS[k - 1] + u * (_STEPS[k] - _STEPS[k - 1]), 0.0)
    a_along, a_up = ankle_at(angle)
    return angle, ball + forward * a_along + UP * a_up


def heel_rise(shape: LowerBodyShape, hips: np.ndarray, feet: np.ndarray, headings: np.ndarray,
              pitches: np.ndarray) -> None:
    """(in place) `feet` (F, 2, 3) ankles raised about their balls and `pitches` (F, 2) set where a
    hip (F, 2, 3) is out of reach of its flat foot; a kneeling foot (pitched already) keeps its pose."""
    angle, raised = rise(shape, hips, feet, headings)
    rows = np.nonzero((angle > 0.0) & (pitches < np.radians(1.0)))
    feet[rows] = raised[rows]
    pitches[rows] = angle[rows]

