"""The timeline preview (Retarget and Bake > Preview): the avatar follows the scene's recording as
the timeline moves, showing at each frame what the bake then keys there, and leaves the armature
(and the saved file) as it was."""

import importlib

import bpy
import numpy as np
import pytest

from bodycal_addon.blender import calibration_scene, recording_scene
from bodycal_addon.core import paths
from bodycal_dev import synthetic

rigs = paths.sample_rigs()
preview = importlib.import_module("bl_ext.user_default.bodycal.bodycal_addon.blender.preview")  # the extension's state


@pytest.fixture(scope="module")
def session():
    performer = synthetic.make_performer(seed=3)
    rec, truth = synthetic.record_session(performer, profile="full", motions=("hand_on_belly", "walk_in_place"),
                                          calibration=["tpose"], seed=3, motion_seconds=1.0)
    rec.name = "belly"
    return rec, truth


@pytest.fixture(autouse=True)
def no_preview_left():
    yield
    preview.stop_all()


def _ready(session, frame_start=101):
    rec, truth = session
    scene = bpy.context.scene
    arm, _mesh, _spec = rigs.build_procedural_avatar()
    recording_scene.import_recording_to_scene(rec, scene, frame_start=frame_start)
    calibration_scene.store_user_model(scene, truth.body_model())
    bake = scene.bodycal_bake
    bake.armature, bake.tolerance, bake.location_tolerance = arm, 0.0, 0.0
    return arm


def _pose(arm) -> tuple[np.ndarray, np.ndarray, list[str]]:
    bones = arm.pose.bones
    q = np.empty(len(bones) * 4, np.float32)
    loc = np.empty(len(bones) * 3, np.float32)
    bones.foreach_get("rotation_quaternion", q)
    bones.foreach_get("location", loc)
    return q.reshape(-1, 4), loc.reshape(-1, 3), [pb.rotation_mode for pb in bones]


def _action_pose(arm, frame) -> tuple[np.ndarray, np.ndarray]:
    """The baked action's values at `frame`, read from its F-Curves (the rest pose where unkeyed)."""
    bones = arm.pose.bones
    q = np.tile(np.array([1.0, 0.0, 0.0, 0.0]), (len(bones), 1))
    loc = np.zeros((len(bones), 3))
    index = {pb.name: i for i, pb in enumerate(bones)}
    from bodycal_addon.blender.fcurves import object_fcurves

    for (path, i), fc in object_fcurves(arm).items():
        name = path.split('"')[1]
        if path.endswith("rotation_quaternion"):
            q[index[name], i] = fc.evaluate(frame)
        elif path.endswith("location"):
            loc[index[name], i] = fc.evaluate(frame)
    return q, loc


def _same_rotations(a, b, atol):
    a, b = (v / np.linalg.norm(v, axis=1)[:, None] for v in (a, b))
    dots = np.abs(np.einsum("bi,bi->b", a, b))
    worst = np.degrees(2 * np.arccos(min(1.0, dots.min())))
    assert dots.min() > 1.0 - atol, f"rotations differ by up to {worst:.3f} deg"


def test_the_preview_shows_what_the_bake_keys_and_puts_the_pose_back(session):
    scene = bpy.context.scene
    arm = _ready(session)
    arm.pose.bones[0].rotation_mode = "XYZ"  # the user's own setting: back when the preview stops
    arm.pose.bones[0].rotation_euler = (0.1, 0.2, 0.3)  # its angles too (a mode change converts them)
    euler = tuple(arm.pose.bones[0].rotation_euler)
    before = _pose(arm)
    frames = [130, 101, 160, 175, 131]  # scrubbing: any order, back and forth
    scene.frame_start, scene.frame_end = 101, 180
    assert bpy.ops.bodycal.preview_retarget() == {"FINISHED"}
    assert preview.active(arm) is not None
    shown = {}
    for f in frames:
        scene.frame_set(f)
        shown[f] = _pose(arm)[:2]
    assert not np.allclose(shown[130][0], shown[175][0], atol=1e-3)  # it moves with the timeline
    assert arm.animation_data is None or arm.animation_data.action is None  # nothing keyed
    assert bpy.ops.bodycal.preview_retarget() == {"FINISHED"}  # the same button stops it
    assert preview.active(arm) is None
    after = _pose(arm)
    np.testing.assert_array_equal(after[0], before[0])
    np.testing.assert_array_equal(after[1], before[1])
    assert after[2] == before[2]
    assert tuple(arm.pose.bones[0].rotation_euler) == euler

    assert bpy.ops.bodycal.retarget_bake() == {"FINISHED"}
    for f in frames:
        q, loc = _action_pose(arm, f)
        _same_rotations(shown[f][0], q, 1e-6)
        np.testing.assert_allclose(shown[f][1], loc, atol=1e-5)


