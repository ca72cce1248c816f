"""Where a performance plays in the avatar's scene (DESIGN.md §1, "Placement"), and the
avatar-model checks that go with the armature object's transform. Numpy only.

The retargeting engine works in the performer's play area: the recording's frame, floor at z = 0,
forward = +Y (FORMATS.md §2.1: a performer in the T-pose faces forward). The avatar is brought
into that frame by `play_area_to_world`'s inverse before anything is computed, and the result is
carried back by it. Two placements:

- `object` (the default): the play area's origin is the armature object's origin (location and
  height) and its forward is the way the avatar faces at rest (its hip line), so a performer who
  starts at the play-area origin facing forward leaves the avatar where and as it stood. The
  performer's whole path is scaled about that origin with the avatar's legs (`root_scale`), so an
  avatar scaled by s plays its performance scaled by s: moving, turning (about the vertical) or
  uniformly scaling the armature object moves the whole result with it, and two avatars in one
  scene each play on their own spot.
- `performer`: the avatar plays where the performer was in the room (the recording's x, y and
  facing), on its own floor (the height of the armature object's origin; a bare skeleton's,
  `floor_height`, under its rest soles); the path is scaled
  about the floor point under the performer's pelvis at the reference time (`root_centre`).

Either way the pose-bone values of the result are in armature space, so the bake is the same; only
the engine's joints and targets are carried back into the world.
"""

from __future__ import annotations

import copy
import dataclasses

import numpy as np

from ..avatar.estimate import ESTIMATED, sole_depth
from ..body.bodymodel import BodyModel
from ..core.errors import BodyCalError

PLACEMENTS = ("object", "performer")  # the default first
PLAY_AREA_FORWARD = np.array([0.0, 1.0, 0.0])
PLAUSIBLE_HEIGHT_M = (0.3, 3.0)  # outside this, an avatar's world height is a units or scale mistake
UNIFORM_SCALE_TOLERANCE = 1e-3  # relative spread of the object's axis scales still called uniform


def check_placement(placement: str) -> str:
    if placement not in PLACEMENTS:
        raise BodyCalError(f"unknown placement '{placement}'", field="placement",
                           hint=f"use one of {', '.join(PLACEMENTS)}")
    return placement


def rig_matrix(model: BodyModel) -> np.ndarray:
    """(4, 4) the armature object's matrix_world when the avatar was calibrated (extra.rig)."""
    rig = model.extra.get("rig")
    raw = rig.get("matrix_world", np.eye(4)) if isinstance(rig, dict) else np.eye(4)
    try:
        m = np.asarray(raw, float).reshape(4, 4)
    except (TypeError, ValueError):
        raise BodyCalError("the rig's matrix_world is not a 4x4 matrix", source=model.name,
                           field="extra.rig.matrix_world", hint="calibrate the avatar again") from None
    if not np.isfinite(m).all():
        raise BodyCalError("the rig's matrix_world is not finite", source=model.name, field="extra.rig.matrix_world")
    return m


def rest_heading(model: BodyModel) -> np.ndarray:
    """(3,) unit floor direction the avatar faces at rest: its hip line (right to left) x up."""
    try:
        lateral = np.asarray(model.joints["hip_l"].world, float) - np.asarray(model.joints["hip_r"].world, float)
    except KeyError as exc:
        raise BodyCalError(f"joint {exc} is missing", source=model.name, field="joints",
                           hint="calibrate the avatar again") from None
    lateral[2] = 0.0
    n = np.linalg.norm(lateral)
    if n < 1e-6:
        raise BodyCalError("the avatar's hips are one above the other at rest: its heading on the floor is "
                           "undefined", source=model.name, hint="stand the avatar up, or use the performer placement")
    return np.array([lateral[1], -lateral[0], 0.0]) / n  # lateral x up


