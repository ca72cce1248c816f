"""What the lower-body model needs of a user body model, read once (DESIGN.md §6 "A lower body
from head and hands"): where the skull base sits in the HMD, the trunk from the pelvis to the skull
base, the standing legs, the feet, and the estimated devices' reference poses.

Body axes: a heading angle psi puts the performer's forward at (cos psi, sin psi, 0) and right at
(sin psi, -cos psi, 0); `body_axes(psi)` has the columns right, forward, up, the same axes as an
estimated device's (calibration/estimated_devices.py). Offsets "in the body frame" are in these
axes at the reference time.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...body.bodymodel import BodyModel
from ...core import transforms as tf
from ...core.errors import BodyCalError

SIDES = ("l", "r")
# The head, arms and trunk: their share of the body's mass and where their mass centre is from the
# hip joints to the shoulders (Winter 2009, Table 4.1: 0.678; 0.626 of the way up)
HAT_MASS, HAT_CENTRE = 0.678, 0.626
FEET = ("foot_l", "foot_r")


def body_axes(psi) -> np.ndarray:
    """(..., 3, 3) columns right, forward, up for heading angles `psi` (...,)."""
    psi = np.asarray(psi, float)
    c, s = np.cos(psi), np.sin(psi)
    z = np.zeros_like(psi)
    o = np.ones_like(psi)
    return np.stack([np.stack([s, c, z], -1), np.stack([-c, s, z], -1), np.stack([z, z, o], -1)], -2)


def heading_of(forward) -> np.ndarray:
    """The heading angle of (horizontal parts of) forward vectors (..., 3)."""
    forward = np.asarray(forward, float)
    return np.arctan2(forward[..., 1], forward[..., 0])


def lean(phi) -> np.ndarray:
    """(..., 3, 3) a forward lean by `phi` in body axes: up turns toward forward."""
    phi = np.asarray(phi, float)
    c, s = np.cos(phi), np.sin(phi)
    z, o = np.zeros_like(phi), np.ones_like(phi)
    return np.stack([np.stack([o, z, z], -1), np.stack([z, c, s], -1), np.stack([z, -s, c], -1)], -2)


@dataclass(frozen=True)
class LowerBodyShape:
    """The user's lower body as the model moves it; lengths in metres, offsets in body axes."""

    estimated: tuple[str, ...]  # the estimated roles (pelvis, foot_l, foot_r or the feet)
    neck_in_hmd: np.ndarray  # (3,) the skull base in the HMD's frame
    hmd_ref: np.ndarray  # (3, 3) the HMD's rotation at the reference time
    heading0: float  # the body's heading at the reference time
    trunk: np.ndarray  # (3,) pelvis -> skull base, body axes
    pelvis_height: float  # standing
    leg: float  # thigh + shin
    thigh: float
    shin: float
    hip: np.ndarray  # (2, 3) pelvis -> hip_l, hip_r, body axes
    ankle: np.ndarray  # (2, 3) pelvis -> ankle_l, ankle_r, body axes (standing)
    ankle_height: float
    foot_turn: np.ndarray  # (2,) each foot's heading minus the body's, reference time
    foot_length: float  # ankle to toe, horizontal
    toe_height: float  # the toe joint (the ball) above the floor, standing
    stature: float
    # Where each estimated device stands on its joint (the pelvis; each ankle): its origin's offset
    # and its rotation in the joint's axes (the body's; the foot's), fixed since the reference
    pelvis_device: tuple[np.ndarray, np.ndarray]
    chest_device: tuple[np.ndarray, np.ndarray]  # on the skull base, the trunk's axes
    shoulders: np.ndarray  # (2, 3) skull base -> shoulder_l, shoulder_r, body axes
    arms: np.ndarray  # (2,) upper arm + forearm
    wrists_in_hands: np.ndarray  # (2, 3) each wrist in its hand device's frame
    palms_in_hands: np.ndarray  # (2, 2, 3) each palm's centre and normal (out of the palm) in its hand device's
    # frame; a zero normal where the calibration has no palm plane
    thigh_radii: np.ndarray  # (2,) the thigh's capsule radius at the hip and at the knee
    foot_devices: tuple[tuple[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]

    @property
    def trunk_length(self) -> float:
        return float(np.linalg.norm(self.trunk))

    @property
    def centre_share(self) -> float:
        """How far from the pelvis toward the skull base the body's mass centre is over the floor:
        the head, arms and trunk's centre (`HAT_MASS`, `HAT_CENTRE` of the way up to the shoulders),
        the legs' under the pelvis."""
        up = float(self.trunk[2])
        return HAT_MASS * HAT_CENTRE * (up + float(np.mean(self.shoulders[:, 2]))) / max(up, 1e-9)

    @classmethod
    def of(cls, user: BodyModel) -> LowerBodyShape:
        extra = user.extra if isinstance(user.extra, dict) else {}
        estimated = tuple(r for r in ("pelvis", *FEET) if r in (extra.get("estimated_devices") or {}))
        tpose = extra.get("tpose") or {}
        if "head" not in tpose or "skull_base" not in user.joints:
            raise BodyCalError("the user model has no HMD reference pose or skull base: the lower body cannot be "
                               "estimated", source=user.name, field="extra.tpose",
                               hint="calibrate the user again from the recording")
        w = {k: np.asarray(j.world, float) for k, j in user.joints.items()}
        head_p = np.asarray(tpose["head"][:3], float)
        hmd_ref = tf.quat_to_matrix(tf.quat_normalize(np.asarray(tpose["head"][3:7], float)))
        left = w["hip_l"] - w["hip_r"]
        left[2] = 0.0
        forward = np.cross(left, [0.0, 0.0, 1.0])
        psi0 = float(heading_of(forward))
        to_body = body_axes(psi0).T
        pelvis = w["pelvis"]
        toes = [w[f"toe_{s}"] - w[f"ankle_{s}"] for s in SIDES]
        foot_turn = np.array([wrap(heading_of(t) - psi0) for t in toes])
        feet_axes = [body_axes(psi0 + t) for t in foot_turn]
        thigh = float(np.mean([user.bones[f"thigh_{s}"].length for s in SIDES]))
        shin = float(np.mean([user.bones[f"shin_{s}"].length for s in SIDES]))
        return cls(
            estimated=estimated,
            neck_in_hmd=hmd_ref.T @ (w["skull_base"] - head_p),
            hmd_ref=hmd_ref,
            heading0=psi0,
            trunk=to_body @ (w["skull_base"] - pelvis),
            pelvis_height=float(pelvis[2]),
            leg=thigh + shin,
            thigh=thigh,
            shin=shin,
            hip=np.array([to_body @ (w[f"hip_{s}"] - pelvis) for s in SIDES]),
            ankle=np.array([to_body @ (w[f"ankle_{s}"] - pelvis) for s in SIDES]),
            ankle_height=float(np.mean([w[f"ankle_{s}"][2] for s in SIDES])),
            foot_turn=foot_turn,
            foot_length=float(np.mean([np.linalg.norm(t[:2]) for t in toes])),
            toe_height=float(np.mean([w[f"toe_{s}"][2] for s in SIDES])),
            stature=float(extra.get("eye_height", head_p[2])) / 0.93,
            pelvis_device=_on_joint(tpose, "pelvis", pelvis, body_axes(psi0)),
            chest_device=_on_joint(tpose, "chest", w["skull_base"], body_axes(psi0)),
            shoulders=np.array([to_body @ (w[f"shoulder_{s}"] - w["skull_base"]) for s in SIDES]),
            arms=np.array([user.bones[f"upperarm_{s}"].length + user.bones[f"forearm_{s}"].length for s in SIDES]),
            wrists_in_hands=np.array([np.asarray(user.joints[f"wrist_{s}"].frames.get(f"hand_{s}", np.zeros(3)),
                                                 float) for s in SIDES]),
            palms_in_hands=np.array([_palm(extra, s) for s in SIDES]),
            thigh_radii=np.array([float(np.mean([_radius(user, f"thigh_{s}", end) for s in SIDES]))
                                  for end in ("radius_head", "radius_tail")]),
            foot_devices=tuple(_on_joint(tpose, f"foot_{s}", w[f"ankle_{s}"], feet_axes[i])
                               for i, s in enumerate(SIDES)),
        )


def _palm(extra: dict, s: str) -> np.ndarray:
    """(2, 3) the palm's centre and normal in its hand device's frame (a zero normal: not known)."""
    plane = (extra.get("palm_planes") or {}).get(f"hand_{s}")
    if not isinstance(plane, dict) or "point" not in plane or "normal" not in plane:
        return np.zeros((2, 3))
    return np.array([np.asarray(plane["point"], float), np.asarray(plane["normal"], float)])


def _radius(user: BodyModel, bone: str, end: str) -> float:
    """A capsule bone's radius at an end (0 when the model has none)."""
    info = user.bones.get(bone)
    value = getattr(info, end, None) if info is not None else None
    return float(value) if value is not None else 0.0


def _on_joint(tpose: dict, role: str, joint: np.ndarray, axes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(offset, rotation) of `role`'s reference pose in the joint's `axes` at `joint` (the identity
    for a device the model does not estimate: it is not made)."""
    if role not in tpose:
        return np.zeros(3), np.eye(3)
    p = np.asarray(tpose[role][:3], float)
    r = tf.quat_to_matrix(tf.quat_normalize(np.asarray(tpose[role][3:7], float)))
    return axes.T @ (p - joint), axes.T @ r


def wrap(a) -> np.ndarray:
    """Angles wrapped to (-pi, pi]."""
    return np.angle(np.exp(1j * np.asarray(a, float)))
