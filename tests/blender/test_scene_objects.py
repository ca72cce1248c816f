"""Recording from Objects (FORMATS.md §2.5): animated scene objects read as the scene's
recording. The poses read back are the objects' world matrices at every frame (Blender's own
`matrix_world` after `frame_set` is the truth) whatever the rotation mode, parent or constraint;
the objects are never changed; what cannot be read is one line; and a take copied onto plain
empties from the sample recording calibrates and bakes like the file."""

from __future__ import annotations

import math

import bpy
import numpy as np
import pytest

from bodycal_addon.blender import calibration_scene, recording_scene
from bodycal_addon.blender.fcurves import new_fcurve, object_fcurves, read_keys, write_keys
from bodycal_addon.core import paths
from bodycal_addon.core import transforms as tf
from bodycal_addon.recording import io as rio

FRAMES = (3, 50)


def _empty(name, mode="XYZ", parent=None):
    obj = bpy.data.objects.new(name, None)
    bpy.context.scene.collection.objects.link(obj)
    obj.rotation_mode = mode
    if parent is not None:
        obj.parent = parent
        obj.matrix_parent_inverse = parent.matrix_world.inverted()
    return obj


def _keys(obj, frame, **values):
    for path, value in values.items():
        setattr(obj, path, value)
        obj.keyframe_insert(path, frame=frame)


def _dense(obj, path, values, frames):
    if obj.animation_data is None or obj.animation_data.action is None:
        obj.animation_data_create()
        obj.animation_data.action = bpy.data.actions.new(f"{obj.name}|dense")
    for k in range(values.shape[1]):
        write_keys(new_fcurve(obj.animation_data.action, obj, path, k), frames.astype(np.float32), values[:, k])


def _snapshot(obj):
    curves = {key: tuple(map(tuple, read_keys(fc))) for key, fc in object_fcurves(obj).items()}
    return (obj.name, obj.rotation_mode, obj.parent, tuple(obj.location), tuple(obj.scale), tuple(obj.rotation_euler),
            tuple(obj.rotation_quaternion), tuple(obj.delta_location), len(obj.constraints), curves,
            obj.animation_data.action.name if obj.animation_data and obj.animation_data.action else None)


@pytest.fixture
def moving_objects():
    """Empties with a known motion: sparse Bezier keys in Euler XYZ under a static scale and delta
    (Root), a child in ZXY with sparse keys (Arm), dense unnormalised quaternion keys (Quat),
    axis-angle keys (Spin), a Copy Location constraint (Follower), a marker, and a static empty."""
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = FRAMES
    scene.render.fps, scene.render.fps_base = 24, 1.001
    root = _empty("Root")
    root.scale = (1.3, 1.3, 1.3)
    root.delta_location = (0.1, 0.0, 0.05)
    for f, loc, rot in ((3, (0, 0, 1), (0, 0, 0)), (20, (0.5, 0.2, 1.1), (0.3, -0.2, 1.0)),
                        (37, (0.2, 0.8, 1.4), (-0.4, 0.5, 2.0)), (50, (-0.3, 0.1, 1.2), (0.1, 0.9, -1.0))):
        _keys(root, f, location=loc, rotation_euler=rot)
    arm = _empty("Arm", "ZXY", parent=root)
    arm.delta_rotation_euler = (0.2, 0.0, -0.3)
    _keys(arm, 5, location=(0.3, 0.0, 0.0), rotation_euler=(0.5, 0.1, 0.0))
    _keys(arm, 30, location=(0.35, 0.1, -0.2), rotation_euler=(-0.6, 0.9, 1.2))
    quat = _empty("LeftHand", "QUATERNION")
    frames = np.arange(FRAMES[0], FRAMES[1] + 1)
    t = (frames - frames[0]) / 10.0
    _dense(quat, "location", np.stack([np.sin(t), np.cos(t), 1 + 0.1 * t], 1), frames)
    axis = tf.normalize(np.stack([np.ones_like(t), t, 0.5 + 0 * t], 1))
    q = tf.axis_angle_to_quat(axis, 2.5 * t) * (1.0 + 0.3 * np.sin(3 * t))[:, None]  # Blender normalises
    q[6] = 0.0  # which Blender reads as a half turn about X (BLENDER_NOTES.md)
    _dense(quat, "rotation_quaternion", q, frames)
    spin = _empty("HMD", "AXIS_ANGLE")
    _keys(spin, 3, location=(0, 0, 1.7), rotation_axis_angle=(0.0, 0.0, 0.0, 1.0))
    _keys(spin, 50, location=(0.1, 0, 1.6), rotation_axis_angle=(2.0, 0.3, 0.0, 1.0))
    follower = _empty("LHR-77AB", "XYZ")
    follower.constraints.new("COPY_LOCATION").target = quat
    _keys(follower, 3, rotation_euler=(0.0, 0.0, 0.0))
    _keys(follower, 40, rotation_euler=(1.0, 0.5, 0.2))
    marker = _empty("Mocap.index_tip_r", parent=arm)
    marker.location = (0.0, 0.1, 0.0)
    static = _empty("Static")
    return {o.name: o for o in (root, arm, quat, spin, follower, marker, static)}


