"""What the bake keys on the armature besides the engine's own pose bones (DESIGN.md §1, "Root
motion" and "Rigify"): where the travel goes (root motion, `retarget/root_motion.py`) read off
the armature object's rest pose, limb bones beside the limb (a game rig's IK feet) keyed in the
armature's space (`output/armature_space.py`), and a generated Rigify rig's DEF- pose carried onto
its FK controls or its DEF- bones (`retarget/rigify.py`).
"""

from __future__ import annotations

import copy

import bpy
import numpy as np

from ..avatar.armature import loose_limb_bones
from ..body import naming
from ..body.animation import AvatarAnimation
from ..core.errors import BodyCalError
from ..output import rigify
from ..output.armature_space import ArmatureSpacePlan, keyed_in_armature_space
from ..output.root_motion import RootRest, apply_root_motion, check_root_motion
from . import avatar_rig


def _rest(obj, name: str) -> tuple[np.ndarray, np.ndarray]:
    b = obj.data.bones[name]
    return np.array([b.matrix_local[i][:3] for i in range(3)], float), np.array(b.head_local[:], float)


def root_bone_of(obj, pelvis: str, bone_map: naming.BoneMap) -> str | None:
    """The bone map's `root` bone when it is an ancestor of `pelvis` (it carries the travel)."""
    root = bone_map.bones.get("root")
    if not root or root == pelvis or root not in obj.data.bones or pelvis not in obj.data.bones:
        return None
    parent = obj.data.bones[pelvis].parent
    while parent is not None:
        if parent.name == root:
            return root
        parent = parent.parent
    return None


def root_rest(obj, anim: AvatarAnimation, bm: naming.BoneMap) -> RootRest:
    lin = np.array(obj.matrix_world, float)[:3, :3]
    up = np.linalg.solve(lin, np.array([0.0, 0.0, 1.0]))
    lateral = np.zeros(3)
    if bm.bones.get("thigh_l") in obj.data.bones and bm.bones.get("thigh_r") in obj.data.bones:
        lateral = _rest(obj, bm.bones["thigh_l"])[1] - _rest(obj, bm.bones["thigh_r"])[1]
    root = root_bone_of(obj, anim.root_bone, bm)
    rm, rh = _rest(obj, root) if root else (None, None)
    pm, ph = _rest(obj, anim.root_bone)
    return RootRest(root, rm, rh, pm, ph, up / np.linalg.norm(up), lateral, lin)


def with_root_motion(anim: AvatarAnimation, obj, bone_map: naming.BoneMap, mode: str, own: bool = False
                     ) -> AvatarAnimation:
    """The travel where `mode` says (output/root_motion.py), on the bones `bone_map` (the one the
    animation was solved with) names."""
    check_root_motion(mode)
    if mode == "pelvis":
        return anim
    return apply_root_motion(anim, root_rest(obj, anim, bone_map), mode, own=own)


# --- limb bones beside the limb: keyed in the armature's space (output/armature_space.py) -------------

def armature_space_plan(obj, bone_map: naming.BoneMap) -> ArmatureSpacePlan | None:
    """What keying the rig's loose limb bones (IK controls beside the limb) needs; None when every
    limb bone hangs from the one before it (most rigs) or the map lacks a limb."""
    if avatar_rig.is_rigify_generated(obj):  # its DEF- bones hang in order (avatar_rig.deform_parents)
        return None
    parents = {b.name: b.parent.name if b.parent else None for b in obj.data.bones}
    try:
        loose = loose_limb_bones(obj.name, bone_map, parents)
    except (KeyError, BodyCalError):  # a map the avatar's reading refuses (or lacking a limb): nothing to key
        return None
    if not loose or not set(loose) <= set(parents):
        return None
    return ArmatureSpacePlan(loose, parents, {n: _rest4(obj, n) for n in parents},
                             {n: bool(obj.data.bones[n].use_local_location) for n in loose})


def with_armature_space(anim: AvatarAnimation, obj, bone_map: naming.BoneMap) -> AvatarAnimation:
    """`anim` with the rig's loose limb bones keyed in the armature's space (unchanged on most rigs)."""
    return keyed_in_armature_space(anim, armature_space_plan(obj, bone_map))


# --- a generated Rigify rig (retarget/rigify.py) ----------------------------------------------------

def _rest4(obj, name: str) -> np.ndarray:
    m, h = _rest(obj, name)
    return rigify.rest_matrix(m, h)


