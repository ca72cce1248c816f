"""The last step as users run it: the sidebar's Retarget and Bake operator, and the `retarget`
command on files, end to end."""

import subprocess
import sys

import bpy
import numpy as np
import pytest
import ui_layout
from repo_paths import REPO

from bodycal_addon.blender import avatar_storage, calibration_scene, mesh_metrics, recording_scene
from bodycal_addon.body.bodymodel import BodyModel
from bodycal_addon.core import paths
from bodycal_addon.recording.filters import DEFAULT_FILTER, filter_recording
from bodycal_addon.retarget.pipeline import retarget
from bodycal_dev import synthetic

rigs = paths.sample_rigs()


@pytest.fixture(scope="module")
def belly_session():
    performer = synthetic.make_performer(seed=3)
    rec, truth = synthetic.record_session(performer, profile="full", motions=("hand_on_belly",),
                                          calibration=["tpose"], seed=3)
    rec.name = "belly"
    return rec, truth


def _scene_ready(rec, truth):
    arm, _mesh, _spec = rigs.build_procedural_avatar()
    recording_scene.import_recording_to_scene(rec, bpy.context.scene)
    calibration_scene.store_user_model(bpy.context.scene, truth.body_model())
    bpy.context.scene.bodycal_bake.armature = arm
    return arm


def test_poll_says_what_is_missing_first():
    arm, _mesh, _spec = rigs.build_procedural_avatar()
    bpy.context.view_layer.objects.active = arm
    assert not bpy.ops.bodycal.retarget_bake.poll()
    from bodycal_addon.blender.session import scene_take_missing

    assert "Import a recording" in scene_take_missing(bpy.context.scene)


def test_operator_bakes_a_new_action_and_reports_figures(belly_session):
    rec, truth = belly_session
    arm = _scene_ready(rec, truth)
    user_action = bpy.data.actions.new("belly|procedural|egocentric")  # the user's own work, same name
    assert bpy.ops.bodycal.retarget_bake() == {"FINISHED"}
    action = arm.animation_data.action
    assert action is not None and action != user_action
    assert action.name.startswith("belly|procedural|egocentric")
    assert bpy.data.actions.get("belly|procedural|egocentric") == user_action  # kept
    assert avatar_storage.has_model(arm)  # calibrated on the fly, stored with the bake
    settings = bpy.context.scene.bodycal_retarget
    assert f"{rec.frame_count} frames" in settings.last_result and "reach p95" in settings.last_result


def test_operator_bakes_every_selected_armature(belly_session):
    rec, truth = belly_session
    first = _scene_ready(rec, truth)
    bpy.context.scene.bodycal_bake.armature = None
    second, _mesh, _spec = rigs.build_procedural_avatar(scale=0.7)
    for arm in (first, second):
        arm.select_set(True)
    bpy.context.view_layer.objects.active = second
    bpy.context.scene.bodycal_retarget.method = "rotations"
    assert bpy.ops.bodycal.retarget_bake() == {"FINISHED"}
    assert first.animation_data.action.name == "belly|procedural|rotations"
    assert second.animation_data.action.name == f"belly|{second.name}|rotations"
    assert bpy.context.scene.bodycal_retarget.last_result.count("Baked") == 2


def _key_frames(obj) -> list[np.ndarray]:
    from bodycal_addon.blender.fcurves import object_fcurves, read_keys

    return [read_keys(fc)[0] for fc in object_fcurves(obj).values()]


