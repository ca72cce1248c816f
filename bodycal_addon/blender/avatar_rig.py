"""An avatar's armature object in Blender: its bone map (auto-detected, plus the user's overrides
stored on the object as `bodycal_bone_map` and `bodycal_hinge_axes`) and `read_rig(arm)`, which
reads the rest pose into the engine's `armature.ArmatureReading` (see `bodycal_addon/avatar/armature.py`
for the joint rules and the bones' `right`).

The overrides are the one place a bone map is kept: an edit (`edit_segment`: the panel's bone map
editor, Assign Bone) writes one segment, applying a preset (`apply_preset`, the panel's Apply,
`--bone-map`) writes every segment, so detection no longer decides anything for that armature
until Reset to Detected (`reset_to_detected`, Detect Bone Map with Reset). Each of them removes a
stored avatar model made with another map.
"""

from __future__ import annotations

import json

import numpy as np

from ..avatar.armature import HINGE_BONES, ArmatureReading, read_armature, settle_pelvis
from ..avatar.structure import map_by_structure
from ..body import naming
from ..body import skeleton as sk
from ..body.bone_presets import SINGLE_SEGMENTS, BonePreset, check_overrides, edit_overrides, map_with_overrides
from ..body.bone_presets import segment_value as segment_value  # re-exported (`X as X`): the bone map editor's
from ..body.naming import SCHEME_BY_NAME as SCHEME_BY_NAME  # re-exported: the editor names the detected scheme
from ..body.naming import BoneMap as BoneMap  # re-exported: the editor's state
from ..body.skeleton import CHAIN_SEGMENTS as CHAIN_SEGMENTS  # re-exported: the editor's rows
from ..body.skeleton import FINGERS as FINGERS  # re-exported: the editor's rows
from ..body.skeleton import SEGMENTS as SEGMENTS  # re-exported: the editor's rows
from ..body.skeleton import SIDES as SIDES  # re-exported: the editor's rows
from ..body.skeleton import required_segments as required_segments  # re-exported: the editor's rows
from ..core.errors import BodyCalError
from . import avatar_storage

BONE_MAP_PROP = "bodycal_bone_map"  # JSON {segment: avatar bone ("" = unmapped)}: user overrides
MODEL_DROPPED = "its avatar model was made with another bone map and was removed: Calibrate Avatar again"
HINGE_AXES_PROP = "bodycal_hinge_axes"  # JSON {canonical bone: [x, y, z] in the avatar bone's frame}


# --- bone map ------------------------------------------------------------------------------------

def load_overrides(arm) -> dict[str, str]:
    raw = arm.get(BONE_MAP_PROP)
    if not raw:
        return {}
    try:
        data = json.loads(raw)
    except (TypeError, ValueError):
        raise BodyCalError("the stored bone map is not valid JSON", source=arm.name, field=BONE_MAP_PROP,
                           hint="clear it with Detect Bone Map") from None
    return {str(k): str(v) for k, v in data.items()} if isinstance(data, dict) else {}


def set_override(arm, segment: str, bone: str | None) -> None:
    """Map `segment` to avatar bone `bone` (None/"" marks it unmapped; the spine and neck chains
    take a comma-separated list, bottom-up); saved with the armature."""
    if segment not in sk.SEGMENTS and segment not in sk.CHAIN_SEGMENTS:
        raise BodyCalError(f"'{segment}' is not a body segment", source=arm.name)
    names = [b.strip() for b in (bone or "").split(",") if b.strip()]
    if len(names) > 1 and segment not in sk.CHAIN_SEGMENTS:
        raise BodyCalError("only the spine and neck take several bones", source=arm.name, field=segment)
    for b in names:
        if b not in arm.data.bones:
            raise BodyCalError(f"armature has no bone '{b}'", source=arm.name, field=segment)
    bone = ",".join(names)
    ov = load_overrides(arm)
    ov[segment] = bone or ""
    arm[BONE_MAP_PROP] = json.dumps(ov)


def clear_overrides(arm) -> None:
    if BONE_MAP_PROP in arm:
        del arm[BONE_MAP_PROP]


# The names read too few segments to go on (at least this share of the required ones missing):
# the map comes from the rig's shape. A rig with one bone named its own way keeps its name-based
# map, and the bone map panel says which segment to assign.
STRUCTURE_WHEN_MISSING = 0.5


