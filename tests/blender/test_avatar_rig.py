"""Reading an avatar's armature: bone maps (detected, overridden, saved), canonical joints from
the rest pose (exact), hinge axes, rest pose detection, the rig dict the retargeting engine uses."""

from __future__ import annotations

import math

import bpy
import numpy as np
import pytest
from mathutils import Matrix

from bodycal_addon.blender import avatar_calibration as ac
from bodycal_addon.blender import avatar_rig
from bodycal_addon.body import skeleton as sk
from bodycal_addon.core.errors import BodyCalError
from sample_rigs import build_procedural_avatar, load_glb_avatar

MIXAMO = {"pelvis": "Hips", "spine_01": "Spine", "spine_02": "Spine1", "spine_03": "Spine2", "neck_01": "Neck",
          "head": "Head"}
for _s, _side in (("l", "Left"), ("r", "Right")):
    MIXAMO |= {f"clavicle_{_s}": f"{_side}Shoulder", f"upperarm_{_s}": f"{_side}Arm",
               f"lowerarm_{_s}": f"{_side}ForeArm", f"hand_{_s}": f"{_side}Hand", f"thigh_{_s}": f"{_side}UpLeg",
               f"calf_{_s}": f"{_side}Leg", f"foot_{_s}": f"{_side}Foot", f"ball_{_s}": f"{_side}ToeBase"}
    for _f in sk.FINGERS:
        MIXAMO |= {f"{_f}_{i:02d}_{_s}": f"{_side}Hand{_f.capitalize()}{i}" for i in (1, 2, 3)}


def _rest(arm, bone):
    b = arm.data.bones[bone]
    mw = np.array(arm.matrix_world)
    return (mw @ np.append(np.array(b.head_local), 1))[:3], (mw @ np.append(np.array(b.tail_local), 1))[:3]


def test_joints_are_the_rig_bones(tmp_path):
    arm, _mesh, spec = build_procedural_avatar()
    arm.matrix_world = Matrix.Translation((1.0, 2.0, 0.5)) @ Matrix.Rotation(math.radians(-70), 4, "Z") @ \
        Matrix.Scale(0.8, 4)
    bpy.context.view_layer.update()
    rig = avatar_rig.read_rig(arm)
    assert rig.bone_map.scheme == "unreal"
    J = rig.joints
    assert np.allclose(J["pelvis"], 0.5 * (_rest(arm, "thigh_l")[0] + _rest(arm, "thigh_r")[0]))
    assert np.allclose(J["spine_root"], _rest(arm, "spine_01")[0])
    assert np.allclose(J["skull_base"], _rest(arm, "head")[0])
    assert np.allclose(J["spine_12"], J["skull_base"])
    assert np.allclose(J["head"], _rest(arm, "head")[1])
    for s in sk.SIDES:
        assert np.allclose(J[f"clavicle_{s}"], _rest(arm, f"clavicle_{s}")[0])
        assert np.allclose(J[f"elbow_{s}"], _rest(arm, f"lowerarm_{s}")[0])
        assert np.allclose(J[f"wrist_{s}"], _rest(arm, f"hand_{s}")[0])
        assert np.allclose(J[f"pip_ring_{s}"], _rest(arm, f"ring_02_{s}")[0])
        assert np.allclose(J[f"tip_thumb_{s}"], _rest(arm, f"thumb_03_{s}")[1])
        assert np.allclose(J[f"knee_{s}"], _rest(arm, f"calf_{s}")[0])
        assert np.allclose(J[f"toe_{s}"], _rest(arm, f"ball_{s}")[0])
    # 12 vertebrae of equal length along the spine + neck polyline
    spine = np.array([J[sk.spine_joint(k)] for k in range(13)])
    steps = np.linalg.norm(np.diff(spine, axis=0), axis=1)
    assert np.allclose(steps, steps.mean(), rtol=1e-6)  # the procedural spine is straight
    assert steps.sum() == pytest.approx(np.linalg.norm(J["skull_base"] - J["spine_root"]), rel=1e-6)
    assert rig.rest_pose == "T"


