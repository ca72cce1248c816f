"""Where an animation's travel goes (DESIGN.md §1 "Root motion", FORMATS.md §4.4).
Numpy only; applied to the finished `AvatarAnimation` just before the bake, so the engine, its
joints and every figure measured on them stay the same.

The engine keys the whole motion on the pelvis bone (its `location` in its rest frame), and a
rig's root bone above it stays at rest. Game rigs (Unreal, Unity, Mixamo with a root) expect the
travel on the root bone instead. Three modes:

- `root` (the default): when the rig has a root bone above the pelvis (the bone map's `root`
  segment), that bone stands on the floor under the pelvis bone's head (its rest height along the
  armature's up) and turns about the vertical with the pelvis's heading (the hip line's direction
  on the floor); the pelvis is keyed relative to it, so every bone lands where it did. A rig
  without a root bone keeps the motion on the pelvis.
- `pelvis`: the engine's keys as they are (the root bone at rest).
- `in-place`: no travel: the root bone at rest and the pelvis's horizontal motion removed (its
  floor position held at the first frame's); the height, the turns and the limbs are kept.

Blender's pose rule for a bone whose ancestors up to the root only follow it (identity keys):
a root posed by rotation D about its head's new place t moves the rest of that chain rigidly,
P_child = D M_child, H_child = D h_child + t. The pelvis then needs
basis = M_p^T D^T P_p and location = M_p^T D^T (H_p - t - D h_p), with P_p, H_p its pose before.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from ..body.animation import AvatarAnimation
from ..core.errors import BodyCalError
from ..core.transforms import matrix_to_quat, quat_to_matrix

ROOT_MOTIONS = ("root", "pelvis", "in-place")  # the default first


def check_root_motion(mode: str) -> str:
    if mode not in ROOT_MOTIONS:
        raise BodyCalError(f"unknown root motion '{mode}'", field="root_motion",
                           hint=f"use one of {', '.join(ROOT_MOTIONS)}")
    return mode


@dataclass
class RootRest:
    """What the conversion needs of the rig, in armature space (armature units)."""

    root_bone: str | None  # the bone above the pelvis that carries the travel; None: the rig has none
    root_matrix: np.ndarray | None  # (3, 3) its bone.matrix_local rotation
    root_head: np.ndarray | None  # (3,)
    pelvis_matrix: np.ndarray  # (3, 3) the pelvis bone's (the animation's root_bone)
    pelvis_head: np.ndarray  # (3,)
    up: np.ndarray  # (3,) the world's up in armature space (unit)
    lateral: np.ndarray  # (3,) the rest hip line (right to left) in armature space
    world_linear: np.ndarray  # (3, 3) the armature object's matrix_world linear part

    # Derived once per rest (the live follow converts every frame with the same one).
    @cached_property
    def floor_axes(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(the rest hip line on the floor (unit), the floor axis a quarter turn from it about the
        up, the rest hip line in the pelvis bone's frame)."""
        up = self.up
        e1 = self.lateral - np.dot(self.lateral, up) * up
        n = np.linalg.norm(e1)
        if n < 1e-9:
            raise BodyCalError("the rest hip line is vertical: the heading on the floor is undefined",
                               field="root_motion", hint="use --root-motion pelvis")
        e1 = e1 / n
        return e1, np.cross(up, e1), self.pelvis_matrix.T @ self.lateral

    @cached_property
    def up_terms(self) -> tuple[np.ndarray, np.ndarray]:
        """The up's cross-product matrix and outer product (Rodrigues' turn about it)."""
        a = self.up
        return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]]), np.outer(a, a)


def _turn_about(terms: tuple[np.ndarray, np.ndarray], angle: np.ndarray) -> np.ndarray:
    """(F, 3, 3) rotations by `angle` (F,) about a unit axis given by its `terms` (its cross-product
    matrix and outer product: Rodrigues)."""
    k, outer = terms
    c, s = np.cos(angle)[:, None, None], np.sin(angle)[:, None, None]
    return c * _EYE + s * k + (1.0 - c) * outer