def test_the_bake_lands_on_the_trackers_frames_and_the_range_limits_it(belly_session):
    """Imported at frame 101, the scene's range then moved to a shot: the avatar is keyed on the
    tracker empties' own frames (every key of every curve on one of them, the first on theirs),
    the scene range (or the preview range, or a typed one) limits the bake to its frames, and the
    scene's range changes only when asked."""
    rec, truth = belly_session
    scene = bpy.context.scene
    arm, _mesh, _spec = rigs.build_procedural_avatar()
    recording_scene.import_recording_to_scene(rec, scene, frame_start=101)
    calibration_scene.store_user_model(scene, truth.body_model())
    bake = scene.bodycal_bake
    bake.armature, bake.tolerance, bake.location_tolerance = arm, 0.0, 0.0
    tracker = next(o for o in bpy.data.objects if recording_scene.DEVICE_PROP in o)
    (tracked,) = {tuple(f) for f in _key_frames(tracker)}
    tracked = np.array(tracked)
    assert tracked[0] == 101 and len(tracked) == rec.frame_count
    shot = (int(tracked[0]) + 40, int(tracked[0]) + 90)
    scene.frame_start, scene.frame_end = shot

    def baked(frame_range, first=None, last=None):
        bake.frame_range = frame_range
        if first is not None:
            bake.frame_first, bake.frame_last = first, last
        assert bpy.ops.bodycal.retarget_bake() == {"FINISHED"}
        curves = _key_frames(arm)
        assert all(np.isin(c, tracked).all() for c in curves)  # every key on a tracker key's frame
        return np.unique(np.concatenate(curves)), min(c[0] for c in curves)

    keys, first_key = baked("take")
    np.testing.assert_array_equal(keys, tracked)  # the whole take, where the trackers are
    assert first_key == tracked[0]
    assert (scene.frame_start, scene.frame_end) == shot  # not asked to change

    in_shot = tracked[(tracked >= shot[0]) & (tracked <= shot[1])]
    keys, first_key = baked("scene")
    np.testing.assert_array_equal(keys, in_shot)
    assert first_key == shot[0] and keys[-1] == shot[1]

    scene.use_preview_range = True
    scene.frame_preview_start, scene.frame_preview_end = shot[0] + 5, shot[0] + 20
    keys, _first = baked("scene")
    np.testing.assert_array_equal(keys, np.arange(shot[0] + 5, shot[0] + 21))

    bake.set_scene_range = True
    keys, _first = baked("custom", 120, 130)
    np.testing.assert_array_equal(keys, np.arange(120, 131))
    assert (scene.frame_start, scene.frame_end) == (120, 130)
    assert "11 frames (120-130)" in scene.bodycal_retarget.last_result

    bake.frame_first, bake.frame_last = 5000, 5100  # past the take: one line, no new action
    n_actions = len(bpy.data.actions)
    with pytest.raises(RuntimeError, match="holds none of the take's frames"):
        bpy.ops.bodycal.retarget_bake()
    assert len(bpy.data.actions) == n_actions


def test_operator_error_is_one_line_and_changes_nothing(belly_session):
    rec, truth = belly_session
    arm = _scene_ready(rec, truth)
    broken = truth.body_model()
    del broken.joints["wrist_r"]
    calibration_scene.store_user_model(bpy.context.scene, broken)
    n_actions = len(bpy.data.actions)
    with pytest.raises(RuntimeError) as err:  # an ERROR report makes bpy.ops raise
        bpy.ops.bodycal.retarget_bake()
    assert "wrist_r" in str(err.value)
    assert len(bpy.data.actions) == n_actions and arm.animation_data is None


