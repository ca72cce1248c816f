"""The rigs users bring (DESIGN.md §2, "Naming schemes"): one sample avatar (MPFB2 adult_male)
rebuilt with the bone names of VRoid, Daz Genesis 8 (with its hip/pelvis pair and Bend/Twist limbs),
Character Creator (with its side-branch twist bones), Unity and numbered Mixamo. Detection needs no
manual step and the calibrated avatar model and the retargeted animation are those of the original.
A rig whose names no scheme knows is mapped with a preset (`--bone-map`, the panel's Import/Apply),
and a bad preset is one line with exit 2."""

from __future__ import annotations

import json
import subprocess
import sys

import bpy
import numpy as np
import pytest
import ui_layout
from repo_paths import REPO

from bodycal_addon.blender import avatar_calibration as ac
from bodycal_addon.blender import avatar_rig, avatar_storage
from bodycal_addon.body import naming
from bodycal_addon.body import skeleton as sk
from bodycal_addon.body.bodymodel import BodyModel
from bodycal_addon.body.bone_presets import BonePreset, preset_from_bone_map
from bodycal_addon.core import paths
from bodycal_addon.retarget.pipeline import retarget
from bodycal_dev import synthetic

rigs = paths.sample_rigs()
FINGER_WORDS = {"thumb": "Thumb", "index": "Index", "middle": "Middle", "ring": "Ring", "pinky": "Pinky"}


def renames(scheme: str) -> dict[str, str]:
    """The sample rig's Unreal-style names -> the convention's."""
    out = {}
    if scheme == "vroid":
        out |= {"pelvis": "J_Bip_C_Hips", "spine_01": "J_Bip_C_Spine", "spine_02": "J_Bip_C_Chest",
                "spine_03": "J_Bip_C_UpperChest", "neck_01": "J_Bip_C_Neck", "head": "J_Bip_C_Head"}
        limb = {"clavicle": "Shoulder", "upperarm": "UpperArm", "lowerarm": "LowerArm", "hand": "Hand",
                "thigh": "UpperLeg", "calf": "LowerLeg", "foot": "Foot", "ball": "ToeBase"}
        for s, side in (("l", "L"), ("r", "R")):
            out |= {f"{b}_{s}": f"J_Bip_{side}_{v}" for b, v in limb.items()}
            out |= {f"{f}_0{i}_{s}": f"J_Bip_{side}_{'Little' if f == 'pinky' else FINGER_WORDS[f]}{i}"
                    for f in sk.FINGERS for i in (1, 2, 3)}
    elif scheme == "daz_genesis8":
        out |= {"Root": "Genesis8Male", "pelvis": "hip", "spine_01": "abdomenLower", "spine_02": "abdomenUpper",
                "spine_03": "chestLower", "neck_01": "neckLower", "head": "head"}
        limb = {"clavicle": "Collar", "upperarm": "ShldrBend", "lowerarm": "ForearmBend", "hand": "Hand",
                "thigh": "ThighBend", "calf": "Shin", "foot": "Foot", "ball": "Toe"}
        words = {"thumb": "Thumb", "index": "Index", "middle": "Mid", "ring": "Ring", "pinky": "Pinky"}
        for s in ("l", "r"):
            out |= {f"{b}_{s}": f"{s}{v}" for b, v in limb.items()}
            out |= {f"{f}_0{i}_{s}": f"{s}{words[f]}{i}" for f in sk.FINGERS for i in (1, 2, 3)}
    elif scheme == "character_creator":
        out |= {"Root": "CC_Base_BoneRoot", "pelvis": "CC_Base_Hip", "spine_01": "CC_Base_Waist",
                "spine_02": "CC_Base_Spine01", "spine_03": "CC_Base_Spine02", "neck_01": "CC_Base_NeckTwist01",
                "head": "CC_Base_Head"}
        limb = {"clavicle": "Clavicle", "upperarm": "Upperarm", "lowerarm": "Forearm", "hand": "Hand",
                "thigh": "Thigh", "calf": "Calf", "foot": "Foot", "ball": "ToeBase"}
        words = {"thumb": "Thumb", "index": "Index", "middle": "Mid", "ring": "Ring", "pinky": "Pinky"}
        for s, side in (("l", "L"), ("r", "R")):
            out |= {f"{b}_{s}": f"CC_Base_{side}_{v}" for b, v in limb.items()}
            out |= {f"{f}_0{i}_{s}": f"CC_Base_{side}_{words[f]}{i}" for f in sk.FINGERS for i in (1, 2, 3)}
    elif scheme == "vrm_humanoid":  # Unity's names, fingers as HumanTrait.BoneName writes them
        out |= {"pelvis": "Hips", "spine_01": "Spine", "spine_02": "Chest", "spine_03": "UpperChest",
                "neck_01": "Neck", "head": "Head"}
        limb = {"clavicle": "Shoulder", "upperarm": "UpperArm", "lowerarm": "LowerArm", "hand": "Hand",
                "thigh": "UpperLeg", "calf": "LowerLeg", "foot": "Foot", "ball": "Toes"}
        for s, side in (("l", "Left"), ("r", "Right")):
            out |= {f"{b}_{s}": f"{side}{v}" for b, v in limb.items()}
            out |= {f"{f}_0{i}_{s}": f"{side} {'Little' if f == 'pinky' else FINGER_WORDS[f]} {p}"
                    for f in sk.FINGERS for i, p in enumerate(("Proximal", "Intermediate", "Distal"), start=1)}
    elif scheme == "mixamo":
        p = "mixamorig12:"
        out |= {"pelvis": p + "Hips", "spine_01": p + "Spine", "spine_02": p + "Spine1", "spine_03": p + "Spine2",
                "neck_01": p + "Neck", "head": p + "Head"}
        limb = {"clavicle": "Shoulder", "upperarm": "Arm", "lowerarm": "ForeArm", "hand": "Hand", "thigh": "UpLeg",
                "calf": "Leg", "foot": "Foot", "ball": "ToeBase"}
        for s, side in (("l", "Left"), ("r", "Right")):
            out |= {f"{b}_{s}": f"{p}{side}{v}" for b, v in limb.items()}
            out |= {f"{f}_0{i}_{s}": f"{p}{side}Hand{FINGER_WORDS[f]}{i}" for f in sk.FINGERS for i in (1, 2, 3)}
    return out