def bone_map_for(arm) -> naming.BoneMap:
    """Auto-detected map with the user's overrides applied (chains: comma-separated bone lists)."""
    overrides = load_overrides(arm)
    return map_with_overrides(arm.data.bones.keys(), overrides, detected=detected_map(arm, "pelvis" in overrides))


def detected_map(arm, pelvis_given: bool = False) -> naming.BoneMap:
    """The map detection gives the armature: by its bones' names, or by its shape when the names
    read too few segments (a COLLADA export's); the pelvis settled on the bone the thighs hang from
    unless the user gave it."""
    bm = naming.detect_bone_map([b.name for b in arm.data.bones])
    if len(bm.missing()) >= STRUCTURE_WHEN_MISSING * len(sk.required_segments()) and not is_rigify_generated(arm):
        bm = map_by_structure({b.name: (b.parent.name if b.parent else None, np.array(b.head_local))
                               for b in arm.data.bones}, armature_up(arm)) or bm
    if not pelvis_given:
        settle_pelvis(bm, skeleton_parents(arm))
    return bm


def edit_segment(arm, segment: str, value: str | None) -> tuple[naming.BoneMap, bool]:
    """One edit of the armature's map (the bone map editor, Assign Bone): `segment` set to `value`
    ("" unmaps it; the spine and neck take comma-separated bones, bottom-up) or given back to
    detection (None). Checked first (`edit_overrides`: one line, nothing changed); a stored avatar
    model made with the map before is removed, as by `apply_bone_map` (returns True)."""
    overrides = edit_overrides(arm.data.bones.keys(), load_overrides(arm), segment, value, source=arm.name)
    arm[BONE_MAP_PROP] = json.dumps(overrides)
    bm = bone_map_for(arm)
    return bm, _drop_stale_model(arm, bm)


def reset_to_detected(arm) -> tuple[naming.BoneMap, bool]:
    """Forget every override and preset: the map detection gives, and whether a stored avatar
    model made with another map was removed."""
    clear_overrides(arm)
    bm = bone_map_for(arm)
    return bm, _drop_stale_model(arm, bm)


def map_problem(arm) -> str | None:
    """What is wrong with the stored map as it is (a bone since renamed or deleted, a bone on two
    segments), as one line; None when nothing is."""
    try:
        check_overrides(arm.data.bones.keys(), load_overrides(arm), source=arm.name)
    except BodyCalError as exc:
        return exc.line()
    return None


def _drop_stale_model(arm, bm: naming.BoneMap) -> bool:
    """Remove a stored avatar model calibrated with a map other than `bm` (True when removed): it
    no longer fits the rig; the next calibration or bake measures it again."""
    if not avatar_storage.has_model(arm):
        return False
    try:
        stored = naming.BoneMap.from_dict(avatar_storage.load_model(arm).extra.get("rig", {}).get("bone_map", {}))
    except BodyCalError:  # damaged: the next calibration replaces it anyway
        return False
    if stored.same_mapping(bm):
        return False
    avatar_storage.clear_model(arm)
    return True


def apply_bone_map(arm, bm: naming.BoneMap) -> bool:
    """Make `bm` the armature's bone map: every segment is written to the overrides ("" where it
    maps nothing). An avatar model stored on the armature that was calibrated with another map no
    longer fits it and is removed (returns True): the next calibration or bake measures it again."""
    missing = [b for b in [*bm.bones.values(), *(b for c in bm.chains.values() for b in c)]
               if b not in arm.data.bones]
    if missing:
        raise BodyCalError(f"armature has no bone '{missing[0]}'", source=arm.name)
    ov = {seg: bm.bones.get(seg, "") for seg in SINGLE_SEGMENTS}
    ov |= {chain: ",".join(bm.chains.get(chain, [])) for chain in sk.CHAIN_SEGMENTS}
    arm[BONE_MAP_PROP] = json.dumps(ov)
    return _drop_stale_model(arm, bm)


def apply_preset(arm, preset: BonePreset) -> tuple[naming.BoneMap, bool]:
    """Resolve `preset` on the armature's bones and store the result (`apply_bone_map`): the map,
    and whether a stored avatar model made with another map was removed."""
    if arm is None or getattr(arm, "type", None) != "ARMATURE":
        raise BodyCalError("not an armature object", source=getattr(arm, "name", "object"))
    bm = preset.resolve([b.name for b in arm.data.bones])
    if not bm.bones and not any(bm.chains.values()):  # would wipe the working map for nothing
        raise BodyCalError(f"bone map preset '{preset.name}' maps none of its bones", source=arm.name,
                           hint="pick the preset of this rig's naming scheme, or Import a map made for it")
    return bm, apply_bone_map(arm, bm)


