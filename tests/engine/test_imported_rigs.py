"""Rigs as importers and other tools leave them (DESIGN.md §2, "Rigs as files bring them"), read by
the engine on the procedural avatar's exact shapes: bone tails an importer guessed, bone rolls
that are not the hinge's axis, fingers the mesh does not model, a rig no naming scheme reads
(mapped from its shape), a pelvis the thighs do not hang from, a foot that is an IK control."""

from __future__ import annotations

import numpy as np
import pytest
from test_avatar_rays import AnalyticCaster, _rest_bones

from bodycal_addon.avatar import armature
from bodycal_addon.avatar.rays import surface_from_rays
from bodycal_addon.avatar.structure import map_by_structure
from bodycal_addon.body import naming
from bodycal_addon.core.errors import BodyCalError
from sample_rigs import procedural


def _read(bones, bm=None):
    return armature.read_armature("rig", np.eye(4), bones, bm or naming.detect_bone_map(list(bones)))


def test_importer_guessed_tails_are_placed_by_proportion():
    """glTF nodes have no length: a 0.01-scaled Mixamo thumb's tail came out 2 m away (its
    capsule's rays all missed), a Quaternius head bone 9 mm tall."""
    spec = procedural.build_spec()
    bones = _rest_bones(spec)
    truth = _read(_rest_bones(spec))
    for name, length in (("index_03_l", 2.0), ("head", 0.009), ("thumb_03_r", 1.5)):
        b = bones[name]
        b["tail"] = b["head"] + b["matrix"][:, 1] * length
    rig = _read(bones)
    assert set(rig.estimated) == {"tip_index_l", "head", "tip_thumb_r"}
    for tip, (dip, pip) in (("tip_index_l", ("dip_index_l", "pip_index_l")),
                            ("tip_thumb_r", ("dip_thumb_r", "pip_thumb_r"))):
        phalanx = np.linalg.norm(rig.joints[dip] - rig.joints[pip])
        assert np.linalg.norm(rig.joints[tip] - rig.joints[dip]) == pytest.approx(0.85 * phalanx)
        assert np.linalg.norm(rig.joints[tip] - truth.joints[tip]) < 0.01
    assert np.linalg.norm(rig.joints["head"] - rig.joints["skull_base"]) > 0.1  # not the 9 mm bone


def test_a_child_in_line_marks_where_a_bone_ends():
    """Mixamo's HeadTop_End and Thumb4 leaves: the end of the chain, whatever the tail says."""
    spec = procedural.build_spec()
    bones = _rest_bones(spec)
    top = bones["head"]["head"] + np.array([0.0, 0.0, 0.21])
    bones["head"]["tail"] = bones["head"]["head"] + np.array([0.0, 0.0, 3.0])
    bones["HeadTop_End"] = {"parent": "head", "head": top, "tail": top + [0, 0, 0.01],
                            "matrix": bones["head"]["matrix"]}
    rig = _read(bones)
    assert np.allclose(rig.joints["head"], top) and "head" not in rig.estimated


def _turned(matrix, columns):
    """A bone's rest axes with its X (flexion) somewhere else: `columns` picks and signs the
    new X, Y, Z from the old ones (its Y stays along the bone)."""
    return np.stack([s * matrix[:, k] for s, k in columns], axis=1)


@pytest.mark.parametrize("bone, hinge, columns", [
    ("lowerarm_l", "forearm_l", ((1, 2), (1, 1), (-1, 0))),  # X = the old Z: a quarter turn of roll
    ("calf_r", "shin_r", ((-1, 0), (1, 1), (-1, 2))),  # X reversed: the knee would bend forward
    ("index_02_l", "index_2_l", ((1, 1), (-1, 0), (1, 2))),  # X along the bone: 'override its hinge axis'
])
def test_a_hinge_axis_an_import_left_wrong_comes_from_the_chain(bone, hinge, columns):
    spec = procedural.build_spec(arm_drop_deg=30.0)
    truth = _read(_rest_bones(spec))
    bones = _rest_bones(spec)
    bones[bone]["matrix"] = _turned(bones[bone]["matrix"], columns)
    rig = _read(bones)
    assert rig.derived_hinges == [hinge]
    assert np.dot(rig.hinges[hinge], truth.hinges[hinge]) > 0.97, rig.hinges[hinge]


def test_a_finger_the_mesh_does_not_model_is_estimated_and_noted():
    """A mitten hand: no ray from the left index finger's bones hits anything of its own."""
    spec = procedural.build_spec()
    rig = _read(_rest_bones(spec))
    caster = AnalyticCaster(spec, np.eye(4))
    caster.capsules = [(c["head"], c["tail"], c["radius"]) for n, c in spec.truth["capsules"].items()
                       if not n.startswith("index_0") or not n.endswith("_l")]
    model = surface_from_rays(rig, caster, "rig")
    for i in (1, 2, 3):
        assert model.calibration["quality"][f"capsule:index_{i}_l"] == {"estimated": True}
        assert "rays from bone index_0" in model.calibration["defaulted"][f"capsule:index_{i}_l"]
        assert 0.2 < model.bones[f"index_{i}_l"].radius_head / model.bones[f"index_{i}_l"].length < 0.5
    assert "capsule:index_2_r" not in model.calibration["defaulted"]


