"""Rigs as users bring them (DESIGN.md §2 "Rigs as files bring them", §1 "Verified bakes"): characters
no one on the project made (sample_data/avatars/outside), a generated Rigify rig after a game
engine's round trip, a Mixamo-named rig exported to .glb, Blender's .L/.R names; each is calibrated
and retargeted with no option, or refused with one line; and a bake whose keys drive nothing is an
error that leaves nothing behind."""

from __future__ import annotations

import bpy
import numpy as np
import pytest
from repo_paths import REPO
from rig_edits import constrain_forearm_to_an_unkeyed_control

from bodycal_addon.blender import avatar_rig, blendfile, mesh_metrics, rig_output, session
from bodycal_addon.blender.fcurves import object_fcurves
from bodycal_addon.calibration import calibrate_user
from bodycal_addon.core import paths
from bodycal_addon.core.errors import BodyCalError
from bodycal_addon.recording.io import load_recording
from bodycal_addon.retarget.takes import RecordingTake
from bodycal_dev import synthetic

OUTSIDE = {p.stem: p for p in paths.outside_avatar_files()}
SAMPLE_TAKE = REPO / "sample_rigs" / "recordings" / "demo_full.bcrec.json"
WINDOW = (1800, 1960)  # frames of the sample take where the performer moves (not its deep squat)


@pytest.fixture(scope="module")
def sample_take():
    rec = load_recording(SAMPLE_TAKE)
    return RecordingTake(rec, calibrate_user(rec)).window(*WINDOW)


@pytest.fixture(scope="module")
def belly():
    performer = synthetic.make_performer(seed=5)
    rec, truth = synthetic.record_session(performer, profile="full", motions=("hand_on_belly",),
                                          calibration=["tpose"], seed=5, motion_seconds=1.5)
    return rec, truth


def _retarget(take, arm):
    """Calibrate and bake as the command line does (no option): the summary and the target."""
    target = session.prepare_target(arm)
    computed = session.compute(take, target, session.Settings())
    return session.bake(take, target, computed), target


@pytest.mark.parametrize("name, scheme", [("cesium_man", "structure"), ("male_base_mesh", "rigify_metarig")])
def test_an_outside_character_calibrates_and_retargets_with_no_option(sample_take, name, scheme):
    """Cesium Man (COLLADA names, no clavicles) was 'not a humanoid rig this version can map'; the
    base mesh on Rigify's metarig without its head bone was refused for a missing head."""
    blendfile.open_avatar(OUTSIDE[name])
    arm = blendfile.find_armature(None, name)
    summary, target = _retarget(sample_take, arm)
    assert target.avatar.extra["rig"]["scheme"] == scheme
    assert summary.frames > 100 and summary.keys > 0
    assert arm.animation_data.action.name == summary.action
    reach = summary.figures["reach p95"]
    assert np.isfinite(reach) and reach < 250.0, reach


def test_cesium_man_is_mapped_from_its_shape():
    blendfile.open_avatar(OUTSIDE["cesium_man"])
    bm = avatar_rig.bone_map_for(blendfile.find_armature(None, "cesium_man"))
    assert bm.scheme == "structure"
    assert bm.bones["pelvis"] == "Skeleton_torso_joint_1" and bm.bones["head"] == "Skeleton_neck_joint_2"
    assert [bm.bones[f"{s}_l"] for s in ("upperarm", "forearm", "hand")] == [
        "Skeleton_arm_joint_L__4_", "Skeleton_arm_joint_L__3_", "Skeleton_arm_joint_L__2_"]
    assert [bm.bones[f"{s}_r"] for s in ("thigh", "shin", "foot", "toe")] == [
        "leg_joint_R_1", "leg_joint_R_2", "leg_joint_R_3", "leg_joint_R_5"]
    assert "clavicle_l" not in bm.bones and bm.chains["spine"][-1] == "torso_joint_3"


