"""The device ladder below the hands (DESIGN.md §3 "The device ladder"): a kit without a pelvis
tracker or foot trackers is calibrated with *estimated devices* in their place, so that every
method animates it as it animates AvatarGo's six devices.

An estimated device is a device the recording does not have. It is defined on the body, not
strapped to it: at the reference time the estimated pelvis stands where the hip joints are
estimated (`provisional_body`: under the skull base, the legs' height above the floor), its axes
the body's (x the performer's right, y forward, z up); the estimated chest (the upper trunk, which
carries the shoulders) stands at the skull base with the same axes; an estimated foot stands at
the ankle, its axes the foot's (x its right, y along the foot, z up, level). During the calibration they are
carried rigidly by the HMD's position and its turn about the vertical (`attach`), so that the
touches a kit of HMD and controllers can make (the torso, the hips, the knees, the soles, with
the performer standing) ride on them like on any tracker; the pelvis and the feet stay where they
stood while the head is lowered (`BENT_DROP`: a performer bends to touch a knee, an ankle or a
sole without moving the feet); at retarget time the lower-body model
(`retarget/lower_body`) moves them. What they carry is estimated, never measured: the report, the
model file (`extra["estimated_devices"]`, `calibration["estimated"]`) and the Calibration panel
say so.

Kits, from the bottom rung: HMD and two controllers (the pelvis, the upper trunk and both feet
estimated); plus a pelvis tracker (the feet estimated, the shoulders on the pelvis tracker as with
six devices); AvatarGo's six devices and up (nothing estimated).
"""

from __future__ import annotations

import numpy as np

from ..body import skeleton as sk
from ..core import transforms as tf
from . import defaults
from .common import Session

ESTIMATED_ROLES = ("pelvis", "chest", "foot_l", "foot_r")
CARRIED = {"pelvis": ("pelvis", "spine_root", "hip_l", "hip_r"), "chest": ("shoulder_l", "shoulder_r"),
           "foot_l": ("ankle_l", "toe_l"), "foot_r": ("ankle_r", "toe_r")}
WHAT = {"pelvis": "the pelvis, estimated from the head and hands",
        "chest": "the upper trunk, estimated from the head and hands",
        "foot_l": "the left foot, estimated from the head and hands",
        "foot_r": "the right foot, estimated from the head and hands"}
UP = np.array([0.0, 0.0, 1.0])
# Decision: the estimated pelvis and feet follow the HMD only while the skull base is within this
# much of the stature below its reference height (standing, a relaxed stance); lower, the performer
# bends or crouches over feet that stay put (the touches of the knees, ankles and soles), and they
# keep their pose of the last frame the head was up; the feet stay on the floor throughout. Carried
# down with the head, an ankle touched bent over sat 1.04 m up in its foot's frame and the knee
# 46 cm off (the synthetic minimal protocol, HMD and controllers kept). The head moves back as a
# crouch begins: held from 0.05 H down the ankles were 64-68 mm off, from 0.03 H 38-42, 0.02 H 23-33.
BENT_DROP = 0.02  # x stature
HELD_ROLES = ("pelvis", "foot_l", "foot_r")
_SIGN = {"l": 1.0, "r": -1.0}  # toward the body's left


def missing(session: Session) -> tuple[str, ...]:
    """The roles of `ESTIMATED_ROLES` the recording has no device for (estimated then): the chest
    only with the pelvis (a pelvis tracker carries the shoulders as with six devices)."""
    has = session.rec.has_role
    return tuple(r for r in ESTIMATED_ROLES if not has(r) and (r != "chest" or not has("pelvis")))


def body_axes(left: np.ndarray) -> np.ndarray:
    """(3, 3) rotation whose columns are the performer's right, forward and up (level), for the
    body's `left` (its vertical part ignored)."""
    right = np.array([-left[0], -left[1], 0.0])
    right /= max(np.linalg.norm(right), 1e-9)
    return np.stack([right, np.cross(UP, right), UP], axis=1)


