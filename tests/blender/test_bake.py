"""Baking an AvatarAnimation: a new action, exact keys, nothing overwritten or left behind."""

import bpy
import numpy as np
import pytest

from bodycal_addon.blender.bake import bake_animation, plan_bake, write_bake
from bodycal_addon.blender.fcurves import object_fcurves, read_keys
from bodycal_addon.body.animation import AvatarAnimation
from bodycal_addon.core import paths
from bodycal_addon.core import transforms as tf
from bodycal_addon.core.errors import BodyCalError
from bodycal_addon.core.transforms import continuous_quaternions

rigs = paths.sample_rigs()
BONES = ["upperarm_l", "lowerarm_l", "thigh_r", "spine_02", "head"]


def _animation(frames=120, seed=0):
    rng = np.random.default_rng(seed)
    q = tf.quat_normalize(rng.normal(size=(frames, len(BONES), 4)))
    return AvatarAnimation("procedural", list(BONES), q, "pelvis", rng.normal(size=(frames, 3)) * 0.1,
                           np.arange(frames) / 30.0, method="egocentric")


def _armature():
    arm, _mesh, _spec = rigs.build_procedural_avatar()
    return arm


def test_keys_reproduce_the_animation_exactly_in_the_pose():
    arm = _armature()
    anim = _animation()
    bpy.context.scene.render.fps = 30
    result = bake_animation(anim, arm, action_name="rec|procedural|egocentric", tolerance_deg=0.0,
                            location_tolerance_mm=0.0)
    assert arm.animation_data.action == result.action
    assert result.keys == anim.frame_count * (4 * len(BONES) + 3)
    q = continuous_quaternions(anim.rotations)
    for f in (0, 37, 119):
        bpy.context.scene.frame_set(int(bpy.context.scene.frame_start + f))
        for b, name in enumerate(BONES):
            got = np.array(arm.pose.bones[name].rotation_quaternion)
            np.testing.assert_allclose(got, q[f, b], atol=1e-6)
        np.testing.assert_allclose(np.array(arm.pose.bones["pelvis"].location), anim.root_location[f], atol=1e-6)
    # Between keys the curves interpolate linearly (dense samples: no overshoot).
    fc = next(fc for fc in object_fcurves(arm).values() if fc.data_path.endswith('"lowerarm_l"].rotation_quaternion')
              and fc.array_index == 2)
    for f in (10, 64):
        mid = fc.evaluate(bpy.context.scene.frame_start + f + 0.5)
        assert abs(mid - (q[f, 1, 2] + q[f + 1, 1, 2]) / 2) < 1e-6


def test_existing_action_is_kept_unless_replace_is_asked():
    arm = _armature()
    mine = bpy.data.actions.new("rec|procedural|egocentric")
    mine.use_fake_user = True
    first = bake_animation(_animation(), arm, action_name="rec|procedural|egocentric")
    assert first.action.name == "rec|procedural|egocentric.001"
    assert bpy.data.actions.get("rec|procedural|egocentric") == mine
    second = bake_animation(_animation(seed=1), arm, action_name="rec|procedural|egocentric", replace=True)
    assert second.replaced == "rec|procedural|egocentric"
    assert second.action.name == "rec|procedural|egocentric"
    assert "rec|procedural|egocentric.001" in bpy.data.actions  # the first bake is the user's now too


def test_failure_before_writing_changes_nothing():
    arm = _armature()
    previous = bpy.data.actions.new("previous")
    arm.animation_data_create().action = previous
    for b in BONES:
        arm.pose.bones[b].rotation_mode = "XYZ"
    bad = _animation()
    bad.rotations[5, 1, 2] = np.nan
    n_actions = len(bpy.data.actions)
    with pytest.raises(BodyCalError, match="non-finite"):
        bake_animation(bad, arm)
    missing = _animation()
    missing.bone_names[0] = "no_such_bone"
    with pytest.raises(BodyCalError, match="no_such_bone"):
        bake_animation(missing, arm)
    assert len(bpy.data.actions) == n_actions
    assert arm.animation_data.action == previous
    # Validation runs before anything is touched: the bones keep their rotation mode.
    assert {arm.pose.bones[b].rotation_mode for b in BONES} == {"XYZ"}


def test_planning_changes_nothing_and_the_write_keys_exactly_the_plan():
    """The bake's two passes: `plan_bake` reads the scene and changes nothing in it (no action, no
    assignment, no rotation mode, no pose, no frame range); `write_bake` writes the plan's keys, no
    other, into one new action that replaces the old one."""
    arm = _armature()
    previous = bpy.data.actions.new("rec|procedural|egocentric")
    arm.animation_data_create().action = previous
    for b in BONES:
        arm.pose.bones[b].rotation_mode = "XYZ"
    arm.pose.bones["head"].location = (0.01, 0.02, 0.03)
    arm.pose.bones["head"]["switch"] = 0.0  # a Rigify-style switch, keyed once
    scene = bpy.context.scene
    scene_range = (scene.frame_start, scene.frame_end)
    anim = _animation()
    anim.constant_keys = {'pose.bones["head"]["switch"]': 1.0}
    actions = sorted(a.name for a in bpy.data.actions)
    plan = plan_bake(anim, arm, action_name="rec|procedural|egocentric", replace=True, frame_start=1.0,
                     tolerance_deg=0.5, location_tolerance_mm=1.0)
    assert sorted(a.name for a in bpy.data.actions) == actions
    assert arm.animation_data.action == previous and len(object_fcurves(arm)) == 0
    assert {arm.pose.bones[b].rotation_mode for b in BONES} == {"XYZ"}
    assert tuple(arm.pose.bones["head"].location) == pytest.approx((0.01, 0.02, 0.03))
    assert (scene.frame_start, scene.frame_end) == scene_range
    assert plan.replaces == "rec|procedural|egocentric" and plan.quaternion_bones == tuple(BONES)
    assert 0 < plan.keys < plan.fcurves * anim.frame_count  # the reduction thinned the keys

    result = write_bake(plan, arm)
    assert arm.animation_data.action == result.action and result.replaced == "rec|procedural|egocentric"
    assert result.action.name == "rec|procedural|egocentric" and len(bpy.data.actions) == len(actions)
    assert (result.keys, result.fcurves) == (plan.keys, plan.fcurves)
    curves = object_fcurves(arm)
    assert len(curves) == plan.fcurves
    for prop in plan.properties:
        for i in range(prop.values.shape[1]):
            frames, values = read_keys(curves[prop.data_path, i])
            np.testing.assert_array_equal(frames, plan.frames32[prop.kept])
            np.testing.assert_array_equal(values, prop.values[prop.kept, i])
    assert {arm.pose.bones[b].rotation_mode for b in BONES} == {"QUATERNION"}


def test_push_to_nla_leaves_a_strip_and_no_active_action():
    arm = _armature()
    result = bake_animation(_animation(), arm, action_name="nla test", push_to_nla=True)
    assert arm.animation_data.action is None
    track = arm.animation_data.nla_tracks[result.nla_track]
    assert track.strips[0].action == result.action


def test_quaternion_continuity_removes_sign_flips():
    q = tf.quat_normalize(np.random.default_rng(2).normal(size=(50, 3, 4)))
    smooth = np.repeat(q[:1], 50, axis=0) * np.where(np.arange(50) % 2, -1, 1)[:, None, None]
    out = continuous_quaternions(smooth)
    assert np.all((out[1:] * out[:-1]).sum(-1) > 0)
    np.testing.assert_allclose(np.abs((out * smooth).sum(-1)), 1.0)