def test_a_robot_whose_feet_are_ik_controls_is_keyed_in_the_armature_space(sample_take):
    """Its feet are IK controls under the root bone, beside the legs ('foot bone 'Foot.L' does not
    hang from the shin bone', refused): the engine poses each foot from its shin, and the bake keys
    the foot's location and rotation in the armature's space, as game exporters key IK feet. The
    bake's check on the evaluated rig passes, and the feet stand where the engine put the ankles.
    (Imported with the importer's guessed bind pose, its bones kept the nodes' rest as a pose the
    keys did not override: the check found the right wrist 2.4 m off. blendfile.bound_elsewhere: only
    this file of the samples is bound in another pose than its nodes' rest.)"""
    samples = paths.shared_avatar_files() + paths.outside_avatar_files()
    assert [p.stem for p in samples if blendfile.bound_elsewhere(p)] == ["robot_expressive"]
    blendfile.open_avatar(OUTSIDE["robot_expressive"])
    arm = blendfile.find_armature(None, "robot_expressive")
    target = session.prepare_target(arm)
    assert target.avatar.extra["rig"]["armature_space"] == {"Foot.L": "Bone", "Foot.R": "Bone"}
    defaulted = target.avatar.calibration["defaulted"]
    assert {"capsule:upperarm_l", "mesh:sole_l"} <= set(defaulted)  # its bare rods and discs, said
    computed = session.compute(sample_take, target, session.Settings())
    anim = computed.animation
    summary = session.bake(sample_take, target, computed)  # bake_check.verify on the evaluated rig
    curves = {p for p, _i in object_fcurves(arm)}
    assert {f'pose.bones["Foot.{s}"].location' for s in "LR"} <= curves
    assert any("keyed with location and rotation in the armature's space" in n for n in summary.notes)
    assert not any("from before they were" in n for n in summary.notes)  # its soles were estimated, not old
    scene = bpy.context.scene
    worst = 0.0
    for k in np.linspace(0, anim.frame_count - 1, 6).astype(int):
        scene.frame_set(int(round(summary.frame_range[0])) + int(k))
        for s in "lr":
            foot = np.array(arm.matrix_world @ arm.pose.bones[f"Foot.{s.upper()}"].head)
            worst = max(worst, float(np.linalg.norm(foot - anim.joints_world[f"ankle_{s}"][k])))
    assert worst < 0.005, worst


def test_a_mini_character_whose_limbs_are_one_bone_each_is_one_line(tmp_path):
    """Kenney's mini characters: root, torso, head and one bone per arm and leg. No map can give
    them an elbow or a knee: refused with one line that says so, on the command line too (exit 2,
    nothing written, one line on stderr)."""
    import subprocess
    import sys

    path = OUTSIDE["kenney_mini_character_male_a"]
    blendfile.open_avatar(path)
    arm = blendfile.find_armature(None, path.name)
    assert len(arm.data.bones) == 7 and blendfile.deformed_meshes(arm)
    with pytest.raises(BodyCalError, match=r"not a humanoid rig this version can animate: 7 bones, fewer than the "
                                           r"15 segments it poses \(missing pelvis, upperarm_l, ") as info:
        session.prepare_target(arm)
    assert "\n" not in info.value.line() and "cannot bend at the elbow or knee" in info.value.line()
    out_file = tmp_path / "kenney.body.json"
    run = subprocess.run([sys.executable, "-m", "bodycal_addon", "calibrate-avatar", str(path), "-o", str(out_file)],
                         cwd=REPO, capture_output=True, text=True, timeout=300)
    assert run.returncode == 2 and len(run.stderr.splitlines()) == 1, run.stderr
    assert "7 bones, fewer than the 15 segments" in run.stderr and not out_file.exists()


# --- two characters in one file ------------------------------------------------------------------------

@pytest.fixture(scope="module")
def two_characters(tmp_path_factory, data_dir):
    """The sample adult imported twice, the second 1.5 m to the side (`adult_male.001` on
    `adult_male_rig.001`), written as one FBX by Blender's exporter and as one .blend."""
    tmp = tmp_path_factory.mktemp("two_characters")
    bpy.ops.wm.read_homefile(use_empty=True)
    glb = data_dir / "avatars" / "mpfb2_variants" / "adult_male.glb"
    blendfile.import_avatar_file(glb)
    for obj in blendfile.import_avatar_file(glb):
        if obj.parent is None:
            obj.location.x += 1.5
    files = {"fbx": tmp / "two.fbx", "blend": tmp / "two.blend"}
    bpy.ops.export_scene.fbx(filepath=str(files["fbx"]), bake_anim=False, add_leaf_bones=False)
    bpy.ops.wm.save_as_mainfile(filepath=str(files["blend"]), copy=True)
    return files


