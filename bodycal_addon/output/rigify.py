"""Rigify's generated rig (DESIGN.md §1 "Rigify", FORMATS.md §4.4). Numpy only.

The engine calibrates and animates a generated rig on its DEF- bones read as a skeleton of their
own (blender/avatar_rig.deform_parents). The result then goes onto the rig itself, one of two ways:

- `fk` (the default, for animators): the FK controls (torso, spine, neck, head, shoulders, limb FK
  chains, fingers) are keyed so that, through Rigify's own constraints, the DEF- bones land where
  the engine put them; IK is switched to FK by the rig's `IK_FK` properties (1 = FK).
- `def` (for export): the DEF- bones themselves are keyed and their constraints muted, so the
  deform skeleton plays the engine's pose exactly and exporters see plain keys.

Both solve the same problem: absolute armature-space targets T_c (F, 4, 4) for a set of keyed
bones, through Blender's pose rule pose_c = pose_parent @ (rest_parent^-1 @ rest_c) @ basis_c, so
basis_c = (pose_parent @ rest_parent^-1 @ rest_c)^-1 @ T_c. A bone that is not keyed moves as its
`Rule` says: rigidly with its parent (no rule), as a copy of another bone (a Copy Transforms
constraint at full influence: Rigify's ORG- bones copying the FK chain), blended half-way between
its own place and another bone's (a Copy Transforms at partial influence: the spine's pivot), or
with another bone as if parented (an Armature constraint: the torso's parent follows the root).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.errors import BodyCalError
from ..core.transforms import matrix_to_quat, quat_between, quat_to_matrix, slerp

RIGIFY_TARGETS = ("fk", "def")  # the default first


def check_rigify_target(target: str) -> str:
    if target not in RIGIFY_TARGETS:
        raise BodyCalError(f"unknown Rigify target '{target}'", field="rigify_target",
                           hint=f"use one of {', '.join(RIGIFY_TARGETS)}")
    return target


# FK control -> the DEF- bone it follows (sides as {S}). The spine: the torso carries the pelvis
# and the lower spine FK controls stay at rest (the pelvis moves rigidly with the torso); the
# upper FK controls take the chest, the tweaks between them the middle vertebrae.
FK_CONTROLS = {
    "root": "root", "torso": "DEF-spine", "tweak_spine.001": "DEF-spine.001", "spine_fk.002": "DEF-spine.002",
    "tweak_spine.002": "DEF-spine.002", "spine_fk.003": "DEF-spine.003", "neck": "DEF-spine.004",
    "head": "DEF-spine.006",
    "shoulder.{S}": "DEF-shoulder.{S}", "upper_arm_fk.{S}": "DEF-upper_arm.{S}", "forearm_fk.{S}": "DEF-forearm.{S}",
    "hand_fk.{S}": "DEF-hand.{S}", "upper_arm_tweak.{S}": "DEF-upper_arm.{S}", "thigh_tweak.{S}": "DEF-thigh.{S}",
    "thigh_fk.{S}": "DEF-thigh.{S}", "shin_fk.{S}": "DEF-shin.{S}",
    "foot_fk.{S}": "DEF-foot.{S}", "toe_fk.{S}": "DEF-toe.{S}",
    **{f"{f}.0{i}.{{S}}": f"DEF-{f}.0{i}.{{S}}" for f in ("thumb", "f_index", "f_middle", "f_ring", "f_pinky")
       for i in (1, 2, 3)},
}
# Rig switches keyed with an FK bake: (pose bone, custom property) -> value. IK_FK = 1 is FK; the
# neck and head follow their parents (Rigify's default lets them keep part of the torso's turn).
FK_SWITCHES = {("upper_arm_parent.{S}", "IK_FK"): 1.0, ("thigh_parent.{S}", "IK_FK"): 1.0,
               ("torso", "neck_follow"): 0.0, ("torso", "head_follow"): 1.0}


def sided(name: str) -> list[str]:
    return [name.replace("{S}", s) for s in ("L", "R")] if "{S}" in name else [name]


@dataclass(frozen=True)
class Rule:
    """One constraint of an unkeyed bone, applied in the stack's order after it followed its parent
    (see the module docstring): "copy" (Copy Transforms), "rotation" (Copy Rotation), "location"
    (Copy Location, at `head_tail` along the target), "track" (Damped Track of +Y towards the
    target's point at `head_tail`), "child_of" (an Armature constraint's heaviest target)."""

    kind: str
    target: str
    influence: float = 1.0
    head_tail: float = 0.0


def rest_matrix(matrix3: np.ndarray, head: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = matrix3
    m[:3, 3] = head
    return m


def basis_matrices(rotations: np.ndarray, locations: np.ndarray | None = None) -> np.ndarray:
    """(F, ..., 4, 4) Blender's matrix_basis from quaternions (F, ..., 4) and locations (F, ..., 3)."""
    out = np.zeros(rotations.shape[:-1] + (4, 4))
    out[..., :3, :3] = quat_to_matrix(np.asarray(rotations, float))
    if locations is not None:
        out[..., :3, 3] = locations
    out[..., 3, 3] = 1.0
    return out