# --- building the variants ----------------------------------------------------------------------------

def _edit(arm):
    bpy.context.view_layer.objects.active = arm
    bpy.ops.object.mode_set(mode="EDIT")
    return arm.data.edit_bones


def _move_weights(mesh, arm, source: str, target: str, head, tail, beyond: float, before: bool = False):
    """Move `source`'s vertex weights to `target` for the vertices past `beyond` of the bone's length
    (before it with `before`): a twist bone carrying the half of the limb it rides on."""
    src, dst = mesh.vertex_groups[source], mesh.vertex_groups.get(target) or mesh.vertex_groups.new(name=target)
    axis = tail - head
    mw = np.array(mesh.matrix_world)
    for v in mesh.data.vertices:
        w = next((g.weight for g in v.groups if g.group == src.index), None)
        if w is None:
            continue
        p = (mw @ np.append(np.array(v.co), 1.0))[:3]
        t = float(np.dot(p - head, axis) / np.dot(axis, axis))
        if (t < beyond) if before else (t > beyond):
            src.remove([v.index])
            dst.add([v.index], w, "REPLACE")


def split_bone(arm, mesh, bone: str, twist: str, *, in_chain: bool):
    """Daz-style (in_chain: bone -> twist -> children, the twist from the middle to the old tail)
    or Character Creator-style (a side branch from the bone's head to its middle)."""
    mw = np.array(arm.matrix_world)
    b = arm.data.bones[bone]
    head = (mw @ np.append(np.array(b.head_local), 1))[:3]
    tail = (mw @ np.append(np.array(b.tail_local), 1))[:3]
    ebs = _edit(arm)
    eb = ebs[bone]
    mid = (eb.head + eb.tail) / 2
    tw = ebs.new(twist)
    tw.head, tw.tail, tw.roll = (mid, eb.tail.copy(), eb.roll) if in_chain else (eb.head.copy(), mid, eb.roll)
    tw.parent = eb
    tw.use_connect = False
    if in_chain:
        for child in list(eb.children):
            if child != tw:
                child.use_connect = False
                child.parent = tw
        eb.tail = mid
    bpy.ops.object.mode_set(mode="OBJECT")
    _move_weights(mesh, arm, bone, twist, head, tail, 0.5, before=not in_chain)