@pytest.mark.parametrize("kind", ["fbx", "blend"])
def test_two_characters_in_one_file_are_each_measured_on_their_own_skin(two_characters, belly, kind):
    """Blender's FBX importer skips the armature after one whose meshes it moves (it reparents them
    while walking the list that holds them): the second character came in unskinned, its body was
    estimated from its bones (no skin contact, no feet on its skin) and the command line took the
    first without asking. Its mesh is bound again by its vertex groups; both characters bake with
    the same contacts and feet (the same body, 1.5 m apart)."""
    notes = blendfile.open_avatar(two_characters[kind])
    arms = sorted((o for o in bpy.data.objects if o.type == "ARMATURE"), key=lambda o: o.name)
    assert [[m.name for m in blendfile.deformed_meshes(a)] for a in arms] == [["adult_male"], ["adult_male.001"]]
    lost = ("adult_male.001: Blender's FBX importer left it unbound (its skin to 'adult_male_rig.001' lost); bound "
            "to 'adult_male_rig.001' again, whose bones its vertex groups name")
    # 4.5 and 5.0's exporter writes the nodes in the order that trips the importer; 4.2's does not
    assert notes == [] if kind == "blend" or bpy.app.version < (4, 3) else notes == [lost]
    with pytest.raises(BodyCalError, match="several armatures"):
        blendfile.find_armature(None, kind)
    contact, feet = [], []
    for arm in arms:
        gaps, _keyed, (take, target, anim) = _gaps(arm, belly)
        assert target.avatar.calibration.get("method") != "estimated"
        summary = session.bake(take, target, session.Computed(anim, 0.0))  # checked on the evaluated rig
        assert summary.keys > 0
        frames = np.linspace(0, anim.frame_count - 1, 5).astype(int)
        skin = mesh_metrics.foot_skin(arm, target.avatar, anim, frames)
        contact.append(np.median(gaps))
        feet.append(np.array([skin[s]["low"] for s in ("l", "r")]))
    assert np.isfinite(contact).all() and abs(contact[0] - contact[1]) < 0.001, contact
    assert np.isfinite(feet).all() and np.abs(feet[0] - feet[1]).max() < 0.001, feet


def test_a_lost_skin_is_bound_only_to_the_armature_it_names_and_stands_on():
    from sample_rigs import build_procedural_avatar

    bpy.ops.wm.read_homefile(use_empty=True)
    arm, mesh, _spec = build_procedural_avatar()
    mesh.modifiers.remove(next(m for m in mesh.modifiers if m.type == "ARMATURE"))
    world = mesh.matrix_world.copy()
    mesh.parent = None
    mesh.matrix_world = world
    mesh.location.x += 3.0  # beside its armature, not on it: left alone
    assert blendfile.bind_lost_skins([arm, mesh]) == [] and not blendfile.deformed_meshes(arm)
    mesh.location.x -= 3.0
    prop = mesh.copy()
    prop.data = mesh.data.copy()  # vertex group names live on the mesh data
    prop.vertex_groups.new(name="not a bone")  # a group no bone of the armature has: left alone
    bpy.context.scene.collection.objects.link(prop)
    assert len(blendfile.bind_lost_skins([arm, mesh, prop])) == 1
    assert blendfile.deformed_meshes(arm) == [mesh] and mesh.parent == arm
    assert np.allclose(np.array(mesh.matrix_world), np.array(world))


# --- a generated Rigify rig after a round trip through glTF or FBX -------------------------------------

@pytest.fixture(scope="module")
def round_trips(tmp_path_factory, rigify_blend):
    """The generated Rigify rig (conftest's) exported to .glb and .fbx with every bone, as a game
    engine gets it: DEF-/ORG-/MCH- names, no constraints."""
    tmp = tmp_path_factory.mktemp("rigify_round_trip")
    bpy.ops.wm.open_mainfile(filepath=str(rigify_blend))
    rig = bpy.data.objects["rigify_avatar"]
    keep = {rig, *blendfile.deformed_meshes(rig)}
    for obj in bpy.context.view_layer.objects:
        obj.select_set(obj in keep)
    files = {"glb": tmp / "rigify.glb", "fbx": tmp / "rigify.fbx"}
    bpy.ops.export_scene.gltf(filepath=str(files["glb"]), export_format="GLB", use_selection=True,
                              export_animations=False, export_def_bones=False)
    bpy.ops.export_scene.fbx(filepath=str(files["fbx"]), use_selection=True, bake_anim=False, add_leaf_bones=False)
    return files


