"""Step 2 and the bake contract: canonical frames -> pose-bone rotations (Blender's matrix_basis)
-> Blender's own FK puts the avatar's joints exactly where the engine says they are."""

from __future__ import annotations

import bpy
import numpy as np
import pytest
from mathutils import Matrix

from bodycal_addon.blender.bake import bake_animation
from bodycal_addon.body import skeleton as sk
from bodycal_addon.body.skeleton import BONE_INDEX as BI
from bodycal_addon.body.skeleton import JOINT_INDEX as JI
from bodycal_addon.core import one_frame
from bodycal_addon.core.errors import BodyCalError
from bodycal_addon.core.transforms import normalize, quat_to_matrix
from bodycal_addon.retarget import avatar_pose as ap
from bodycal_addon.retarget import pipeline as pl
from bodycal_dev import retarget_fixtures as rt
from bodycal_dev import synthetic
from sample_rigs import build_procedural_avatar, procedural

# canonical joint -> (procedural bone, "head" | "tail"): read straight off Blender's pose bones.
BLENDER_JOINTS = {
    "pelvis": ("pelvis", "head"), "skull_base": ("head", "head"), "head": ("head", "tail"),
    "shoulder_l": ("upperarm_l", "head"), "elbow_l": ("lowerarm_l", "head"), "wrist_l": ("hand_l", "head"),
    "shoulder_r": ("upperarm_r", "head"), "elbow_r": ("lowerarm_r", "head"), "wrist_r": ("hand_r", "head"),
    "hip_l": ("thigh_l", "head"), "knee_l": ("calf_l", "head"), "ankle_l": ("foot_l", "head"),
    "knee_r": ("calf_r", "head"), "ankle_r": ("foot_r", "head"), "toe_r": ("ball_r", "head"),
    "tip_index_l": ("index_03_l", "tail"), "tip_thumb_r": ("thumb_03_r", "tail"),
    "pip_middle_l": ("middle_02_l", "head"),
}


def _random_frames(rig, n, seed=0, amount=0.4):
    rng = np.random.default_rng(seed)
    q = normalize(np.concatenate([np.ones((n, len(sk.BONES), 1)), amount * rng.normal(size=(n, len(sk.BONES), 3))],
                                 -1))
    return quat_to_matrix(q) @ rig.frames0


@pytest.mark.parametrize("world", [None, rt.rigid_matrix_world(35.0, 1.4)])
@pytest.mark.parametrize("drop", [0.0, 40.0])
def test_solve_then_fk_reproduces_joints_and_frames(world, drop):
    rig = ap.AvatarRig.from_model(rt.procedural_avatar(matrix_world=world, arm_drop_deg=drop))
    frames = _random_frames(rig, 7, seed=int(drop))
    pelvis = rig.joint_world[JI["pelvis"]] + np.linspace(0, 0.3, 7)[:, None]
    pose = rig.solve(frames, pelvis)
    again = rig.fk(pose.basis, pose.root_location)
    np.testing.assert_allclose(again.joints, pose.joints, atol=1e-9)
    np.testing.assert_allclose(pose.joints[:, JI["pelvis"]], pelvis, atol=1e-9)
    # Every canonical bone the rig has a bone for is realised exactly (vertebrae are resampled).
    for b in ("sacrum", "head", "upperarm_l", "forearm_r", "hand_l", "thigh_r", "shin_l", "foot_r", "index_2_l",
              "thumb_3_r", "clavicle_l"):
        np.testing.assert_allclose(pose.frames[:, BI[b]], frames[:, BI[b]], atol=1e-9, err_msg=b)
    # The bone lengths follow the frames: elbow = shoulder + L * Y(upperarm).
    length = rig.lengths[BI["upperarm_l"]]
    np.testing.assert_allclose(pose.joints[:, JI["elbow_l"]],
                               pose.joints[:, JI["shoulder_l"]] + length * frames[:, BI["upperarm_l"]][..., :, 1],
                               atol=1e-9)


@pytest.mark.parametrize("world", [None, rt.rigid_matrix_world(35.0, 1.4)])
def test_joint_positions_of_a_few_joints_match_the_full_solve(world):
    # The IK poses only the bones the limb roots hang from; they must land where the full solve puts them.
    rig = ap.AvatarRig.from_model(rt.procedural_avatar(matrix_world=world, arm_drop_deg=30.0))
    frames = _random_frames(rig, 6, seed=5)
    pelvis = rig.joint_world[JI["pelvis"]] + np.linspace(0, 0.2, 6)[:, None]
    names = ["shoulder_l", "hip_r", "skull_base", "tip_index_l"]
    full = rig.solve(frames, pelvis, basis=False, realised=False).joints
    np.testing.assert_allclose(rig.joint_positions(frames, pelvis, names), full[:, [JI[j] for j in names]],
                               atol=1e-12)