def test_rig_dict_reproduces_joints_by_fk():
    """world = matrix_world @ (head + matrix @ local) with the stored rig, for every joint: what
    the retargeting engine's FK relies on."""
    arm, _mesh, _spec = build_procedural_avatar(arm_drop_deg=35)
    arm.matrix_world = Matrix.Rotation(0.3, 4, "Z") @ Matrix.Scale(1.7, 4)
    bpy.context.view_layer.update()
    model = ac.calibrate_avatar(arm)
    rig = model.extra["rig"]
    mw = np.array(rig["matrix_world"])
    for b in arm.data.bones:
        stored = rig["bones"][b.name]
        assert np.allclose(stored["head"], b.head_local, atol=1e-7)
        assert np.allclose(stored["matrix"], np.array(b.matrix_local)[:3, :3], atol=1e-7)
        assert stored["parent"] == (b.parent.name if b.parent else None)
    for name, j in model.joints.items():
        bone = rig["bones"][j.frame]
        p = mw @ np.append(np.array(bone["head"]) + np.array(bone["matrix"]) @ j.local, 1.0)
        assert np.allclose(p[:3], j.world, atol=1e-6), name
    assert rig["rest_pose"] == "A"
    assert rig["bones"]["spine_02"]["segment"] == "spine" and rig["bones"]["spine_02"]["chain_index"] == 1
    assert rig["bones"]["lowerarm_l"]["segment"] == "forearm_l"


def test_hinge_right_is_local_x_and_overridable():
    arm, _mesh, _spec = build_procedural_avatar()
    rig = avatar_rig.read_rig(arm)
    x = np.array(arm.data.bones["lowerarm_l"].matrix_local)[:3, 0]
    assert np.allclose(rig.rights["forearm_l"], x, atol=1e-6)
    # the upper arm shares the elbow's axis (one rule with the user model)
    assert np.allclose(rig.rights["upperarm_l"], x, atol=1e-6)
    avatar_rig.set_hinge_axis(arm, "forearm_l", (0.0, 0.0, 1.0))
    rig2 = avatar_rig.read_rig(arm)
    z = np.array(arm.data.bones["lowerarm_l"].matrix_local)[:3, 2]
    assert np.allclose(rig2.rights["forearm_l"], z, atol=1e-6)
    with pytest.raises(BodyCalError, match="not a hinge"):
        avatar_rig.set_hinge_axis(arm, "thigh_l", (1, 0, 0))


def test_mixamo_names_give_the_same_model():
    arm, _mesh, _spec = build_procedural_avatar()
    ref = ac.calibrate_avatar(arm)
    for old, new in MIXAMO.items():
        arm.data.bones[old].name = new
    model = ac.calibrate_avatar(arm)
    assert model.extra["rig"]["scheme"] == "mixamo"
    for j, joint in ref.joints.items():
        assert np.allclose(model.joints[j].world, joint.world, atol=1e-7), j
        assert model.joints[j].frame == MIXAMO.get(joint.frame, joint.frame)
    for b, info in ref.bones.items():
        if info.radius_head is not None:
            assert model.bones[b].radius_head == pytest.approx(info.radius_head, abs=1e-6)
    assert model.element("sphere:skull").radius == pytest.approx(ref.element("sphere:skull").radius, abs=1e-6)


def test_not_humanoid_lists_missing_segments():
    arm_data = bpy.data.armatures.new("crane")
    arm = bpy.data.objects.new("crane", arm_data)
    bpy.context.scene.collection.objects.link(arm)
    bpy.context.view_layer.objects.active = arm
    bpy.ops.object.mode_set(mode="EDIT")
    for i, n in enumerate(("base", "boom", "hook")):
        eb = arm_data.edit_bones.new(n)
        eb.head, eb.tail = (0, 0, i), (0, 0, i + 1)
    bpy.ops.object.mode_set(mode="OBJECT")
    with pytest.raises(BodyCalError) as exc:
        avatar_rig.read_rig(arm)
    msg = str(exc.value)
    assert "missing" in msg and "pelvis" in msg and "thigh_l" in msg and "forearm_r" in msg
    assert "\n" not in msg