@pytest.mark.slow
def test_retarget_command_end_to_end_keeps_the_hand_on_the_belly(tmp_path, belly_session, avatar_files):
    rec, truth = belly_session
    rec_path, _truth_path = synthetic.write_session(tmp_path, "belly", rec, truth)
    user_path = truth.body_model().save(tmp_path / "performer.body.json")
    avatar_path = next(p for p in avatar_files if p.stem == "heavy_belly_male")
    arm, _mesh = rigs.load_glb_avatar(avatar_path)
    avatar_blend = tmp_path / "heavy_belly_male.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(avatar_blend))
    out_blend = tmp_path / "out.blend"
    out = subprocess.run([sys.executable, "-m", "bodycal_addon", "retarget", str(rec_path), "--user", str(user_path),
                          "--avatar", str(avatar_blend), "-o", str(out_blend)], cwd=REPO, capture_output=True,
                         text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "Baked 'belly|heavy_belly_male|egocentric'" in out.stdout

    bpy.ops.wm.open_mainfile(filepath=str(out_blend))
    arm = bpy.data.objects["heavy_belly_male"]
    assert arm.animation_data.action.name == "belly|heavy_belly_male|egocentric"
    avatar = avatar_storage.load_model(arm)
    # Reading the keys back through Blender: the evaluated pose in the belly-contact frames puts the
    # avatar's palm on its evaluated belly.
    anim = retarget(filter_recording(rec, DEFAULT_FILTER), BodyModel.load(user_path), avatar, "egocentric")  # smoothed
    (contact,) = [c for c in truth.contacts if c["target"].startswith("mesh:torso")]
    gaps = mesh_metrics.contact_gaps(arm, avatar, anim, [contact], max_frames=6)[0]
    assert np.all(np.abs(gaps) < 0.010), gaps  # within the quality target (bench_retarget_quality: p95 <= 10 mm)
    frame = int(bpy.context.scene.frame_start + np.flatnonzero(contact["frames"])[0])
    bpy.context.scene.frame_set(frame)
    baked = np.array(arm.pose.bones["hand_r"].rotation_quaternion)
    want = anim.rotations[frame - bpy.context.scene.frame_start, anim.bone_names.index("hand_r")]
    assert abs(abs(float(baked @ want)) - 1) < 1e-5  # the .blend's keys are the engine's pose


def test_operator_smooths_the_devices_when_asked_and_leaves_the_recording_alone(belly_session):
    """The One Euro filter (DESIGN.md §6b) is a panel option, on by default; it works on a copy (the
    scene's recording keeps its samples) and changes the bake; feet can be left to the method."""
    from bodycal_addon.blender.fcurves import object_fcurves, read_keys

    rec, truth = belly_session
    arm = _scene_ready(rec, truth)
    settings, bake = bpy.context.scene.bodycal_retarget, bpy.context.scene.bodycal_bake
    settings.method = "rotations"
    bake.tolerance = 0.0  # every frame keyed, so the two bakes compare key for key
    samples = recording_scene.recording_from_scene(bpy.context.scene).positions.copy()
    assert settings.use_filter  # the default
    keys = {}
    for smooth in (False, True):
        settings.use_filter = smooth
        bake.plant_feet = not smooth
        assert bpy.ops.bodycal.retarget_bake() == {"FINISHED"}
        fcurves = object_fcurves(arm)
        keys[smooth] = np.stack([read_keys(fc)[1] for (path, _i), fc in sorted(fcurves.items())
                                 if "upperarm" in path and "rotation_quaternion" in path])
    np.testing.assert_array_equal(recording_scene.recording_from_scene(bpy.context.scene).positions, samples)
    assert keys[True].shape == keys[False].shape
    change = np.abs(keys[True] - keys[False]).max()
    assert 1e-4 < change < 0.2, change  # smoothed, not another motion


@pytest.mark.parametrize("panel, group", [("BODYCAL_PT_retarget", "bodycal_retarget"),
                                          ("BODYCAL_PT_transfer", "bodycal_transfer")])
def test_both_bake_panels_draw_the_shared_bake_settings(panel, group):
    """Retarget and Transfer share one group of bake settings (`scene.bodycal_bake`,
    operators/bake_settings.py) and draw it with the same rows: every property drawn is its
    group's, each shared setting is there, each panel's own settings are its own group's, and the
    last result is shown part by part."""
    settings, bake = getattr(bpy.context.scene, group), bpy.context.scene.bodycal_bake
    if group == "bodycal_retarget":
        settings.use_filter = True  # its rows drawn too
    settings.last_result = "first avatar: 10 keys; second avatar: 12 keys"
    log = ui_layout.draw(getattr(bpy.types, panel), bpy.context)
    props = [(e[1], e[2]) for e in log if e[0] == "prop"]
    for data, name in props:
        assert name in data.bl_rna.properties, (panel, name)
    shared = {"armature", "placement", "plant_feet", "root_motion", "rigify_target", "replace", "push_to_nla",
              "output_fps", "tolerance", "location_tolerance", "frame_range", "set_scene_range"}
    assert {name for data, name in props if data == bake} == shared
    own = {name for data, name in props if data == settings}
    assert "method" in own and not own & shared
    assert [e[1] for e in log if e[0] == "label"] == ["first avatar: 10 keys", "second avatar: 12 keys"]
    assert bake.bake_options(bpy.context).tolerance_deg == pytest.approx(0.1)
    settings.last_result = ""