def _rules(obj) -> dict[str, list[rigify.Rule]]:
    """What each bone's constraints do, read from the evaluated rig (drivers set the influences,
    e.g. IK_FK switches the ORG- bones' Copy Transforms from the IK chain to the FK one)."""
    ev = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    kinds = {"COPY_TRANSFORMS": "copy", "COPY_ROTATION": "rotation", "COPY_LOCATION": "location",
             "DAMPED_TRACK": "track"}
    rules: dict[str, list[rigify.Rule]] = {}
    for pb in ev.pose.bones:
        for c in pb.constraints:
            on = getattr(c, "enabled", not getattr(c, "mute", False))
            if not on or c.influence < 1e-6:
                continue
            if c.type == "ARMATURE":
                live = [t for t in c.targets if t.subtarget and t.weight > 1e-6]
                if live:
                    rules.setdefault(pb.name, []).append(
                        rigify.Rule("child_of", max(live, key=lambda t: t.weight).subtarget))
                continue
            target = getattr(c, "target", None)
            if c.type not in kinds or target is None or target.name != obj.name or not c.subtarget:
                continue
            if c.type != "DAMPED_TRACK" and (c.target_space != "WORLD" or c.owner_space != "WORLD"):
                continue  # local-space copies (the spine's hips and chest halves) act on controls left at rest
            if c.type == "COPY_ROTATION" and (c.mix_mode != "REPLACE" or not (c.use_x and c.use_y and c.use_z)):
                continue
            if c.type == "DAMPED_TRACK" and c.track_axis != "TRACK_Y":
                continue
            rules.setdefault(pb.name, []).append(rigify.Rule(kinds[c.type], c.subtarget, float(c.influence),
                                                             float(getattr(c, "head_tail", 0.0))))
    return rules


DEF_MUTED_PROP = "bodycal_def_muted"  # set on a Rigify rig whose DEF- constraints a DEF bake muted


def mute_deform(obj, mute: bool) -> None:
    """Mute (or unmute) the constraints of the rig's DEF- bones, and say so on the object."""
    for pb in obj.pose.bones:
        if pb.name.startswith("DEF-"):
            for c in pb.constraints:
                c.mute = mute
    if mute:
        obj[DEF_MUTED_PROP] = 1
    elif DEF_MUTED_PROP in obj:
        del obj[DEF_MUTED_PROP]