# --- a rig no scheme names: Cesium Man's, as Blender imports it (heads in armature space, Z up) ----------

CESIUM = {
    "Skeleton_torso_joint_1": (None, (0.005, 0.0, 0.679)),
    "Skeleton_torso_joint_2": ("Skeleton_torso_joint_1", (0.005, -0.011, 0.824)),
    "torso_joint_3": ("Skeleton_torso_joint_2", (0.005, 0.004, 1.074)),
    "Skeleton_neck_joint_1": ("torso_joint_3", (0.005, -0.006, 1.138)),
    "Skeleton_neck_joint_2": ("Skeleton_neck_joint_1", (0.005, -0.008, 1.19)),
    "Skeleton_arm_joint_L__4_": ("torso_joint_3", (0.096, 0.004, 1.074)),
    "Skeleton_arm_joint_L__3_": ("Skeleton_arm_joint_L__4_", (0.312, 0.016, 0.964)),
    "Skeleton_arm_joint_L__2_": ("Skeleton_arm_joint_L__3_", (0.455, -0.066, 0.875)),
    "Skeleton_arm_joint_R": ("torso_joint_3", (-0.086, 0.004, 1.074)),
    "Skeleton_arm_joint_R__2_": ("Skeleton_arm_joint_R", (-0.301, 0.016, 0.965)),
    "Skeleton_arm_joint_R__3_": ("Skeleton_arm_joint_R__2_", (-0.445, -0.067, 0.875)),
    "leg_joint_L_1": ("Skeleton_torso_joint_1", (0.073, -0.024, 0.614)),
    "leg_joint_L_2": ("leg_joint_L_1", (0.082, -0.068, 0.352)),
    "leg_joint_L_3": ("leg_joint_L_2", (0.083, 0.005, 0.086)),
    "leg_joint_L_5": ("leg_joint_L_3", (0.085, -0.027, 0.021)),
    "leg_joint_R_1": ("Skeleton_torso_joint_1", (-0.063, -0.024, 0.614)),
    "leg_joint_R_2": ("leg_joint_R_1", (-0.072, -0.068, 0.352)),
    "leg_joint_R_3": ("leg_joint_R_2", (-0.073, 0.005, 0.086)),
    "leg_joint_R_5": ("leg_joint_R_3", (-0.075, -0.027, 0.021)),
}


def test_a_rig_no_scheme_names_is_mapped_from_its_shape():
    rest = {n: (p, np.array(h)) for n, (p, h) in CESIUM.items()}
    assert naming.detect_bone_map(list(rest)).missing()  # no scheme reads these names
    # Y-up bones (an FBX's) under any order of the bones: the same map
    turn = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])
    turned = {n: (p, turn @ h) for n, (p, h) in reversed(list(rest.items()))}
    for bm in (map_by_structure(rest, np.array([0.0, 0, 1])), map_by_structure(turned, turn @ [0.0, 0, 1])):
        assert bm.scheme == "structure" and bm.missing() == []
        assert bm.bones["pelvis"] == "Skeleton_torso_joint_1" and bm.bones["head"] == "Skeleton_neck_joint_2"
        assert bm.chains == {"spine": ["Skeleton_torso_joint_2", "torso_joint_3"], "neck": ["Skeleton_neck_joint_1"]}
        assert (bm.bones["upperarm_r"], bm.bones["forearm_r"], bm.bones["hand_r"]) == (
            "Skeleton_arm_joint_R", "Skeleton_arm_joint_R__2_", "Skeleton_arm_joint_R__3_")
        assert (bm.bones["thigh_l"], bm.bones["shin_l"], bm.bones["foot_l"], bm.bones["toe_l"]) == (
            "leg_joint_L_1", "leg_joint_L_2", "leg_joint_L_3", "leg_joint_L_5")
        assert "clavicle_l" not in bm.bones  # a three-bone arm hangs from the chest
    unsided = {n.replace("_L", "_A").replace("_R", "_B"): (p and p.replace("_L", "_A").replace("_R", "_B"), h)
               for n, (p, h) in rest.items()}
    assert map_by_structure(unsided, np.array([0.0, 0, 1])) is None  # which side is which: nothing says


def test_a_rig_without_clavicles_reads_with_the_arms_hanging_from_the_chest():
    rest = {n: {"parent": p, "head": np.array(h), "tail": np.array(h) + [0, 0, 0.05], "matrix": np.eye(3)}
            for n, (p, h) in CESIUM.items()}
    bm = map_by_structure({n: (b["parent"], b["head"]) for n, b in rest.items()}, np.array([0.0, 0, 1]))
    rig = _read(rest, bm)
    assert "clavicle_l" not in rig.joints and "clavicle_l (the arm hangs from the spine)" in rig.missing
    assert np.allclose(rig.joints["shoulder_l"], CESIUM["Skeleton_arm_joint_L__4_"][1])