def hinge_overrides(arm) -> dict[str, np.ndarray]:
    raw = arm.get(HINGE_AXES_PROP)
    if not raw:
        return {}
    try:
        return {k: np.asarray(v, float) for k, v in json.loads(raw).items()}
    except (TypeError, ValueError):
        raise BodyCalError("stored hinge axes are not valid JSON", source=arm.name, field=HINGE_AXES_PROP) from None


def set_hinge_axis(arm, canonical_bone: str, local_axis) -> None:
    """Override a hinge's flexion axis, given in the mapped avatar bone's local frame."""
    if canonical_bone not in HINGE_BONES:
        raise BodyCalError(f"'{canonical_bone}' is not a hinge bone ({', '.join(HINGE_BONES[:3])}, ...)",
                           source=arm.name)
    axes = {k: v.tolist() for k, v in hinge_overrides(arm).items()}
    axes[canonical_bone] = [float(x) for x in local_axis]
    arm[HINGE_AXES_PROP] = json.dumps(axes)


# --- reading the rig -----------------------------------------------------------------------------


def is_rigify_generated(arm) -> bool:
    """A rig Rigify generated (not its metarig): Rigify's `rig_id` on the armature data, or its
    DEF-/ORG- pair of spines where a file lost the property."""
    bones = arm.data.bones
    if "DEF-spine" not in bones:
        return False
    return bool(arm.data.get("rig_id")) or "ORG-spine" in bones


def deform_parents(arm) -> dict[str, str | None]:
    """The DEF- bones of a generated Rigify rig (and its `root`) as a skeleton of their own: each
    DEF- bone's parent is its nearest ancestor that is a DEF- bone, an ORG- bone standing for its
    DEF- twin (ORG-spine -> DEF-spine), or the root. Rigify parents DEF- bones to ORG- and MCH-
    bones that its constraints move; at rest both skeletons are the same, so this one calibrates
    and retargets exactly, and blender/rig_output.py puts the result on the rig's controls."""
    bones = arm.data.bones
    out: dict[str, str | None] = {}
    for b in bones:
        if not b.name.startswith("DEF-") and b.name != "root":
            continue
        p = b.parent
        while p is not None:
            twin = "DEF-" + p.name[4:] if p.name.startswith("ORG-") else None
            if p.name.startswith("DEF-") or p.name == "root":
                break
            if twin and twin in bones and twin != b.name:
                p = bones[twin]
                break
            p = p.parent
        out[b.name] = p.name if p is not None else None
    return out


def armature_up(arm) -> np.ndarray:
    """The world's up in the armature's space (an FBX import's bones stand along its Y)."""
    up = np.linalg.solve(np.array(arm.matrix_world, float)[:3, :3], np.array([0.0, 0.0, 1.0]))
    return up / np.linalg.norm(up)


def skeleton_parents(arm) -> dict[str, str | None]:
    """Each bone's parent in the skeleton the engine reads: the armature's own, or for a generated
    Rigify rig its DEF- skeleton (`deform_parents`)."""
    if is_rigify_generated(arm):
        return deform_parents(arm)
    return {b.name: b.parent.name if b.parent else None for b in arm.data.bones}


def read_rig(arm, bone_map: naming.BoneMap | None = None) -> ArmatureReading:
    """Canonical joints and bone rights of an armature object in its rest pose (a generated Rigify
    rig: of its DEF- bones, `deform_parents`)."""
    if arm is None or getattr(arm, "type", None) != "ARMATURE":
        raise BodyCalError("not an armature object", source=getattr(arm, "name", "object"))
    bm = bone_map or bone_map_for(arm)
    parents = skeleton_parents(arm)
    rest = {name: {"parent": parent, "head": np.array(arm.data.bones[name].head_local[:]),
                   "tail": np.array(arm.data.bones[name].tail_local[:]),
                   "matrix": np.array([arm.data.bones[name].matrix_local[i][:3] for i in range(3)], dtype=float)}
            for name, parent in parents.items()}
    return read_armature(arm.name, np.array([row[:] for row in arm.matrix_world], dtype=float), rest, bm,
                         hinge_overrides(arm))