def _select(objects):
    for obj in bpy.context.scene.objects:
        obj.select_set(obj in objects)


def _truth(objects):
    """{name: (F, 4, 4)} of matrix_world after frame_set at every frame: Blender's own evaluation."""
    scene = bpy.context.scene
    out = {o.name: [] for o in objects}
    for f in range(FRAMES[0], FRAMES[1] + 1):
        scene.frame_set(f)
        for o in objects:
            out[o.name].append(np.array(o.matrix_world))
    return {k: np.array(v) for k, v in out.items()}


def test_poses_read_back_are_the_objects_world_matrices_at_every_frame(moving_objects):
    scene = bpy.context.scene
    scene.frame_set(7)
    before = {name: _snapshot(o) for name, o in moving_objects.items()}
    _select(list(moving_objects.values()))
    assert bpy.ops.bodycal.recording_from_objects(name="objects") == {"FINISHED"}
    assert scene.frame_current == 7  # put back after the depsgraph pass
    assert {name: _snapshot(o) for name, o in moving_objects.items()} == before  # the objects are not changed
    assert all(o.select_get() for o in moving_objects.values())

    rec = recording_scene.recording_from_scene(scene)
    assert [d.name for d in rec.devices] == ["Root", "Arm", "LeftHand", "HMD", "LHR-77AB"]
    assert [d.kind for d in rec.devices] == ["tracker", "tracker", "controller", "hmd", "tracker"]
    assert rec.marker_names == ["index_tip_r"]
    assert (scene.frame_start, scene.frame_end, scene.render.fps) == (*FRAMES, 24)
    assert scene.render.fps_base == pytest.approx(1.001)
    assert rec.frame_count == FRAMES[1] - FRAMES[0] + 1
    np.testing.assert_allclose(rec.time, np.arange(rec.frame_count) * 1.001 / 24, atol=1e-9)
    notes = " ".join(rec.notes)
    assert "LHR-77AB (constraints)" in notes and "Arm (" not in notes  # only the constraint needs frame_set
    assert "left out (not animated): Static" in notes

    truth = _truth(list(moving_objects.values()))
    for i, d in enumerate(rec.devices):
        m = truth[d.name]
        np.testing.assert_allclose(rec.positions[:, i], m[:, :3, 3], atol=1e-6, err_msg=d.name)
        rot = m[:, :3, :3] / np.linalg.norm(m[:, :3, :3], axis=1, keepdims=True)
        np.testing.assert_allclose(tf.quat_to_matrix(rec.rotations[:, i]), rot, atol=1e-6, err_msg=d.name)
    np.testing.assert_allclose(rec.markers[:, 0], truth["Mocap.index_tip_r"][:, :3, 3], atol=1e-6)
    # the take moves: the sparse keys are interpolated, not held
    assert np.ptp(rec.positions[:, 1], axis=0).max() > 0.3


def test_what_cannot_be_read_is_one_line_and_changes_nothing(moving_objects):
    scene = bpy.context.scene
    counts = lambda: (len(bpy.data.objects), len(bpy.data.collections), len(bpy.data.actions))  # noqa: E731
    before = counts()
    _select([moving_objects["Static"]])
    with pytest.raises(RuntimeError, match="none of the 1 selected objects is animated"):
        bpy.ops.bodycal.recording_from_objects()
    _select(list(moving_objects.values()))
    scene.unit_settings.scale_length = 0.01
    with pytest.raises(RuntimeError, match=r"Unit Scale is 0\.01: BodyCal reads object locations as metres"):
        bpy.ops.bodycal.recording_from_objects()
    scene.unit_settings.scale_length = 1.0
    moving_objects["Root"].scale = (1.0, -1.0, 1.0)
    with pytest.raises(RuntimeError) as err:
        bpy.ops.bodycal.recording_from_objects()
    assert "Root: is mirrored" in str(err.value) and "Traceback" not in str(err.value)
    assert counts() == before and recording_scene.scene_recording_collection(scene) is None


def test_operator_undoes_and_polls_with_a_reason():
    cls = bpy.types.Operator.bl_rna_get_subclass_py("BODYCAL_OT_recording_from_objects")
    assert {"REGISTER", "UNDO"} <= set(cls.bl_options)
    assert not bpy.ops.bodycal.recording_from_objects.poll()  # nothing selected


