"""Limb bones keyed in the armature's space (DESIGN.md §2, "Rigs as files bring them"): a game rig
whose foot (or hand) is an IK control beside the limb (RobotExpressive: `Foot.L` under the root
bone, the leg reaching it through a constraint a glTF file does not keep) is posed by the engine as
if the foot hung from the shin (avatar/armature.loose_limb_bones). Blender poses it from its real
parent, so the bake keys it the way game exporters key IK feet: its location and rotation such that
its pose in the armature's space is the engine's,

    basis = (M_p^-1 M_b)^-1 P_p^-1 P_b,

P the bones' poses in armature space (Blender's pose rule, output/rigify.pose_matrices), M their
rests, p the bone's parent in the file (none: M_p = P_p = identity). Numpy only; the Blender side
reads the rig (blender/rig_output.armature_space_plan).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from ..body.animation import AvatarAnimation
from .rigify import basis_matrices, basis_values, pose_matrices


@dataclass
class ArmatureSpacePlan:
    """What keying loose limb bones needs, read once from the rig."""

    bones: dict[str, str]  # loose bone -> the limb bone the engine hangs it from
    parents: dict[str, str | None]  # every bone's parent in the file
    rest: dict[str, np.ndarray]  # every bone's rest (4, 4), armature space (bone.matrix_local)
    local_location: dict[str, bool]  # loose bone -> its location is in its own rest frame (Blender's default)

    def note(self) -> str:
        names = ", ".join(f"'{b}'" for b in self.bones)
        return (f"{names}: keyed with location and rotation in the armature's space (IK controls beside the "
                "limb in the file, posed from the limb as the engine solved it)")


def _engine_parents(plan: ArmatureSpacePlan) -> dict[str, str | None]:
    return {n: plan.bones.get(n, p) for n, p in plan.parents.items()}


def _chain(bone: str | None, parents: dict[str, str | None]) -> list[str]:
    out = []
    while bone is not None and bone not in out:
        out.append(bone)
        bone = parents.get(bone)
    return out[::-1]


def keyed_in_armature_space(anim: AvatarAnimation, plan: ArmatureSpacePlan | None) -> AvatarAnimation:
    """`anim` (the engine's pose bones, its travel where the bake puts it) with each loose bone's
    rotation and location made relative to its parent in the file; a bone `anim` already keys a
    location of is taken as done. A copy; `anim` is not changed."""
    if plan is None:
        return anim
    todo = [b for b in plan.bones if b in anim.bone_names and b not in anim.bone_locations]
    if not todo:
        return anim
    engine = _engine_parents(plan)
    needed: list[str] = []
    for b in todo:  # the bone and its real parent, each with its ancestors as the engine poses them
        for n in _chain(b, engine) + _chain(plan.parents.get(b), engine):
            if n not in needed:
                needed.append(n)
    depth = {n: len(_chain(n, engine)) for n in needed}
    needed.sort(key=depth.__getitem__)  # parents first
    index = {n: i for i, n in enumerate(anim.bone_names)}
    frames = anim.frame_count
    basis = {}
    for n in needed:
        loc = anim.root_location if n == anim.root_bone else anim.bone_locations.get(n)
        basis[n] = (basis_matrices(anim.rotations[:, index[n]], loc) if n in index
                    else np.broadcast_to(np.eye(4), (frames, 4, 4)))  # a bone the bake does not key: at rest
    poses = pose_matrices(needed, engine, plan.rest, basis)
    out = copy.copy(anim)
    out.rotations = np.array(anim.rotations, copy=True)
    out.bone_locations = dict(anim.bone_locations)
    for b in todo:
        p = plan.parents.get(b)
        offset = plan.rest[b] if p is None else np.linalg.inv(plan.rest[p]) @ plan.rest[b]
        in_parent = poses[b] if p is None else np.linalg.solve(poses[p], poses[b])
        quat, loc = basis_values(np.linalg.solve(offset, in_parent))
        if not plan.local_location[b]:  # Local Location off: the location is along the parent's axes
            loc = loc @ offset[:3, :3].T
        out.rotations[:, index[b]] = quat
        out.bone_locations[b] = loc
    out.notes = [*anim.notes, plan.note()]
    return out
