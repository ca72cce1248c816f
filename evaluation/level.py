"""A clip's floor laid level: the rigid turn fitted from the clip's own feet, applied to a take's
devices and its truth alike.

A motion-capture floor is not always level (the CMU walk 02_01's rises 44 mm along its 2.8 m of
stances, 1.6 %: `measure.floor_along`), while a VR take's floor is (the headset's guardian: the
engine's floor is the calibration's, level). Judged as recorded, a clip's sloped floor reads as the
body rising off the engine's floor. `level_take` turns the whole recording about a horizontal axis
through the session's origin (where the calibration stands and the clip starts) so that its feet's
stance lows (the source's own floor, never a solve's) lie level. A turn of the whole take moves
everything rigidly: device poses, markers and the truth's joints keep every distance and every
relative orientation, the recording stays one a person could have made.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from . import measure, rot


def floor_turn(feet: list[np.ndarray], fps: float) -> tuple[np.ndarray, float]:
    """(q (4,) w x y z, tilt in radians): the turn about a horizontal axis that lays the floor under
    `feet` (`measure.floor_along`'s input) level; no turn with fewer than three stances."""
    axis, slope, _ = measure.floor_along(feet, fps)
    if axis is None or slope == 0.0:
        return np.array([1.0, 0.0, 0.0, 0.0]), 0.0
    up_hill = np.array([axis[0], axis[1], slope])
    hinge = np.cross(up_hill, [axis[0], axis[1], 0.0])  # horizontal, across the walk
    tilt = float(np.arctan(slope))
    return rot.to_quat(rot.axis_angle(hinge, tilt)), tilt


def turn_points(points: np.ndarray, q: np.ndarray, pivot: np.ndarray) -> np.ndarray:
    """Points (..., 3) turned by `q` about `pivot`."""
    return (np.asarray(points, float) - pivot) @ rot.from_quat(q).T + pivot


def turn_orientations(rotations: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Orientations (..., 4) w x y z (local to world) after the world turns by `q`: q * r, each
    keeping its sign (a track stays continuous)."""
    w0, v0 = q[0], np.asarray(q[1:], float)
    r = np.asarray(rotations, float)
    w, v = r[..., :1], r[..., 1:]
    return np.concatenate([w0 * w - v @ v0[:, None], w0 * v + w * v0 + np.cross(v0, v)], axis=-1)


def level_take(rec, truth: dict, fps: float):
    """(recording, truth, tilt in radians): the take and its truth turned together so that the
    truth's feet (ankle and ball, over the clip's motion) stand on a level floor. The turn's axis is
    horizontal through the session's origin (`truth["origin"]` on the lab floor); `rec` is a
    `Recording` (the engine's frame, the truth's lab frame), returned as a copy."""
    a, b = truth["motion"]
    J = truth["joints"]
    T = truth["positions"]
    feet = [T[a:b][:, [J.index(f"ankle_{s}"), J.index(f"toe_{s}")]] for s in "lr"]
    q, tilt = floor_turn(feet, fps)
    if tilt == 0.0:
        return rec, truth, 0.0
    pivot = np.array([truth["origin"][0], truth["origin"][1], 0.0])
    markers = rec.markers if rec.markers is None else turn_points(rec.markers, q, pivot)
    rec = replace(rec, positions=turn_points(rec.positions, q, pivot),
                  rotations=turn_orientations(rec.rotations, q), markers=markers)
    return rec, {**truth, "positions": turn_points(T, q, pivot)}, tilt