def _copy_onto_plain_empties(coll) -> dict[str, str]:
    """New empties with other names carrying the imported empties' keys (Euler for some, the
    markers under a parent that does not move): {new object name: device or marker name}."""
    scene = bpy.context.scene
    holder = _empty("Markers Holder")
    holder.location = (0.0, 0.0, 0.0)
    made = {}
    for k, src in enumerate(sorted(coll.objects, key=lambda o: o.name)):
        curves = object_fcurves(src)
        frames, _ = read_keys(curves[("location", 0)])
        loc = np.stack([read_keys(curves[("location", i)])[1] for i in range(3)], 1)
        if recording_scene.MARKER_PROP in src:
            name = f"Mocap.{src[recording_scene.MARKER_PROP]}"
            obj = _empty(name, parent=holder)
            _dense(obj, "location", loc, frames)
        else:
            obj = _empty(f"Device {k:02d}", "QUATERNION")
            _dense(obj, "location", loc, frames)
            quat = np.stack([read_keys(curves[("rotation_quaternion", i)])[1] for i in range(4)], 1)
            _dense(obj, "rotation_quaternion", quat, frames)
        made[obj.name] = src.get(recording_scene.DEVICE_PROP) or src[recording_scene.MARKER_PROP]
    scene.frame_set(scene.frame_start)
    return made


@pytest.mark.slow
def test_a_take_copied_onto_objects_calibrates_and_bakes_like_the_file():
    scene = bpy.context.scene
    path = paths.ROOT_DIR / "sample_rigs" / "recordings" / "demo_full.bcrec.json"
    file_rec = rio.load_recording(path)
    file_coll = recording_scene.import_recording_to_scene(file_rec, scene)
    assert bpy.ops.bodycal.calibrate_user(show_helpers=False) == {"FINISHED"}
    file_model = calibration_scene.load_user_model(scene)

    made = _copy_onto_plain_empties(file_coll)
    _select([bpy.data.objects[n] for n in made])
    assert bpy.ops.bodycal.recording_from_objects(name="copied") == {"FINISHED"}
    coll = recording_scene.scene_recording_collection(scene)
    assert coll != file_coll and coll.name == "copied"
    truth = {d.name: d.role for d in file_rec.devices}
    empties = {o["bodycal_device"]: o for o in coll.objects if "bodycal_device" in o}
    # The T-pose marked on the timeline identified every role from where the devices are.
    assert {made[n]: o["bodycal_role"] for n, o in empties.items()} == truth
    assert {o["bodycal_role_from"] for o in empties.values()} == {"tpose"}

    for obj in empties.values():  # assigned in the Devices list, as a user would
        obj.bodycal_device_role = "none"
    for name, obj in empties.items():
        obj.bodycal_device_role = truth[made[name]]
    assert {o["bodycal_role_from"] for o in empties.values()} == {"user"}
    assert bpy.ops.bodycal.calibrate_user(show_helpers=False) == {"FINISHED"}
    model = calibration_scene.load_user_model(scene)
    # The file's times are rounded to 1e-9 s and its steps do not all start on a sample, so a step
    # may take or leave the sample at its edge: 0.80 mm at most here (the poses are the same).
    worst = max(np.linalg.norm(model.world(j) - file_model.world(j)) for j in file_model.joints)
    assert worst <= 1e-3, f"{1000 * worst:.3f} mm"
    assert set(model.joints) == set(file_model.joints)

    arm, _mesh, _spec = paths.sample_rigs().build_procedural_avatar()
    bake = scene.bodycal_bake
    bake.armature, bake.tolerance, bake.location_tolerance = arm, 0.0, 0.0
    bake.frame_range, bake.frame_first, bake.frame_last = "custom", 1300, 1420
    keys = {}
    calibration_scene.store_user_model(scene, file_model)  # the same performer: only the take differs
    for which, take in (("objects", coll), ("file", file_coll)):
        scene[recording_scene.SCENE_KEY] = take
        assert bpy.ops.bodycal.retarget_bake() == {"FINISHED"}
        curves = object_fcurves(arm)
        keys[which] = {key: read_keys(fc) for key, fc in curves.items()}
    assert keys["objects"].keys() == keys["file"].keys()
    for key, (frames, values) in keys["objects"].items():
        np.testing.assert_array_equal(frames, keys["file"][key][0])
        tol = 1e-4 if "location" in key[0] else math.radians(0.01)
        np.testing.assert_allclose(values, keys["file"][key][1], atol=tol, err_msg=str(key))