def test_override_fixes_an_unmapped_bone_and_is_saved(tmp_path):
    arm, _mesh, _spec = build_procedural_avatar()
    arm.data.bones["calf_l"].name = "LegLower_Left"
    with pytest.raises(BodyCalError, match="shin_l"):
        avatar_rig.read_rig(arm)
    avatar_rig.set_override(arm, "shin_l", "LegLower_Left")
    with pytest.raises(BodyCalError, match="no bone 'nope'"):
        avatar_rig.set_override(arm, "shin_r", "nope")
    path = tmp_path / "mapped.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.open_mainfile(filepath=str(path))
    arm = bpy.data.objects["procedural"]
    rig = avatar_rig.read_rig(arm)
    assert rig.bone_map.bones["shin_l"] == "LegLower_Left"
    assert rig.bone_map.scheme.endswith("+custom")
    assert rig.joint_frames["knee_l"] == "LegLower_Left"
    # a chain override: the spine without its top bone
    avatar_rig.set_override(arm, "spine", "spine_01,spine_02")
    assert avatar_rig.bone_map_for(arm).chains["spine"] == ["spine_01", "spine_02"]
    avatar_rig.clear_overrides(arm)
    assert "shin_l" not in avatar_rig.bone_map_for(arm).bones


def test_rigify_metarig_maps_and_reads():
    import addon_utils

    addon_utils.enable("rigify", default_set=False)
    try:
        bpy.ops.object.armature_human_metarig_add()
        arm = bpy.context.active_object
        rig = avatar_rig.read_rig(arm)
    finally:
        addon_utils.disable("rigify", default_set=False)
    assert rig.bone_map.scheme == "rigify_metarig"
    assert not [m for m in rig.missing if m.startswith("fingers")]
    assert all(j in rig.joints for j in sk.JOINTS)
    assert rig.joints["head"][2] > rig.joints["skull_base"][2] > rig.joints["spine_root"][2] > rig.joints["knee_l"][2]
    assert rig.joints["shoulder_l"][0] > 0 > rig.joints["shoulder_r"][0]


def test_model_is_what_the_retargeting_engine_reads(avatar_files):
    """Contract with the retargeting engine (retarget.avatar_pose): it reads the calibrated model
    of a real rig and its canonical frames carry the model's rights; on the procedural A-pose
    avatar, solving for the rest frames gives the rest pose back (identity pose bones, joints in
    place)."""
    from bodycal_addon.body import rest_frames
    from bodycal_addon.retarget import avatar_pose as ap

    arm, _mesh = load_glb_avatar(avatar_files[0])
    model = ac.calibrate_avatar(arm)
    ap.AvatarRig.from_model(model)
    frames = rest_frames.model_rest_frames(model)
    for i, b in enumerate(sk.BONES):
        if b.name in model.bones:
            assert np.allclose(frames[i][:, 0], model.bones[b.name].right, atol=1e-6), b.name
    bpy.ops.wm.read_homefile(use_empty=True)
    arm, _mesh, _spec = build_procedural_avatar(arm_drop_deg=30)
    model = ac.calibrate_avatar(arm)
    rig = ap.AvatarRig.from_model(model)
    pose = rig.solve(rig.frames0[None], model.joints["pelvis"].world[None])
    assert np.allclose(np.abs(pose.basis[0, :, 0]), 1.0, atol=1e-6)
    joints = np.array([model.joints[j].world for j in sk.JOINTS])
    assert np.allclose(pose.joints[0], joints, atol=1e-5)
