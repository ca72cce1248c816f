"""The estimated devices of a kit below six devices (calibration/estimated_devices.py), made from
the head and hands (DESIGN.md §6 "A lower body from head and hands"): `complete` adds them to a
whole recording (looking ahead), `LiveLowerBody` to a stream's frames as they come.

What the estimated devices carry comes from the user model: their reference poses, and the joints
on them, are the calibration's, so the user animation, the feet plan and every method read them
as they read any tracker (retarget/user_animation.py, feet.py).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ...body.bodymodel import BodyModel
from ...core import transforms as tf
from ...recording.model import Device, Recording
from ..trackers import forward_fill
from .body_path import BodyPath, LivePath, gaussian, offline_path, tracked_path
from .chest import chest_turn
from .heel import heel_rise
from .kneel import pitch_down
from .shape import LowerBodyShape, body_axes, lean
from .stepping import Stepper
from .touch import hold_pelvis, rest_on_thighs

KIND = "estimated"
CHEST_SMOOTH_S = 0.08  # the chest's turn smoothed over this, both ways, on a whole take


def estimated_roles(recording: Recording, user: BodyModel) -> tuple[str, ...]:
    """The roles the user model estimates that the recording has no device for."""
    extra = user.extra if isinstance(user.extra, dict) else {}
    return tuple(r for r in ("pelvis", "chest", "foot_l", "foot_r")
                 if r in (extra.get("estimated_devices") or {}) and not recording.has_role(r))


def filled_pose(recording: Recording, role: str) -> tuple[np.ndarray, np.ndarray]:
    """(F, 3) positions and (F, 3, 3) rotations of a role's device, untracked frames holding the
    last tracked pose (the first for a leading gap)."""
    pos, quat, valid = recording.pose(role)
    idx = forward_fill(np.asarray(valid, bool))
    return np.asarray(pos, float)[idx], tf.quat_to_matrix(tf.quat_normalize(np.asarray(quat, float)[idx]))


def _pelvis_local(user: BodyModel) -> np.ndarray:
    return np.asarray(user.joints["pelvis"].frames["pelvis"], float)


def _tracker_ref(user: BodyModel, role: str) -> np.ndarray:
    return tf.quat_to_matrix(tf.quat_normalize(np.asarray(user.extra["tpose"][role][3:7], float)))


def complete(recording: Recording, user: BodyModel, *, seat_height: float | None = None) -> Recording:
    """`recording` with the estimated devices the user model needs and the recording lacks (the
    same recording when it lacks none); a note says how many steps the feet took."""
    roles = estimated_roles(recording, user)
    if not roles or recording.frame_count == 0:
        return recording
    shape = LowerBodyShape.of(user)
    t = np.asarray(recording.time, float)
    fps = recording.fps or 90.0
    if "pelvis" in roles:
        path = offline_path(shape, t, *filled_pose(recording, "head"), seat_height=seat_height)
        if seat_height is None:  # hands resting on the belly hold the pelvis, on the thighs lift it (touch.py)
            path = hold_pelvis(shape, t, path, wrists(recording, shape))
            path = rest_on_thighs(shape, t, path, palms(recording, shape),
                                  lambda p: _stand(shape, fps, p))
    else:
        pos, rot = filled_pose(recording, "pelvis")
        path = tracked_path(shape, t, pos, rot, _pelvis_local(user), _tracker_ref(user, "pelvis"))
    stepper = Stepper(shape, fps)
    feet, headings, pitches = _stand(shape, fps, path, stepper)
    heel_rise(shape, hips_of(shape, path), feet, headings, pitches)
    turn = 0.0
    if "chest" in roles:
        turn = gaussian(chest_turn(shape, path.neck, path.heading, path.lean, wrists(recording, shape)),
                        CHEST_SMOOTH_S * fps)
    poses = device_poses(shape, roles, path, feet, headings, pitches, turn)
    what = " and ".join(["the pelvis"] * ("pelvis" in roles) + ["the feet"] * ("foot_l" in roles))
    note = (f"{what} estimated from the head and hands"
            + (f" ({stepper.steps} steps)" if "foot_l" in roles else "")
            + (f", seated at {seat_height:.2f} m" if seat_height is not None else ""))
    return with_devices(recording, roles, poses, note)


def _stand(shape: LowerBodyShape, fps: float, path: BodyPath, stepper: Stepper | None = None):
    """(F, 2, 3) ankles, (F, 2) headings and (F, 2) toes-down pitches of the feet along the whole
    `path` (offline: each step looks ahead)."""
    F = len(path.heading)
    feet, headings, pitches = np.empty((F, 2, 3)), np.empty((F, 2)), np.zeros((F, 2))
    (stepper or Stepper(shape, fps)).advance(path, 0, F, feet, headings, available=F, out_pitch=pitches)
    return feet, headings, pitches


def palms(recording: Recording, shape: LowerBodyShape) -> np.ndarray:
    """(F, 2, 2, 3) each hand's palm centre and normal (out of the palm) where the hand devices put
    them (a zero normal where the calibration has no palm)."""
    out = []
    for s, (centre, normal) in zip("lr", shape.palms_in_hands):
        pos, rot = filled_pose(recording, f"hand_{s}")
        out.append(np.stack([pos + np.einsum("fij,j->fi", rot, centre), np.einsum("fij,j->fi", rot, normal)], 1))
    return np.stack(out, axis=1)


def wrists(recording: Recording, shape: LowerBodyShape) -> np.ndarray:
    """(F, 2, 3) the wrists where the hand devices put them."""
    out = []
    for s, local in zip("lr", shape.wrists_in_hands):
        pos, rot = filled_pose(recording, f"hand_{s}")
        out.append(pos + np.einsum("fij,j->fi", rot, local))
    return np.stack(out, axis=1)


def hips_of(shape: LowerBodyShape, path: BodyPath) -> np.ndarray:
    """(F, 2, 3) the hips along the path (on the pelvis, turned with the body)."""
    return path.pelvis[:, None] + np.einsum("fij,sj->fsi", body_axes(path.heading), shape.hip)


def device_poses(shape: LowerBodyShape, roles, path: BodyPath, feet: np.ndarray, headings: np.ndarray,
                 pitches: np.ndarray, chest: np.ndarray | float = 0.0) -> dict:
    """{role: ((F, 3) positions, (F, 4) quaternions)} of the estimated devices, each where it
    stands on its joint (`shape`): the pelvis on the path's pelvis, the chest on the skull base with
    the trunk's whole lean and turned by `chest` from the heading (chest.py), the feet on their
    ankles turned by their headings and pitched toes down by `pitches` (a kneel)."""
    out = {}
    for role in roles:
        if role == "pelvis":
            axes, joint, (off, rot) = path.pelvis_rot, path.pelvis, shape.pelvis_device
        elif role == "chest":
            axes, joint, (off, rot) = body_axes(path.heading + chest) @ lean(path.lean), path.neck, \
                shape.chest_device
        else:
            s = 0 if role == "foot_l" else 1
            axes, joint, (off, rot) = body_axes(headings[:, s]) @ pitch_down(pitches[:, s]), feet[:, s], \
                shape.foot_devices[s]
        out[role] = (joint + np.einsum("fij,j->fi", axes, off), tf.matrix_to_quat(axes @ rot))
    return out


def with_devices(recording: Recording, roles, poses: dict, note: str) -> Recording:
    """`recording` with the devices of `roles` added (kind `KIND`, always tracked): `poses`
    {role: ((F, 3) positions, (F, 4) quaternions)}; `note` joins the recording's notes."""
    n = recording.frame_count
    devices = list(recording.devices) + [Device(f"estimated {r}", KIND, r) for r in roles]
    positions = np.concatenate([recording.positions] + [poses[r][0][:, None] for r in roles], axis=1)
    rotations = np.concatenate([recording.rotations] + [poses[r][1][:, None] for r in roles], axis=1)
    valid = np.concatenate([recording.valid, np.ones((n, len(roles)), bool)], axis=1)
    return replace(recording, devices=devices, positions=positions, rotations=rotations, valid=valid,
                   notes=list(recording.notes) + [note])