@pytest.mark.parametrize("mathutils_path", [False, True])
def test_rest_frames_give_the_identity_pose(mathutils_path, monkeypatch):
    # one frame: numpy's path exactly; mathutils' (its spine chain aimed in float32, DESIGN.md
    # "Prepared solver") to float32's rounding
    monkeypatch.setattr(one_frame, "ENABLED", mathutils_path)
    atol = 1e-6 if mathutils_path else 1e-12
    rig = ap.AvatarRig.from_model(rt.procedural_avatar(matrix_world=rt.rigid_matrix_world(20.0, 0.8)))
    pose = rig.solve(rig.frames0[None], rig.joint_world[JI["pelvis"]][None])
    np.testing.assert_allclose(np.abs(pose.basis[..., 0]), 1.0, atol=atol)
    np.testing.assert_allclose(pose.root_location, 0.0, atol=atol)
    np.testing.assert_allclose(pose.joints[0], rig.joint_world, atol=atol)


def test_armature_placement_does_not_move_the_world_pose():
    perf = synthetic.make_performer(seed=2)
    user = synthetic.record_session(perf, motions=("clap",), calibration=False, motion_seconds=0.5)[1].body_model()
    a = ap.AvatarRig.from_model(rt.avatar_from_user(user))
    b = ap.AvatarRig.from_model(rt.avatar_from_user(user, matrix_world=rt.rigid_matrix_world(50.0, 2.0)))
    frames = _random_frames(a, 5, seed=4)
    pel = np.tile(a.joint_world[JI["pelvis"]], (5, 1))
    np.testing.assert_allclose(a.solve(frames, pel).joints, b.solve(frames, pel).joints, atol=1e-9)


def test_missing_rig_or_mapping_is_one_clear_error():
    model = rt.procedural_avatar()
    broken = rt.procedural_avatar()
    broken.extra = {}
    with pytest.raises(BodyCalError, match="no rig"):
        ap.AvatarRig.from_model(broken)
    unmapped = rt.procedural_avatar()
    unmapped.extra["rig"]["bone_map"]["bones"].pop("upperarm_l")
    with pytest.raises(BodyCalError, match="upperarm_l"):
        ap.AvatarRig.from_model(unmapped)
    no_joint = rt.procedural_avatar()
    no_joint.joints.pop("elbow_r")
    with pytest.raises(BodyCalError, match="elbow_r"):
        ap.AvatarRig.from_model(no_joint)
    assert ap.AvatarRig.from_model(model).names


@pytest.fixture(scope="module")
def session():
    perf = synthetic.make_performer(seed=0, build="heavy")
    rec, truth = synthetic.record_session(perf, motions=("hand_on_belly", "clap"), calibration=False,
                                          motion_seconds=1.0)
    return rec, truth.body_model()


def _blender_joint(arm, bone, end):
    pb = arm.pose.bones[bone]
    return np.array(arm.matrix_world @ (pb.head if end == "head" else pb.tail))


@pytest.mark.slow
@pytest.mark.parametrize("method", ["egocentric", "offsets", "rotations"])
@pytest.mark.parametrize("case", ["rotated_scaled_tpose", "apose"])
def test_bake_contract_blender_fk_reproduces_the_joints(session, method, case):
    """The AvatarAnimation, baked as keys and evaluated by Blender, puts every joint where
    `joints_world` says (within 0.1 mm), with a rotated, scaled, moved armature and an A-pose rig."""
    rec, user = session
    if case == "apose":
        spec, world = procedural.build_spec(arm_drop_deg=35.0), np.eye(4)
    else:
        spec, world = procedural.build_spec(), rt.rigid_matrix_world(25.0, 1.3)
    arm, _mesh, _ = build_procedural_avatar(spec)
    arm.matrix_world = Matrix(world.tolist())
    avatar = rt.procedural_avatar(spec, matrix_world=world)
    anim = pl.retarget(rec, user, avatar, method, chunk_frames=64)
    anim.armature = arm.name
    # One key per integer frame, no key reduction: this is the every-frame contract.
    bake_animation(anim, arm, fps=rec.fps, frame_start=1.0, tolerance_deg=0.0, location_tolerance_mm=0.0)
    scene = bpy.context.scene
    for f in np.linspace(0, anim.frame_count - 1, 6).astype(int):
        scene.frame_set(int(f) + 1)
        for joint, (bone, end) in BLENDER_JOINTS.items():
            got = _blender_joint(arm, bone, end)
            np.testing.assert_allclose(got, anim.joints_world[joint][f], atol=1e-4,
                                       err_msg=f"{method} {case} frame {f} {joint}")