@pytest.fixture(scope="module")
def plain_gaps(belly):
    """The same body as a plain (Unreal-style) rig: the contact gaps the round trip must keep."""
    from sample_rigs import build_procedural_avatar
    from sample_rigs.rigify_rig import bent_spec

    bpy.ops.wm.read_homefile(use_empty=True)
    arm, _mesh, _spec = build_procedural_avatar(bent_spec())
    return _gaps(arm, belly)[0]


def _gaps(arm, belly):
    rec, truth = belly
    take = RecordingTake(rec, truth.body_model())
    target = session.prepare_target(arm)
    anim = session.compute(take, target, session.Settings()).animation
    keyed = rig_output.for_bake(anim, arm, avatar_rig.bone_map_for(arm), "root", "fk")
    contacts = [c for c in truth.contacts if c["target"].startswith("mesh:")]
    gaps = mesh_metrics.contact_gaps(arm, target.avatar, anim, contacts, max_frames=6, posed=keyed)
    return np.abs(np.concatenate(gaps)), keyed, (take, target, anim)


def _round_trip(path):
    bpy.ops.wm.read_homefile(use_empty=True)
    blendfile.import_avatar_file(path)
    arm = blendfile.find_armature(None, path.name)
    assert avatar_rig.is_rigify_generated(arm) and not rig_output.controls_drive_deform(arm)
    return arm


def test_a_rigify_rig_without_its_constraints_is_keyed_on_what_deforms(round_trips, belly, plain_gaps):
    """The round trip through glTF keeps DEF-/ORG-/MCH- names and drops every constraint: it is
    still detected as Rigify, but its FK controls drive nothing (the hand stayed 380 mm from the
    belly, exit 0). The keys go on its DEF- bones, the bake's check passes on the evaluated rig,
    and the hand-on-belly contact is the plain rig's."""
    arm = _round_trip(round_trips["glb"])
    gaps, keyed, (take, target, anim) = _gaps(arm, belly)
    assert keyed.bone_names and all(n.startswith("DEF-") for n in keyed.bone_names)
    assert rig_output.ROUND_TRIP_NOTE in keyed.notes
    assert abs(np.median(gaps) - np.median(plain_gaps)) < 0.005
    assert np.percentile(gaps, 95) < np.percentile(plain_gaps, 95) + 0.02
    summary = session.bake(take, target, session.Computed(anim, 0.0))  # checked against the evaluated rig
    keyed_paths = {p.split('"')[1] for p, _i in object_fcurves(arm) if p.startswith("pose.bones")}
    assert "DEF-hand.R" in keyed_paths and "hand_fk.R" not in keyed_paths and summary.keys > 0


def test_the_same_rig_through_fbx_is_keyed_on_its_def_bones(round_trips, belly):
    arm = _round_trip(round_trips["fbx"])
    rec, truth = belly
    target = session.prepare_target(arm)
    anim = session.compute(RecordingTake(rec, truth.body_model()), target, session.Settings()).animation
    keyed = rig_output.for_bake(anim, arm, avatar_rig.bone_map_for(arm), "root", "fk")
    assert {"DEF-hand.R", "DEF-thigh.L", "DEF-spine.003"} <= set(keyed.bone_names)
    assert not any(n.startswith(("ORG-", "MCH-")) or n.endswith("_fk.L") for n in keyed.bone_names)


# --- rigs that were refused: Mixamo names through glTF, Blender's .L/.R names ---------------------------