_EYE = np.eye(3)


def pelvis_pose(anim: AvatarAnimation, rest: RootRest) -> tuple[np.ndarray, np.ndarray]:
    """(F, 3, 3) pose rotations and (F, 3) heads of the pelvis bone in armature space, with its
    ancestors at rest (the engine's output)."""
    b = anim.bone_names.index(anim.root_bone)
    P = rest.pelvis_matrix @ quat_to_matrix(np.asarray(anim.rotations[:, b], float))
    H = rest.pelvis_head + np.asarray(anim.root_location, float) @ rest.pelvis_matrix.T
    return P, H


def heading(P: np.ndarray, rest: RootRest) -> np.ndarray:
    """(F,) the pelvis's turn about the vertical since rest (radians, unwrapped): its hip line's
    direction on the floor. The hip line stays level when the trunk bends forward, so the heading
    holds through a bow where the pelvis's forward axis would tip towards the floor."""
    e1, e2, lat_local = rest.floor_axes
    lat = P @ lat_local
    angle = np.arctan2(lat @ e2, lat @ e1)
    return np.unwrap(angle) if len(angle) > 1 else angle


def apply_root_motion(anim: AvatarAnimation, rest: RootRest, mode: str, *, own: bool = False) -> AvatarAnimation:
    """`anim` (the engine's: travel on the pelvis) with its travel put where `mode` says. The
    result's `bone_locations` holds the root bone's location keys in `root` mode. `own`: the caller
    gives `anim` away, which is changed and returned (no copy of its rotations: a 10-minute take's
    are ~90 MB at the bake's peak)."""
    check_root_motion(mode)
    if mode == "pelvis" or (mode == "root" and rest.root_bone is None):
        return anim
    out = anim if own else copy.copy(anim)
    if not own:
        out.rotations = np.array(anim.rotations, float, copy=True)
    out.bone_locations = dict(anim.bone_locations)
    P, H = pelvis_pose(anim, rest)
    Mp, hp, up = rest.pelvis_matrix, rest.pelvis_head, rest.up
    pel = anim.bone_names.index(anim.root_bone)
    if mode == "in-place":
        drift = H - H[0]
        drift -= (drift @ up)[:, None] * up
        out.root_location = (H - drift - hp) @ Mp
        world_drift = (drift @ rest.world_linear.T).astype(np.float32)
        out.joints_world = {j: v - world_drift for j, v in anim.joints_world.items()}
        out.targets = {j: v - world_drift for j, v in anim.targets.items()}
        out.notes = [*anim.notes, "in place: the pelvis's horizontal travel removed"]
        return out
    Mr, hr = rest.root_matrix, rest.root_head
    D = _turn_about(rest.up_terms, heading(P, rest))
    Hr = H - ((H - hr) @ up)[:, None] * up  # on the root's rest floor, under the pelvis's head
    t = Hr - D @ hr
    Dt = np.swapaxes(D, -1, -2)
    # the pelvis's and the root's bases in one conversion (each item's quaternion is its own)
    bases = matrix_to_quat(np.concatenate([Mp.T @ Dt @ P, Mr.T @ D @ Mr]))
    out.rotations[:, pel] = bases[:len(P)]
    out.root_location = ((Dt @ (H - t - D @ hp)[..., None])[..., 0]) @ Mp
    root_basis = bases[len(P):]
    if rest.root_bone in anim.bone_names:
        out.rotations[:, anim.bone_names.index(rest.root_bone)] = root_basis
    else:
        out.bone_names = [*anim.bone_names, rest.root_bone]
        out.rotations = np.concatenate([out.rotations, root_basis[:, None]], axis=1)
    out.bone_locations[rest.root_bone] = (Hr - hr) @ Mr
    out.notes = [*anim.notes, f"root motion on '{rest.root_bone}'"]
    return out