def test_a_pelvis_the_thighs_do_not_hang_from_gives_way_to_the_one_they_do():
    """Quaternius: Root -> Hips -> Abdomen and Root -> UpperLeg.L; the thighs and the spine hang
    from Root, which was refused ('map pelvis to Root')."""
    spec = procedural.build_spec()
    bones = _rest_bones(spec)
    for thigh in ("thigh_l", "thigh_r"):
        bones[thigh]["parent"] = "Root"
    bm = naming.detect_bone_map(list(bones))
    with pytest.raises(BodyCalError, match="map pelvis to 'Root'"):
        _read(bones, bm)
    note = armature.settle_pelvis(bm, {n: b["parent"] for n, b in bones.items()})
    assert bm.bones["pelvis"] == "Root" and "root" not in bm.bones and "pelvis" in bm.unmapped
    assert note.startswith("pelvis: 'Root'")
    assert _read(bones, bm).joints["pelvis"] is not None


def test_a_foot_beside_the_leg_is_posed_from_the_shin():
    """RobotExpressive's and Quaternius' knight's feet are IK controls under the root (refused with
    'does not hang from the shin bone'): the engine poses the foot as if it hung from the shin, and
    the model's rig says which bones the bake keys in the armature's space."""
    spec = procedural.build_spec()
    truth = _read(_rest_bones(spec))
    bones = _rest_bones(spec)
    bones["foot_l"]["parent"] = "Root"
    rig = _read(bones)
    assert rig.armature_space == {"foot_l": "Root"} and rig.bones["foot_l"]["parent"] == "calf_l"
    assert rig.rig_dict()["armature_space"] == {"foot_l": "Root"} and "armature_space" not in truth.rig_dict()
    assert all(np.allclose(rig.joints[j], truth.joints[j]) for j in truth.joints)


def test_a_limb_mapped_upside_down_is_one_line():
    spec = procedural.build_spec()
    bones = _rest_bones(spec)
    bm = naming.detect_bone_map(list(bones))
    bm.bones["shin_l"], bm.bones["foot_l"] = bm.bones["foot_l"], bm.bones["shin_l"]
    with pytest.raises(BodyCalError, match=r"the foot bone 'calf_l' does not hang from the shin bone 'foot_l', which "
                                           r"hangs from it") as info:
        _read(bones, bm)
    assert "\n" not in str(info.value)


def _chain(n, parents):
    out = []
    while n is not None:
        out.append(n)
        n = parents.get(n)
    return out


@pytest.mark.parametrize("local_location", [True, False])
def test_the_bake_keys_a_loose_foot_so_blender_poses_it_where_the_engine_did(local_location):
    """output/armature_space.py: any pose of the rig (every bone turned, the travel on the pelvis,
    the foot's parent in the file turned too) keyed with the foot's location and rotation relative
    to its parent in the file gives every bone the armature-space pose the engine's hierarchy
    gives (Blender's pose rule, rigify.pose_matrices; Local Location off: the location along the
    parent's axes, as Blender reads it)."""
    from bodycal_addon.body.animation import AvatarAnimation
    from bodycal_addon.core import transforms as tf
    from bodycal_addon.output import rigify
    from bodycal_addon.output.armature_space import ArmatureSpacePlan, keyed_in_armature_space

    bones = _rest_bones(procedural.build_spec())
    rest = {n: rigify.rest_matrix(b["matrix"], b["head"]) for n, b in bones.items()}
    engine = {n: b["parent"] for n, b in bones.items()}
    file = dict(engine, foot_l="Root")
    names = sorted(bones, key=lambda n: len(_chain(n, engine)))
    rng = np.random.default_rng(4)
    frames = 7
    rot = tf.quat_normalize(np.array([1.0, 0, 0, 0]) + 0.4 * rng.normal(size=(frames, len(names), 4)))
    anim = AvatarAnimation("rig", names, rot, "pelvis", rng.normal(size=(frames, 3)) * 0.2, np.arange(frames) / 30.0)
    plan = ArmatureSpacePlan({"foot_l": "calf_l"}, file, rest, {"foot_l": local_location})
    keyed = keyed_in_armature_space(anim, plan)
    assert set(keyed.bone_locations) == {"foot_l"} and keyed.notes and not anim.bone_locations

    def poses(a, parents):
        basis = {}
        for k, n in enumerate(a.bone_names):
            loc = a.root_location if n == a.root_bone else a.bone_locations.get(n)
            if n == "foot_l" and loc is not None and not local_location:  # Blender: along the parent's axes
                off = np.linalg.inv(rest["Root"]) @ rest["foot_l"]
                loc = loc @ off[:3, :3]
            basis[n] = rigify.basis_matrices(a.rotations[:, k], loc)
        return rigify.pose_matrices(sorted(a.bone_names, key=lambda n: len(_chain(n, parents))), parents, rest, basis)

    want, got = poses(anim, engine), poses(keyed, file)
    for n in ("foot_l", "ball_l", "calf_l", "Root", "foot_r"):
        assert np.allclose(got[n], want[n], atol=1e-9), n
    assert not np.allclose(poses(anim, file)["foot_l"], want["foot_l"], atol=1e-3)  # the engine's keys as they were
    assert keyed_in_armature_space(keyed, plan) is keyed  # keyed once