def insert_pelvis(arm, hip: str, pelvis: str, thighs: list[str]):
    """Daz and Character Creator: the thighs hang from a 'pelvis' bone under the hips root."""
    ebs = _edit(arm)
    root = ebs[hip]
    pb = ebs.new(pelvis)
    pb.head = root.head.copy()
    pb.tail = root.head.copy()
    pb.tail.z -= 0.08
    pb.parent = root
    for t in thighs:
        ebs[t].use_connect = False
        ebs[t].parent = pb
    bpy.ops.object.mode_set(mode="OBJECT")


def build_variant(avatar_path, scheme: str):
    """The sample avatar with `scheme`'s names (and structure); returns (arm, mesh, old -> new)."""
    arm, mesh = rigs.load_glb_avatar(avatar_path)
    names = renames(scheme)
    for old, new in names.items():
        arm.data.bones[old].name = new  # Blender renames the mesh's vertex groups with it
    if scheme == "daz_genesis8":
        for s in ("l", "r"):
            split_bone(arm, mesh, f"{s}ShldrBend", f"{s}ShldrTwist", in_chain=True)
            split_bone(arm, mesh, f"{s}ForearmBend", f"{s}ForearmTwist", in_chain=True)
            split_bone(arm, mesh, f"{s}ThighBend", f"{s}ThighTwist", in_chain=True)
        insert_pelvis(arm, "hip", "pelvis", ["lThighBend", "rThighBend"])
    if scheme == "character_creator":
        for side in ("L", "R"):
            split_bone(arm, mesh, f"CC_Base_{side}_Upperarm", f"CC_Base_{side}_UpperarmTwist01", in_chain=False)
            split_bone(arm, mesh, f"CC_Base_{side}_Thigh", f"CC_Base_{side}_ThighTwist01", in_chain=False)
        insert_pelvis(arm, "CC_Base_Hip", "CC_Base_Pelvis", ["CC_Base_L_Thigh", "CC_Base_R_Thigh"])
    bpy.context.view_layer.update()
    return arm, mesh, names


# --- the original, once ----------------------------------------------------------------------------

@pytest.fixture(scope="module")
def session():
    performer = synthetic.make_performer(seed=5)
    rec, truth = synthetic.record_session(performer, profile="full", motions=("hand_on_belly",),
                                          calibration=["tpose"], seed=5, motion_seconds=1.5)
    rec.name = "belly"
    return rec, truth.body_model(), truth


@pytest.fixture(scope="module")
def original(avatar_files, session):
    """The adult male as shipped: its avatar model and its animation (computed once)."""
    rec, user, _truth = session
    path = next(p for p in avatar_files if p.stem == "adult_male")
    arm, _mesh = rigs.load_glb_avatar(path)
    model = ac.calibrate_avatar(arm)
    return path, model, retarget(rec, user, model, "egocentric")