def pose_matrices(names: list[str], parents: dict[str, str | None], rest: dict[str, np.ndarray],
                  basis: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Blender's pose (armature space, (F, 4, 4) per bone) of a plain hierarchy from each bone's
    matrix_basis (`basis`: (F, 4, 4)); `names` parents first."""
    out: dict[str, np.ndarray] = {}
    for n in names:
        p = parents.get(n)
        local = rest[n] if p is None else np.linalg.inv(rest[p]) @ rest[n]
        out[n] = (local if p is None else out[p] @ local) @ basis[n]
    return out


def _blend(a: np.ndarray, b: np.ndarray, t: float) -> np.ndarray:
    """Blender's constraint blend of two matrices: locations mixed, rotations slerped."""
    out = np.array(a, copy=True)
    out[..., :3, 3] = (1 - t) * a[..., :3, 3] + t * b[..., :3, 3]
    qa, qb = matrix_to_quat(a[..., :3, :3]), matrix_to_quat(b[..., :3, :3])
    out[..., :3, :3] = quat_to_matrix(slerp(qa, qb, np.full(qa.shape[:-1], t)))
    return out


def solve_basis(targets: dict[str, np.ndarray], rest: dict[str, np.ndarray], parents: dict[str, str | None],
                rules: dict[str, list[Rule]], frames: int, lengths: dict[str, float] | None = None
                ) -> dict[str, np.ndarray]:
    """matrix_basis (F, 4, 4) of every keyed bone (`targets`: absolute armature-space poses) on the
    rig's real hierarchy, unkeyed bones moving as their rules say."""
    memo: dict[str, np.ndarray] = {}
    lengths = lengths or {}

    def pose(n: str, depth: int = 0) -> np.ndarray:
        if n in targets:
            return targets[n]
        if n in memo:
            return memo[n]
        if depth > 512:
            raise BodyCalError(f"bone '{n}' depends on itself through its constraints", field="rig")
        p = parents.get(n)
        own = (np.broadcast_to(rest[n], (frames, 4, 4)) if p is None
               else pose(p, depth + 1) @ (np.linalg.inv(rest[p]) @ rest[n]))
        for rule in rules.get(n, ()):
            other = pose(rule.target, depth + 1)
            if rule.kind == "child_of":
                own = other @ (np.linalg.inv(rest[rule.target]) @ rest[n])
                continue
            new = np.array(own, copy=True)
            if rule.kind == "copy":
                new = np.array(other, copy=True)
            elif rule.kind == "rotation":
                new[..., :3, :3] = other[..., :3, :3]
            elif rule.kind == "location":
                new[..., :3, 3] = other[..., :3, 3] + rule.head_tail * lengths.get(rule.target, 0.0) * other[..., :3, 1]
            elif rule.kind == "track":
                point = other[..., :3, 3] + rule.head_tail * lengths.get(rule.target, 0.0) * other[..., :3, 1]
                turn = quat_to_matrix(quat_between(own[..., :3, 1], point - own[..., :3, 3]))
                new[..., :3, :3] = turn @ own[..., :3, :3]
            own = new if rule.influence > 0.999 else _blend(own, new, rule.influence)
        memo[n] = own
        return own

    out = {}
    for n, target in targets.items():
        p = parents.get(n)
        frame = rest[n] if p is None else pose(p) @ (np.linalg.inv(rest[p]) @ rest[n])
        out[n] = np.linalg.inv(frame) @ target
    return out


def basis_values(basis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(F, 4) quaternions and (F, 3) locations of matrix_basis stacks (F, 4, 4)."""
    rot = basis[..., :3, :3]
    u, _, vt = np.linalg.svd(rot)  # the nearest rotation: products of float32 rests drift by ~1e-7
    return matrix_to_quat(u @ vt), np.array(basis[..., :3, 3])