def provisional_body(session: Session) -> tuple[dict[str, np.ndarray], np.ndarray, float]:
    """({pelvis, ankle_l, ankle_r, skull_base: world}, body axes, stature) at the reference time,
    from the HMD and the hands alone: the skull base behind and below the HMD, the hip joints a
    little in front of the plumb line through it (the skull base) at the height of the ankle plus
    the thigh and the shin (0.551 H, where the surface landmark `defaults.R["hip_height"]`, the
    greater trochanter, is 0.53 H), the ankles under the hips and a little behind them (standing,
    the centre of mass is over the middle of the feet)."""
    R = defaults.R
    head = session.ref_pose("head")[0]
    H = float(head[2]) / defaults.EYE_TO_STATURE
    left = None
    if session.reference_step == "tpose" and session.has("hand_l") and session.has("hand_r"):
        left = session.ref_pose("hand_l")[0] - session.ref_pose("hand_r")[0]
    if left is None or np.linalg.norm(left[:2]) < 1e-6:  # the view's axes (FORMATS.md §2.1): x right
        left = -tf.quat_to_matrix(session.ref_pose("head")[1])[:, 0]
    axes = body_axes(left)
    right, forward = axes[:, 0], axes[:, 1]
    skull = defaults.skull_base_under_hmd(session, forward, H)
    legs = R["ankle_height"] + R["thigh"] + R["shin"]
    pelvis = skull + forward * R["hips_forward_of_skull_base"] * H
    pelvis[2] = legs * H
    out = {"skull_base": skull, "pelvis": pelvis}
    for s in sk.SIDES:
        a = pelvis - right * _SIGN[s] * R["hip_half_width"] * H - forward * R["ankles_behind_hips"] * H
        a[2] = R["ankle_height"] * H
        out[f"ankle_{s}"] = a
    return out, axes, H


def attach(session: Session) -> None:
    """Adds the estimated devices the kit lacks to the session, with their reference poses and
    their poses over the recording, carried by the HMD (the module docstring)."""
    roles = missing(session)
    if not roles or not session.has("head"):
        return
    body, axes, H = provisional_body(session)
    hp, hq, hv = session.rec.pose("head")
    ref_p, ref_q = session.ref_pose("head")
    ref_r = tf.quat_to_matrix(ref_q)
    rel = tf.quat_to_matrix(tf.quat_normalize(np.asarray(hq, float))) @ ref_r.T
    rel_q = tf.matrix_to_quat(rel)
    turn = 2.0 * np.arctan2(rel_q[:, 3], rel_q[:, 0])
    c, s = np.cos(turn), np.sin(turn)
    z, o = np.zeros_like(turn), np.ones_like(turn)
    yaw = np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)
    neck = np.asarray(hp, float) + np.einsum("fij,j->fi", rel, body["skull_base"] - ref_p)
    held = _last_upright(neck[:, 2] >= body["skull_base"][2] - BENT_DROP * H)
    for role in roles:
        origin = body["skull_base"] if role == "chest" else body["pelvis"] if role == "pelvis" else \
            body[f"ankle_{role[-1]}"]
        pos = neck + np.einsum("fij,j->fi", yaw, origin - body["skull_base"])
        quat = tf.matrix_to_quat(yaw @ axes)
        if role in HELD_ROLES:
            pos, quat = pos[held], quat[held]
        if role.startswith("foot_"):  # on the floor, whatever the head's height
            pos[:, 2] = origin[2]
        session.estimate(role, origin, tf.matrix_to_quat(axes), (pos, quat, np.asarray(hv, bool)))


def _last_upright(up: np.ndarray) -> np.ndarray:
    """(F,) for every frame the last frame at or before it whose `up` is true (before the first,
    the first; none at all: every frame itself)."""
    idx = np.arange(len(up))
    if not up.any():
        return idx
    last = np.maximum.accumulate(np.where(up, idx, -1))
    return np.where(last < 0, int(np.argmax(up)), last)