def rigify_deform_pose(anim: AvatarAnimation, obj, parents: dict | None = None, rest: dict | None = None
                       ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """(armature-space poses (F, 4, 4) of the DEF- skeleton the engine animated, their rests).
    `parents` (avatar_rig.deform_parents) and `rest` (bone -> 4x4 rest) when already read."""
    parents = avatar_rig.deform_parents(obj) if parents is None else parents
    names = [n for n in anim.bone_names if n in parents]
    rest = {n: _rest4(obj, n) for n in names} if rest is None else {n: rest[n] for n in names}
    index = {n: i for i, n in enumerate(anim.bone_names)}
    basis = {}
    for n in names:
        loc = anim.root_location if n == anim.root_bone else anim.bone_locations.get(n)
        basis[n] = rigify.basis_matrices(anim.rotations[:, index[n]], loc)
    return rigify.pose_matrices(names, parents, rest, basis), rest


CHUNK_FRAMES = 2000


def _frames(anim: AvatarAnimation, start: int, stop: int) -> AvatarAnimation:
    part = copy.copy(anim)
    part.rotations, part.root_location = anim.rotations[start:stop], anim.root_location[start:stop]
    part.time = anim.time[start:stop]
    part.bone_locations = {k: v[start:stop] for k, v in anim.bone_locations.items()}
    return part


def rigify_animation(anim: AvatarAnimation, obj, target: str) -> AvatarAnimation:
    """The engine's animation of a generated Rigify rig's DEF- skeleton, as keys on the rig itself:
    its FK controls (`fk`, the rig switched to FK) or its DEF- bones (`def`, their constraints
    muted). Sets the pose of every other bone to rest, the switches and the mutes on the rig."""
    return RigifyPlan(obj, target, anim.bone_names).animation(anim)


class RigifyPlan:
    """What carrying a DEF- pose onto a generated Rigify rig needs, read once (`rigify_animation`
    for a take; the live follow for every frame): the rig set up for `target` (every pose bone at
    rest, the FK switches or the DEF- mutes), the controls paired with the DEF- bones the engine
    animates (`bone_names`), the rests, parents, lengths and constraint rules."""

    def __init__(self, obj, target: str, bone_names):
        rigify.check_rigify_target(target)
        self.obj, self.target = obj, target
        bones = obj.data.bones
        self.deform = avatar_rig.deform_parents(obj)
        for pb in obj.pose.bones:  # an unkeyed control keeps its pose in a new action: rest it
            pb.location = (0.0, 0.0, 0.0)
            pb.rotation_quaternion = (1.0, 0.0, 0.0, 0.0)
            pb.rotation_euler = (0.0, 0.0, 0.0)
            pb.scale = (1.0, 1.0, 1.0)
        if target == "fk":
            if obj.get(DEF_MUTED_PROP):  # a DEF bake muted them: the controls drive the DEF- bones again
                mute_deform(obj, False)
            for (bone_t, prop), value in rigify.FK_SWITCHES.items():
                for bone in rigify.sided(bone_t):
                    if bone in obj.pose.bones and prop in obj.pose.bones[bone]:
                        obj.pose.bones[bone][prop] = value
            self.pairs = [(c, d) for ct, dt in rigify.FK_CONTROLS.items()
                          for c, d in zip(rigify.sided(ct), rigify.sided(dt)) if c in bones and d in self.deform
                          and d in bone_names]
        else:
            mute_deform(obj, True)
            self.pairs = [(n, n) for n in self.deform if n.startswith("DEF-") and n in bone_names]
        bpy.context.view_layer.update()
        self.rest = {b.name: _rest4(obj, b.name) for b in bones}
        self.parents = {b.name: b.parent.name if b.parent else None for b in bones}
        self.lengths = {b.name: b.length for b in bones}
        self.rules = _rules(obj)
        self.names = [c for c, _d in self.pairs]
        self.root = "torso" if target == "fk" and "torso" in self.names else self.names[0]
        self.located = [n for n in self.names if n != self.root and not bones[n].use_connect]
        self.switches = {}
        if target == "fk":
            for (bone_t, prop), value in rigify.FK_SWITCHES.items():
                for bone in rigify.sided(bone_t):
                    if bone in obj.pose.bones and prop in obj.pose.bones[bone]:
                        self.switches[f'pose.bones["{bpy.utils.escape_identifier(bone)}"]["{prop}"]'] = float(value)

    def animation(self, anim: AvatarAnimation) -> AvatarAnimation:
        """`anim` (the DEF- skeleton's) as the controls' (or DEF- bones') values."""
        quats = np.empty((anim.frame_count, len(self.names), 4))
        locs = np.empty((anim.frame_count, len(self.names), 3))
        for start in range(0, anim.frame_count, CHUNK_FRAMES):  # (F, 4, 4) per bone: bounded memory on long takes
            stop = min(anim.frame_count, start + CHUNK_FRAMES)
            poses, _ = rigify_deform_pose(_frames(anim, start, stop), self.obj, self.deform, self.rest)
            targets = {c: poses[d] @ (np.linalg.inv(self.rest[d]) @ self.rest[c]) for c, d in self.pairs}
            basis = rigify.solve_basis(targets, self.rest, self.parents, self.rules, stop - start, self.lengths)
            for k, n in enumerate(self.names):
                quats[start:stop, k], locs[start:stop, k] = rigify.basis_values(basis[n])
        values = {n: (quats[:, k], locs[:, k]) for k, n in enumerate(self.names)}
        located = {n: values[n][1] for n in self.located}
        note = f"Rigify rig: keys on its {'FK controls' if self.target == 'fk' else 'DEF- bones'}"
        return AvatarAnimation(anim.armature, list(self.names), np.stack([values[n][0] for n in self.names], axis=1),
                               self.root, values[self.root][1], anim.time, anim.method, anim.joints_world,
                               anim.targets, [*anim.notes, note], located, dict(self.switches))


def controls_drive_deform(obj) -> bool:
    """Whether a generated Rigify rig's controls still move its DEF- bones: only its constraints
    do (DEF- follows ORG-, ORG- the FK or IK chain). A rig exported and imported again (glTF, FBX:
    a game engine's round trip) keeps every bone and none of the constraints, so its FK controls
    drive nothing and only its DEF- bones deform the mesh."""
    return any(pb.constraints for pb in obj.pose.bones if pb.name.startswith(("DEF-", "ORG-", "MCH-")))


ROUND_TRIP_NOTE = ("Rigify rig without its constraints (exported and imported again): its controls drive nothing, "
                   "so the keys are on its DEF- bones, the ones that deform the mesh")


def for_bake(anim: AvatarAnimation, obj, bone_map: naming.BoneMap, root_motion: str, rigify_target: str,
             own: bool = False) -> AvatarAnimation:
    """The animation the bake keys on `obj`: travel where `root_motion` says, and a generated
    Rigify rig's DEF- pose carried onto its controls or DEF- bones (its DEF- bones whatever
    `rigify_target` says when its constraints are gone, `controls_drive_deform`). `bone_map`: the
    map the animation was solved with (the avatar model's). `own`: `anim` is given away and may be
    changed in place."""
    anim = with_root_motion(anim, obj, bone_map, root_motion, own)
    anim = with_armature_space(anim, obj, bone_map)
    if avatar_rig.is_rigify_generated(obj):
        if rigify_target == "fk" and not controls_drive_deform(obj):
            anim = rigify_animation(anim, obj, "def")
            anim.notes[-1] = ROUND_TRIP_NOTE
        else:
            anim = rigify_animation(anim, obj, rigify_target)
    return anim