def _assert_same_model(model: BodyModel, ref: BodyModel, names: dict[str, str]):
    assert set(model.joints) == set(ref.joints)
    for j, joint in ref.joints.items():
        np.testing.assert_allclose(model.joints[j].world, joint.world, atol=1e-6, err_msg=j)
        assert model.joints[j].frame == names.get(joint.frame, joint.frame), j
    for b, info in ref.bones.items():
        for end in ("radius_head", "radius_tail"):
            if getattr(info, end) is not None:
                assert getattr(model.bones[b], end) == pytest.approx(getattr(info, end), abs=1e-6), (b, end)
        np.testing.assert_allclose(model.bones[b].right, info.right, atol=1e-6, err_msg=b)
    assert model.element("sphere:skull").radius == pytest.approx(ref.element("sphere:skull").radius, abs=1e-6)


# Renaming bones changes no number: the motion is the same to the last bit (1e-9 m). Splitting a
# bone or inserting one goes through Edit Mode, which recomputes the rest matrix of every bone
# whose parent changed from its head, tail and roll in float32 (entries move by 1.25e-6, BLENDER_NOTES.md);
# the limb IK carries that to at most 6 um on the joints of the 1.5 s take, except where a limb is
# straight: at frame 31 the right arm is straight within 0.5 deg, its elbow sits 1 mm off the
# shoulder-wrist axis and turns about it with the swivel, and moves 17 um (measured since the
# finger realignment's angle order changed, which moved that elbow by 1 mm), hence 20 um there.
# The same holds for a leg since the feet roll (heel -> flat -> ball, DESIGN.md §6): at frame 271
# the right knee is straight within 0.3 deg, 1.1 mm off the hip-ankle axis, and moves 30 um, hence
# 40 um (30.1-30.2 um on Blender 4.2, 4.5 and 5.0).
RENAMED_ATOL = 1e-9
EDITED_ATOL = 4e-5


def _assert_same_animation(anim, ref, names: dict[str, str], atol: float):
    assert anim.frame_count == ref.frame_count
    for j, path in ref.joints_world.items():
        np.testing.assert_allclose(anim.joints_world[j], path, atol=atol, rtol=0, err_msg=j)
    index = {n: i for i, n in enumerate(anim.bone_names)}
    for i, old in enumerate(ref.bone_names):
        q, q0 = anim.rotations[:, index[names.get(old, old)]], ref.rotations[:, i]
        np.testing.assert_allclose(np.abs(np.sum(q * q0, axis=-1)), 1.0, atol=1e-6, err_msg=old)
    for extra in set(anim.bone_names) - {names.get(n, n) for n in ref.bone_names}:  # twist, inserted pelvis
        np.testing.assert_allclose(np.abs(anim.rotations[:, index[extra], 0]), 1.0, atol=1e-6, err_msg=extra)


@pytest.mark.slow
@pytest.mark.parametrize("scheme", ["vroid", "daz_genesis8", "character_creator", "vrm_humanoid", "mixamo"])
def test_a_renamed_rig_is_detected_and_gives_the_same_model_and_motion(original, session, scheme):
    path, ref_model, ref_anim = original
    rec, user, _truth = session
    arm, _mesh, names = build_variant(path, scheme)
    bm = avatar_rig.bone_map_for(arm)
    assert bm.scheme == scheme and bm.missing(with_fingers=True) == []
    model = ac.calibrate_avatar(arm)
    _assert_same_model(model, ref_model, names)
    edited = scheme in ("daz_genesis8", "character_creator")  # split limbs, an inserted pelvis bone
    _assert_same_animation(retarget(rec, user, model, "egocentric"), ref_anim, names,
                           EDITED_ATOL if edited else RENAMED_ATOL)