def test_changing_a_setting_while_previewing_shows_the_new_result(session):
    scene = bpy.context.scene
    arm = _ready(session)
    scene.frame_start, scene.frame_end = 101, 180
    scene.frame_set(150)
    assert bpy.ops.bodycal.preview_retarget() == {"FINISHED"}
    ego = _pose(arm)[0]
    scene.bodycal_retarget.method = "rotations"
    scene.frame_set(151)
    scene.frame_set(150)
    rot = _pose(arm)[0]
    assert not np.allclose(ego, rot, atol=1e-4)
    preview.stop_all()
    scene.frame_set(150)
    assert bpy.ops.bodycal.preview_retarget() == {"FINISHED"}  # a fresh preview with rotations
    np.testing.assert_allclose(_pose(arm)[0], rot, atol=1e-6)


def test_a_saved_file_never_holds_the_preview(session, tmp_path):
    scene = bpy.context.scene
    arm = _ready(session)
    rest = _pose(arm)
    scene.frame_start, scene.frame_end = 101, 180
    assert bpy.ops.bodycal.preview_retarget() == {"FINISHED"}
    scene.frame_set(140)
    shown = _pose(arm)
    path = tmp_path / "previewing.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path), copy=True)
    np.testing.assert_array_equal(_pose(arm)[0], shown[0])  # still previewing after the save
    with bpy.data.libraries.load(str(path), link=True) as (src, dst):
        dst.objects = [arm.name]
    saved = dst.objects[0]
    assert saved.library is not None
    np.testing.assert_array_equal(_pose(saved)[0], rest[0])
    np.testing.assert_array_equal(_pose(saved)[1], rest[1])


def test_a_preview_without_what_it_needs_says_so(session):
    arm, _mesh, _spec = rigs.build_procedural_avatar()
    bpy.context.scene.bodycal_bake.armature = arm
    with pytest.raises(RuntimeError, match="Import a recording first"):
        bpy.ops.bodycal.preview_retarget()
    with pytest.raises(RuntimeError, match="Pick the animated source armature"):
        bpy.ops.bodycal.preview_retarget(take="transfer")
    assert preview.active(arm) is None


def test_a_transfer_preview_shows_what_the_transfer_bakes(data_dir):
    """Transfer Animation > Preview: a CMU walk (a bare skeleton) followed by the avatar as the
    timeline moves; the transfer bake then keys the values shown."""
    from bodycal_addon.blender import blendfile
    from bodycal_addon.blender import character_source as ts

    ts.open_source(data_dir / "motion" / "cmu_bvh" / "02_01_walk.bvh")
    scene = bpy.context.scene
    source = blendfile.find_armature(None, "walk")
    target, _mesh, _spec = rigs.build_procedural_avatar()
    scene.bodycal_transfer.source = source
    bake = scene.bodycal_bake
    bake.armature, bake.tolerance, bake.location_tolerance, bake.frame_range = target, 0.0, 0.0, "take"
    assert bpy.ops.bodycal.preview_retarget(take="transfer") == {"FINISHED"}
    shown = {}
    for f in (200, 40, 120):
        scene.frame_set(f)
        shown[f] = _pose(target)[:2]
    preview.stop_all()
    assert bpy.ops.bodycal.transfer_animation() == {"FINISHED"}
    for f, (q_shown, loc_shown) in shown.items():
        q, loc = _action_pose(target, f)
        _same_rotations(q_shown, q, 1e-6)
        np.testing.assert_allclose(loc_shown, loc, atol=1e-5)
