"""The device ladder below the hands (DESIGN.md §3 "The device ladder"): a kit without a pelvis
tracker or foot trackers is calibrated with *estimated devices* in their place, so that every
method animates it as it animates AvatarGo's six devices.

An estimated device is a device the recording does not have, whose poses the lower-body model
(`retarget/lower_body`) makes from the head and the hands. It is defined on the body, not strapped
to it: the estimated pelvis's origin is the pelvis joint (the middle of the hips) and its axes
the body's at the reference time (x the performer's right, y forward, z up); an estimated foot's
origin is the ankle and its axes the foot's (x its right, y along the foot, z up, level). The joints
they carry (pelvis, spine_root and the hips on the pelvis; the ankle and the toe on each foot) are
therefore at fixed, exactly known places in them, and the model's offsets (AvatarGo §3.3) and
reference poses (`extra["tpose"]`) are those of any device. What they carry is estimated, never
measured: the report, the model file (`extra["estimated_devices"]`, `calibration["estimated"]`)
and the Calibration panel say so.

Kits, from the bottom rung: HMD and two controllers (the pelvis and both feet estimated); plus a
pelvis tracker (the feet estimated); AvatarGo's six devices and up (nothing estimated).
"""

from __future__ import annotations

import numpy as np

from ..core import transforms as tf
from .common import Session, State

ESTIMATED_ROLES = ("pelvis", "foot_l", "foot_r")
CARRIED = {"pelvis": ("pelvis", "spine_root", "hip_l", "hip_r"), "foot_l": ("ankle_l", "toe_l"),
           "foot_r": ("ankle_r", "toe_r")}
UP = np.array([0.0, 0.0, 1.0])


def missing(session: Session) -> tuple[str, ...]:
    """The roles of `ESTIMATED_ROLES` the recording has no device for (estimated then)."""
    return tuple(r for r in ESTIMATED_ROLES if not session.rec.has_role(r))


def body_axes(left: np.ndarray) -> np.ndarray:
    """(3, 3) rotation whose columns are the performer's right, forward and up (level), for the
    body's `left` (its vertical part ignored)."""
    right = np.array([-left[0], -left[1], 0.0])
    right /= max(np.linalg.norm(right), 1e-9)
    return np.stack([right, np.cross(UP, right), UP], axis=1)


def register(session: Session, state: State, left: np.ndarray) -> dict[str, str]:
    """Reference poses of the estimated devices (the module docstring's definition), put into the
    session so every later pass (joints' frames, offsets, the T-pose poses) treats them as
    devices; `left`: the body's left at the reference time. Returns {role: what it stands for}."""
    w = state.world
    body = body_axes(left)
    out = {}
    for role in missing(session):
        if role == "pelvis":
            origin, rot = w["pelvis"], body
            out[role] = "the pelvis joint, estimated from the head and hands"
        else:
            s = role[-1]
            along = w[f"toe_{s}"] - w[f"ankle_{s}"]
            along[2] = 0.0
            n = np.linalg.norm(along)
            along = body[:, 1] if n < 1e-9 else along / n
            origin, rot = w[f"ankle_{s}"], np.stack([np.cross(along, UP), along, UP], axis=1)
            out[role] = f"the {'left' if s == 'l' else 'right'} ankle, estimated from the head and hands"
        session.estimate(role, np.asarray(origin, float), tf.matrix_to_quat(rot))
    return out