def test_split_limbs_keep_the_joints_at_the_bend_bones_heads(avatar_files):
    """Daz's Bend/Twist pairs: the elbow and knee are the heads of the next Bend bones, the twist
    bones and the inserted pelvis are unmapped, and 'hip' (the hips root) is the pelvis segment."""
    arm, _mesh, _names = build_variant(next(p for p in avatar_files if p.stem == "adult_male"), "daz_genesis8")
    rig = avatar_rig.read_rig(arm)
    mw = np.array(arm.matrix_world)
    for joint, bone in (("elbow_l", "lForearmBend"), ("knee_r", "rShin"), ("wrist_l", "lHand"),
                        ("shoulder_r", "rShldrBend"), ("hip_l", "lThighBend")):
        np.testing.assert_allclose(rig.joints[joint], (mw @ np.append(arm.data.bones[bone].head_local, 1))[:3],
                                   atol=1e-9, err_msg=joint)
    assert arm.data.bones["lForearmBend"].parent.name == "lShldrTwist"  # in the chain, as in Genesis 8
    assert {"lShldrTwist", "lForearmTwist", "rThighTwist", "pelvis"} <= set(rig.bone_map.unmapped)
    assert rig.bone_map.bones["pelvis"] == "hip"


def test_mapping_the_bone_called_pelvis_as_the_pelvis_is_refused_with_the_fix(avatar_files):
    arm, _mesh, _names = build_variant(next(p for p in avatar_files if p.stem == "adult_male"), "daz_genesis8")
    avatar_rig.set_override(arm, "pelvis", "pelvis")
    with pytest.raises(Exception) as exc:
        avatar_rig.read_rig(arm)
    line = str(exc.value)
    assert "'pelvis' is not a parent of abdomenLower" in line and "map pelvis to 'hip'" in line
    assert "\n" not in line


def test_a_new_map_drops_a_model_made_with_another(avatar_files):
    arm, _mesh, _names = build_variant(next(p for p in avatar_files if p.stem == "adult_male"), "mixamo")
    avatar_storage.store_model(arm, ac.calibrate_avatar(arm))
    same = preset_from_bone_map(avatar_rig.bone_map_for(arm), "same")
    assert avatar_rig.apply_preset(arm, same)[1] is False and avatar_storage.has_model(arm)
    other = BonePreset("other", "mixamo", bones={"toe_l": None})
    bm, dropped = avatar_rig.apply_preset(arm, other)
    assert dropped and not avatar_storage.has_model(arm) and "toe_l" not in bm.bones
    assert avatar_rig.bone_map_for(arm).same_mapping(bm) and avatar_rig.bone_map_for(arm).scheme == "custom"


# --- presets in the panel ----------------------------------------------------------------------------

def test_panel_preset_round_trip_export_import_apply(avatar_files, tmp_path):
    """Export the map of a rig no scheme knows (mapped by hand), forget it, Import the file: the
    same map, and the preset is in your presets list."""
    path = next(p for p in avatar_files if p.stem == "adult_male")
    arm, _mesh = rigs.load_glb_avatar(path)
    ref = avatar_rig.bone_map_for(arm)
    names = {b.name: f"jnt{i:03d}" for i, b in enumerate(arm.data.bones)}
    for old, new in names.items():
        arm.data.bones[old].name = new
    wanted = naming.BoneMap("x", {s: names[b] for s, b in ref.bones.items()},
                        {c: [names[b] for b in v] for c, v in ref.chains.items()}, [])
    avatar_rig.apply_bone_map(arm, wanted)
    bpy.context.view_layer.objects.active = arm
    out = tmp_path / "renamed.json"
    assert bpy.ops.bodycal.export_bone_map(filepath=str(out), preset_name="Renamed adult") == {"FINISHED"}
    assert json.loads(out.read_text())["name"] == "Renamed adult"
    assert bpy.ops.bodycal.detect_bone_map(reset=True) == {"FINISHED"}
    assert avatar_rig.bone_map_for(arm).missing()  # no scheme knows these names
    assert bpy.ops.bodycal.import_bone_map(filepath=str(out)) == {"FINISHED"}
    assert avatar_rig.bone_map_for(arm).same_mapping(wanted)
    wm = bpy.context.window_manager
    assert wm.bodycal_bone_map_preset == "user:Renamed_adult.json"  # kept among your presets
    assert bpy.ops.bodycal.detect_bone_map(reset=True) == {"FINISHED"}
    assert bpy.ops.bodycal.apply_bone_map_preset() == {"FINISHED"}  # the chosen one, from your folder
    assert avatar_rig.bone_map_for(arm).same_mapping(wanted)
    wm.bodycal_bone_map_preset = "builtin:unreal"
    with pytest.raises(RuntimeError, match="maps none of its bones"):  # Unreal names on a rig that has none
        bpy.ops.bodycal.apply_bone_map_preset()
    assert avatar_rig.bone_map_for(arm).same_mapping(wanted)  # the working map is kept