def yaw_matrix(from_dir: np.ndarray, to_dir: np.ndarray) -> np.ndarray:
    """(3, 3) the turn about +Z carrying the floor direction `from_dir` onto `to_dir`."""
    ang = np.arctan2(to_dir[1], to_dir[0]) - np.arctan2(from_dir[1], from_dir[0])
    c, s = np.cos(ang), np.sin(ang)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def floor_height(avatar: BodyModel) -> float:
    """The avatar's floor (world z): the height of its object's origin; for a bare skeleton's
    estimated body (avatar/estimate.py), under its rest soles instead: nothing says where a
    skeleton's floor is (a BVH's rest hangs from the hips at the object's origin), and a rest pose
    standing on the floor is where the skeleton stands."""
    origin = rig_matrix(avatar)[:3, 3]
    if avatar.calibration.get("method") != ESTIMATED:
        return float(origin[2])
    try:
        return min(float(avatar.joints[f"ankle_{s}"].world[2]) - sole_depth(avatar, s) for s in ("l", "r"))
    except (KeyError, ValueError, BodyCalError):  # no sole estimated (no foot bones): the object's origin
        return float(origin[2])


def play_area_to_world(avatar: BodyModel, placement: str = "object") -> np.ndarray:
    """(4, 4) rigid: the performer's play area -> the world, for this avatar (module docstring)."""
    check_placement(placement)
    origin = rig_matrix(avatar)[:3, 3]
    m = np.eye(4)
    if placement == "performer":
        m[2, 3] = floor_height(avatar)  # the avatar's floor: where its object stands
        return m
    m[:3, :3] = yaw_matrix(PLAY_AREA_FORWARD, rest_heading(avatar))
    m[:3, 3] = origin[0], origin[1], floor_height(avatar)
    return m


def similarity_parts(m: np.ndarray) -> tuple[np.ndarray, float, np.ndarray] | None:
    """(rotation (3, 3), uniform scale, translation) of a 4x4 similarity, else None."""
    m = np.asarray(m, float)
    lin = m[:3, :3]
    det = np.linalg.det(lin)
    if not np.isfinite(m).all() or det <= 0 or np.abs(m[3] - [0, 0, 0, 1]).max() > 1e-9:
        return None
    s = float(np.cbrt(det))
    rot = lin / s
    if np.abs(rot.T @ rot - np.eye(3)).max() > 1e-6:
        return None
    return rot, s, m[:3, 3].copy()


def transformed_avatar(model: BodyModel, m: np.ndarray) -> BodyModel:
    """A copy of the avatar model with its whole body moved by the similarity `m` (rotation,
    uniform scale, translation), as if the armature object had been transformed by `m` before the
    calibration: world joints, bone rights, lengths and radii, the surface (its points are local
    to the canonical bone frames, which turn with the body, so they only scale) and the rig's
    matrix_world. The armature's own data (bones in armature space, joints' `local`) is unchanged."""
    parts = similarity_parts(m)
    if parts is None:
        raise BodyCalError("the avatar can only be moved, turned and uniformly scaled", source=model.name,
                           field="extra.rig.matrix_world", hint="calibrate the avatar again where it stands")
    rot, s, t = parts
    out = _copied(model)
    for j in out.joints.values():
        j.world = rot @ (s * np.asarray(j.world, float)) + t
    for b in out.bones.values():
        b.length = b.length * s
        if b.right is not None:
            b.right = rot @ np.asarray(b.right, float)
        b.radius_head = None if b.radius_head is None else b.radius_head * s
        b.radius_tail = None if b.radius_tail is None else b.radius_tail * s
    for e in out.surface:
        if e.center is not None:
            e.center = np.asarray(e.center, float) * s
        if e.radius is not None:
            e.radius = e.radius * s
        if e.type == "capsule" and ("axis_head" in e.extra or "axis_tail" in e.extra):
            e.set_axis_offsets(*(e.axis_offsets() * s))
        if isinstance(e.extra.get("contact"), dict):  # a sole's contact points (foot_contact.py)
            e.extra["contact"] = {k: (np.asarray(v, float) * s).tolist() for k, v in e.extra["contact"].items()}
        for p in e.points.values():
            p.local = np.asarray(p.local, float) * s
    if isinstance(out.extra.get("rig"), dict):
        out.extra["rig"]["matrix_world"] = (np.asarray(m, float) @ rig_matrix(model)).tolist()
    return out