class LiveLowerBody:
    """The estimated devices of a stream, one frame at a time from the frames so far (forward
    only): `roles` to add; `frame(t, head_pos, head_rot, pelvis_pos, pelvis_rot)` gives their
    {role: (position (3,), quaternion (4,))} for the frame (the pelvis tracker's pose when the
    kit has one, else None)."""

    def __init__(self, user: BodyModel, roles: tuple[str, ...], fps: float = 90.0, *,
                 seat_height: float | None = None):
        self.user, self.roles = user, tuple(roles)
        self.shape = LowerBodyShape.of(user)
        self.path = LivePath(self.shape, seat_height)
        self.stepper = Stepper(self.shape, fps)
        self._k = 0
        self._last_pelvis = None
        self._turn, self._t = 0.0, None  # the chest's turn (forward exponential), the last frame's time

    def frame(self, t: float, head_pos, head_rot, pelvis_pos=None, pelvis_rot=None, hands=None) -> dict:
        """The estimated devices' {role: (position, quaternion)} at time `t` from the head's pose,
        the pelvis tracker's when the kit has one, and the hand devices' ((position, rotation
        matrix) left, right; the chest turns to keep them in reach) when given."""
        if "pelvis" in self.roles or pelvis_pos is None:
            step = self.path.step(t, np.asarray(head_pos, float), np.asarray(head_rot, float))
        else:
            step = self._tracked(t, np.asarray(pelvis_pos, float), np.asarray(pelvis_rot, float))
        feet, headings, pitches = np.empty((1, 2, 3)), np.empty((1, 2)), np.zeros((1, 2))
        self.stepper.advance(step, self._k, self._k + 1, feet, headings, available=self._k + 1, base=self._k,
                             out_pitch=pitches)
        self._k += 1
        heel_rise(self.shape, hips_of(self.shape, step), feet, headings, pitches)
        if "chest" in self.roles and hands is not None:
            w = np.array([np.asarray(p, float) + np.asarray(r, float) @ local
                          for (p, r), local in zip(hands, self.shape.wrists_in_hands)])[None]
            target = chest_turn(self.shape, step.neck, step.heading, step.lean, w)[0]
            dt = 0.0 if self._t is None else max(t - self._t, 0.0)
            self._turn += (1.0 - np.exp(-dt / CHEST_SMOOTH_S)) * (target - self._turn) if self._t is not None \
                else target
        self._t = t
        poses = device_poses(self.shape, self.roles, step, feet, headings, pitches, self._turn)
        return {r: (p[0], q[0]) for r, (p, q) in poses.items()}

    def _tracked(self, t: float, pos: np.ndarray, rot: np.ndarray) -> BodyPath:
        shape = self.shape
        local = _pelvis_local(self.user)
        p = pos + rot @ local
        velocity = np.zeros(2)
        if self._last_pelvis is not None:
            t0, p0, v0 = self._last_pelvis
            dt = max(t - t0, 1e-6)
            a = 1.0 - np.exp(-dt / 0.06)
            velocity = v0 + a * ((p[:2] - p0[:2]) / dt - v0)
        self._last_pelvis = (t, p, velocity)
        return tracked_path(shape, np.array([t]), pos[None], rot[None], local, _tracker_ref(self.user, "pelvis"),
                            velocity=velocity[None])