def test_a_preset_naming_a_bone_the_armature_lacks_changes_nothing(avatar_files, tmp_path):
    arm, _mesh = rigs.load_glb_avatar(next(p for p in avatar_files if p.stem == "adult_male"))
    before = arm.get(avatar_rig.BONE_MAP_PROP)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"format": "bodycal-bone-map", "version": 1, "scheme": "unreal",
                               "bones": {"pelvis": "Pelvis_jnt"}}))
    bpy.context.view_layer.objects.active = arm
    with pytest.raises(RuntimeError, match="has no bone 'Pelvis_jnt'"):
        bpy.ops.bodycal.import_bone_map(filepath=str(bad))
    assert arm.get(avatar_rig.BONE_MAP_PROP) == before


# --- the command line -------------------------------------------------------------------------------

def _run(*args):
    return subprocess.run([sys.executable, "-m", "bodycal_addon", *map(str, args)], cwd=REPO, capture_output=True,
                          text=True, timeout=600)


def _unknown_rig_files(tmp_path, avatar_files):
    """A .blend of the adult male with names no scheme knows, and the preset that maps them."""
    path = next(p for p in avatar_files if p.stem == "adult_male")
    arm, _mesh = rigs.load_glb_avatar(path)
    ref = avatar_rig.bone_map_for(arm)
    names = {b.name: f"jnt{i:03d}" for i, b in enumerate(arm.data.bones)}
    for old, new in names.items():
        arm.data.bones[old].name = new
    blend = tmp_path / "unknown.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    preset = BonePreset("unknown rig", None, {s: names[b] for s, b in ref.bones.items()},
                        {c: [names[b] for b in v] for c, v in ref.chains.items() if v})
    return blend, preset.save(tmp_path / "unknown.bonemap.json"), names