def test_a_mixamo_rig_exported_to_glb_calibrates_its_fingers(tmp_path, sample_take):
    """FBX's 0.01 scale and centimetre bones carried through glTF: the importer guesses every
    bone's tail (a thumb's came out 2 m long) and its bone rolls ('capsule:thumb_3_l: only 0 of 60
    rays ... hit the mesh')."""
    from mathutils import Matrix

    from sample_rigs import build_procedural_avatar

    arm, mesh, _spec = build_procedural_avatar()
    words = {"thumb": "Thumb", "index": "Index", "middle": "Middle", "ring": "Ring", "pinky": "Pinky"}
    names = {"pelvis": "Hips", "spine_01": "Spine", "spine_02": "Spine1", "spine_03": "Spine2", "neck_01": "Neck",
             "head": "Head"}
    limbs = {"clavicle": "Shoulder", "upperarm": "Arm", "lowerarm": "ForeArm", "hand": "Hand", "thigh": "UpLeg",
             "calf": "Leg", "foot": "Foot", "ball": "ToeBase"}
    for s, side in (("l", "Left"), ("r", "Right")):
        names |= {f"{b}_{s}": f"{side}{w}" for b, w in limbs.items()}
        names |= {f"{f}_0{i}_{s}": f"{side}Hand{w}{i}" for f, w in words.items() for i in (1, 2, 3)}
    for old, new in names.items():
        arm.data.bones[old].name = "mixamorig:" + new
    m = Matrix.Rotation(np.pi / 2, 4, "X") @ Matrix.Scale(0.01, 4)  # as Blender's FBX import of a Mixamo rig
    arm.data.transform(m.inverted())
    arm.matrix_world = m
    mesh.matrix_parent_inverse = m.inverted()
    bpy.context.view_layer.update()
    path = tmp_path / "mixamo.glb"
    bpy.ops.export_scene.gltf(filepath=str(path), export_format="GLB", export_animations=False)
    bpy.ops.wm.read_homefile(use_empty=True)
    blendfile.import_avatar_file(path)
    arm = blendfile.find_armature(None, "mixamo.glb")
    summary, target = _retarget(sample_take, arm)
    model = target.avatar
    assert model.extra["rig"]["scheme"] == "mixamo"
    assert {f"capsule:thumb_{i}_l" for i in (1, 2, 3)} <= {e.id for e in model.surface}
    tips = [np.linalg.norm(model.joints[f"tip_{f}_l"].world - model.joints[f"dip_{f}_l"].world)
            for f in ("thumb", "index", "middle")]
    assert max(tips) < 0.06, tips  # a fingertip, not the importer's 2 m guess
    assert summary.keys > 0


def test_blender_side_suffixes_map_and_retarget(sample_take):
    """Hips, Abdomen / Torso / Chest, UpperArm.L, LowerLeg.R, fingers numbered from 2 (Quaternius'
    characters) were 'not a humanoid rig this version can map'."""
    from sample_rigs import build_procedural_avatar

    arm, _mesh, _spec = build_procedural_avatar()
    names = {"Root": "Root", "pelvis": "Hips", "spine_01": "Abdomen", "spine_02": "Torso", "spine_03": "Chest",
             "neck_01": "Neck", "head": "Head"}
    parts = {"clavicle": "Shoulder", "upperarm": "UpperArm", "lowerarm": "LowerArm", "hand": "Hand",
             "thigh": "UpperLeg", "calf": "LowerLeg", "foot": "Foot", "ball": "Toes"}
    for s, side in (("l", "L"), ("r", "R")):
        names |= {f"{p}_{s}": f"{w}.{side}" for p, w in parts.items()}
        names |= {f"{f}_0{i}_{s}": f"{f.title()}{i + 1}.{side}" for f in ("thumb", "index", "middle", "ring", "pinky")
                  for i in (1, 2, 3)}
    for old, new in names.items():
        arm.data.bones[old].name = new
    bm = avatar_rig.bone_map_for(arm)
    assert bm.scheme == "blender_sided" and bm.missing(with_fingers=True) == []
    assert bm.bones["index_1_l"] == "Index2.L" and bm.bones["pinky_3_r"] == "Pinky4.R"
    assert bm.chains["spine"] == ["Abdomen", "Torso", "Chest"] and bm.bones["pelvis"] == "Hips"
    summary, _target = _retarget(sample_take, arm)
    assert summary.keys > 0


# --- a bake whose keys drive nothing -------------------------------------------------------------------

def test_a_bake_that_does_not_move_the_deforming_bones_is_an_error_and_leaves_nothing(sample_take):
    """The right forearm, which the mesh follows, copies an unkeyed control bone (a control rig
    the bake does not know): its keys do nothing. The bake is one error, the new action is
    removed and the armature keeps its own action."""
    from sample_rigs import build_procedural_avatar

    arm, _mesh, _spec = build_procedural_avatar()
    constrain_forearm_to_an_unkeyed_control(arm)
    mine = bpy.data.actions.new("animator's")
    arm.animation_data_create().action = mine
    before = set(bpy.data.actions)
    with pytest.raises(BodyCalError, match=r"do not move the bones that deform the mesh.*(elbow|wrist)_r"):
        _retarget(sample_take, arm)
    assert set(bpy.data.actions) == before and arm.animation_data.action == mine