def _copied(model: BodyModel) -> BodyModel:
    """A copy of `model` that shares nothing mutable with it, as copy.deepcopy's. Decision (speed):
    each joint, bone, element and point a new object and their arrays copied by numpy, not through
    copy.deepcopy's Python walk: `transformed_avatar` of the bench avatar 20.2 -> 12.7 M instructions,
    once in every solver's set-up."""
    out = copy.copy(model)
    deep = copy.deepcopy
    out.joints = {k: dataclasses.replace(j, world=np.array(j.world), local=deep(j.local), frames=deep(j.frames))
                  for k, j in model.joints.items()}
    out.bones = {k: dataclasses.replace(b, right=deep(b.right), extra=deep(b.extra)) for k, b in model.bones.items()}
    out.surface = [dataclasses.replace(e, center=deep(e.center), triangles=list(e.triangles), extra=deep(e.extra),
                                       points={k: dataclasses.replace(p, local=np.array(p.local))
                                               for k, p in e.points.items()})
                   for e in model.surface]
    out.offsets, out.calibration, out.extra = deep(model.offsets), deep(model.calibration), deep(model.extra)
    return out


def moved_to(model: BodyModel, matrix_world: np.ndarray) -> BodyModel:
    """The avatar model as if calibrated with the armature object at `matrix_world` (the object was
    moved, turned or uniformly scaled since its model was calibrated and stored); the model itself
    when nothing moved."""
    stored = rig_matrix(model)
    now = np.asarray(matrix_world, float)
    if np.abs(now - stored).max() <= 1e-9 * max(1.0, np.abs(stored).max()):
        return model
    try:
        change = now @ np.linalg.inv(stored)
    except np.linalg.LinAlgError:
        change = None
    if change is None or similarity_parts(change) is None:
        raise BodyCalError("the armature object was scaled unevenly or mirrored since its avatar model was "
                           "calibrated", source=model.name, hint="calibrate the avatar again")
    return transformed_avatar(model, change)


def object_scale(model: BodyModel) -> np.ndarray:
    """(3,) the armature object's scale along its own axes."""
    return np.linalg.norm(rig_matrix(model)[:3, :3], axis=0)


def world_height(model: BodyModel) -> float:
    """The avatar's height in world units at rest: from its lowest joint to its highest."""
    z = np.array([np.asarray(j.world, float)[2] for j in model.joints.values()])
    return float(z.max() - z.min()) if len(z) else 0.0


def avatar_warnings(model: BodyModel) -> list[str]:
    """One line per thing about the armature object's transform that makes a result doubtful but
    not impossible: a non-uniform scale (posed as its mean uniform scale: limbs look stretched) and
    a world height no human avatar has (a units mistake: a centimetre file read as metres)."""
    out = []
    scale = object_scale(model)
    if scale.max() - scale.min() > UNIFORM_SCALE_TOLERANCE * scale.max():
        out.append(f"{model.name}: the armature object's scale is not uniform "
                   f"({', '.join(f'{x:.3g}' for x in scale)}): it is posed as if uniformly scaled by "
                   f"{float(np.cbrt(np.prod(scale))):.3g} and will look stretched; apply the scale "
                   f"(Ctrl+A) and calibrate again")
    height = world_height(model)
    low, high = PLAUSIBLE_HEIGHT_M
    if not low <= height <= high:
        out.append(f"{model.name}: the avatar is {height:.3g} m tall in world units, outside {low:g}-{high:g} m: "
                   f"check the file's units and the armature object's scale")
    return out