@pytest.mark.slow
def test_bone_map_on_the_command_line_maps_a_rig_no_scheme_knows(tmp_path, avatar_files, original, session):
    _path, ref_model, ref_anim = original
    rec, user, truth = session
    blend, preset, names = _unknown_rig_files(tmp_path, avatar_files)
    out = _run("calibrate-avatar", blend, "-o", tmp_path / "no_map.body.json")
    assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1
    assert "missing pelvis" in out.stderr and "Traceback" not in out.stderr

    out = _run("calibrate-avatar", blend, "--bone-map", preset, "-o", tmp_path / "avatar.body.json")
    assert out.returncode == 0, out.stderr[-2000:]
    _assert_same_model(BodyModel.load(tmp_path / "avatar.body.json"), ref_model, names)

    rec_path, _truth_path = synthetic.write_session(tmp_path, "belly", rec, truth)
    user_path = user.save(tmp_path / "performer.body.json")
    out = _run("retarget", rec_path, "--user", user_path, "--avatar", blend, "--bone-map", preset, "--no-filter",
               "-o", tmp_path / "out.blend")  # as the reference, unsmoothed
    assert out.returncode == 0, out.stderr[-2000:]
    bpy.ops.wm.open_mainfile(filepath=str(tmp_path / "out.blend"))
    arm = bpy.data.objects["adult_male"]
    assert arm.animation_data.action.name == "belly|adult_male|egocentric"
    stored = avatar_storage.load_model(arm)
    assert naming.BoneMap.from_dict(stored.extra["rig"]["bone_map"]).bones["pelvis"] == names["pelvis"]
    # the keys in the .blend are the original rig's motion on the renamed bones
    i = ref_anim.bone_names.index("upperarm_l")
    for f in (0, ref_anim.frame_count // 2, ref_anim.frame_count - 1):
        bpy.context.scene.frame_set(int(bpy.context.scene.frame_start + f))
        baked = np.array(arm.pose.bones[names["upperarm_l"]].rotation_quaternion)
        assert abs(abs(float(baked @ ref_anim.rotations[f, i])) - 1) < 1e-5, f


@pytest.mark.parametrize("content,words", [
    ("{not json", "not valid JSON"),
    (json.dumps({"format": "bodycal-bone-map", "version": 1, "bones": {"upper_arm_l": "jnt001"}}),
     "unknown segment 'upper_arm_l'"),
    (json.dumps({"format": "bodycal-bone-map", "version": 1, "scheme": "unreal", "bones": {"pelvis": "Hips"}}),
     "has no bone 'Hips'"),
])
def test_a_bad_bone_map_is_one_line_and_exit_2(tmp_path, avatar_files, content, words):
    arm, _mesh = rigs.load_glb_avatar(next(p for p in avatar_files if p.stem == "adult_male"))
    blend = tmp_path / "avatar.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    (tmp_path / "map.json").write_text(content)
    for args in (("calibrate-avatar", blend, "--bone-map", tmp_path / "map.json", "-o", tmp_path / "a.body.json"),
                 ("retarget", "no.bcrec.json", "--user", "u.body.json", "--avatar", blend, "--bone-map",
                  tmp_path / "map.json", "-o", tmp_path / "o.blend")):
        if "has no bone" in words and args[0] == "retarget":
            continue  # the recording is checked first there; calibrate-avatar shows the armature check
        out = _run(*args)
        assert out.returncode == 2, out.stderr
        (line,) = out.stderr.strip().splitlines()
        assert words in line and "map.json" in line and "Traceback" not in out.stderr
    assert not (tmp_path / "a.body.json").exists() and not (tmp_path / "o.blend").exists()


def test_the_output_may_not_be_the_bone_map(tmp_path):
    (tmp_path / "map.json").write_text(json.dumps({"format": "bodycal-bone-map", "version": 1, "scheme": "unreal"}))
    out = _run("calibrate-avatar", tmp_path / "a.blend", "--bone-map", tmp_path / "map.json", "-o",
               tmp_path / "map.json", "--overwrite")
    assert out.returncode == 2 and "is the bone map (--bone-map), an input" in out.stderr
    assert json.loads((tmp_path / "map.json").read_text())["scheme"] == "unreal"


def test_the_bone_map_panel_offers_the_preset_list_and_its_operators(avatar_files):
    arm, _mesh = rigs.load_glb_avatar(next(p for p in avatar_files if p.stem == "adult_male"))
    bpy.context.view_layer.objects.active = arm
    log = ui_layout.draw(bpy.types.BODYCAL_PT_bone_map, bpy.context)
    drawn_ops = {entry[1] for entry in log if entry[0] == "operator"}
    assert {"bodycal.apply_bone_map_preset", "bodycal.export_bone_map", "bodycal.import_bone_map"} <= drawn_ops
    for idname in drawn_ops:  # every button names a registered operator
        group, name = idname.split(".")
        assert hasattr(getattr(bpy.ops, group), name) and getattr(getattr(bpy.ops, group), name).idname()
    (preset_prop,) = [entry for entry in log if entry[0] == "prop" and entry[2] == "bodycal_bone_map_preset"]
    assert preset_prop[1] == bpy.context.window_manager
    assert bpy.context.window_manager.bodycal_bone_map_preset.startswith("builtin:")
    assert bpy.ops.bodycal.apply_bone_map_preset.poll()  # a preset is chosen and an armature is active
