"""The Recording panel's Devices list (FORMATS.md §2.5): a device's role is a drop-down that
writes its empty's `bodycal_role` (and says the user set it), which calibration then uses and the
.blend keeps; Identify Roles rewrites the roles from the T-pose, keeping the user's; the panel shows
the recording and where each role came from; errors about roles point at the list."""

from __future__ import annotations

import types

import bpy
import numpy as np
import pytest
import ui_layout
from recording_fixtures import tpose_recording

from bodycal_addon.blender import calibration_scene, device_roles, recording_scene
from bodycal_addon.core import paths
from bodycal_addon.recording import io as rio

DEMO = paths.ROOT_DIR / "sample_rigs" / "recordings" / "demo_full.bcrec.json"


def _empties(scene=None) -> dict:
    coll = recording_scene.scene_recording_collection(scene or bpy.context.scene)
    return {o["bodycal_device"]: o for o in device_roles.device_empties(coll)}


def _by_role() -> dict:
    return {o["bodycal_role"]: o for o in _empties().values() if o["bodycal_role"]}


def test_a_role_changed_in_the_list_is_the_one_calibration_uses_and_the_file_keeps(tmp_path):
    scene = bpy.context.scene
    recording_scene.import_recording_to_scene(rio.load_recording(DEMO), scene)
    assert {device_roles.origin_of(o) for o in _empties().values()} == {"file"}
    assert bpy.ops.bodycal.calibrate_user(show_helpers=False) == {"FINISHED"}
    before = calibration_scene.load_user_model(scene).extra["tpose"]
    left, right = _by_role()["foot_l"], _by_role()["foot_r"]

    left.bodycal_device_role = "foot_r"  # what the drop-down does
    assert (left["bodycal_role"], left["bodycal_role_from"], left.bodycal_device_role) == ("foot_r", "user", "foot_r")
    coll = recording_scene.scene_recording_collection(scene)
    assert set(device_roles.role_problems(coll)) == {left.name, right.name}  # flagged in the list at once
    with pytest.raises(RuntimeError, match="both have the role 'foot_r'"):
        bpy.ops.bodycal.calibrate_user(show_helpers=False)
    right.bodycal_device_role = "foot_l"
    assert device_roles.role_problems(coll) == {}
    assert bpy.ops.bodycal.calibrate_user(show_helpers=False) == {"FINISHED"}
    after = calibration_scene.load_user_model(scene).extra["tpose"]
    # the device now called foot_l is the one that was foot_r, at the same reference time
    np.testing.assert_allclose(after["foot_l"], before["foot_r"], atol=1e-9)
    np.testing.assert_allclose(after["foot_r"], before["foot_l"], atol=1e-9)
    np.testing.assert_allclose(after["head"], before["head"], atol=1e-9)

    path = tmp_path / "roles.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.open_mainfile(filepath=str(path))
    roles = {d.name: d.role for d in recording_scene.recording_from_scene(bpy.context.scene).devices}
    assert (roles["tracker_foot_l"], roles["tracker_foot_r"]) == ("foot_r", "foot_l")
    obj = _empties()["tracker_foot_l"]
    obj.bodycal_device_role = "none"
    assert (obj["bodycal_role"], obj["bodycal_role_from"], device_roles.origin_of(obj)) == ("", "", "")


def _shuffled():
    rec = tpose_recording(roles=False, shuffle=True, seed=5, yaw=0.7)
    truth = {d.name: d.role for d in tpose_recording(roles=True, shuffle=True, seed=5, yaw=0.7).devices}
    return rio.finish_recording(rec, fill_gaps_s=0.0), truth


def test_identify_roles_keeps_the_users_roles_unless_asked():
    rec, truth = _shuffled()
    recording_scene.import_recording_to_scene(rec, bpy.context.scene)
    empties = _empties()
    assert {n: o["bodycal_role"] for n, o in empties.items()} == truth  # identified at import
    assert {o["bodycal_role_from"] for o in empties.values()} == {"tpose"}
    name_of = {r: n for n, r in truth.items()}
    for obj in empties.values():
        obj.bodycal_device_role = "none"
    empties[name_of["hand_l"]].bodycal_device_role = "hand_l"
    empties[name_of["thigh_l"]].bodycal_device_role = "thigh_r"  # a mistake the user made on purpose

    assert bpy.ops.bodycal.identify_roles() == {"FINISHED"}
    got = {n: o["bodycal_role"] for n, o in empties.items()}
    assert got[name_of["hand_l"]] == "hand_l" and got[name_of["thigh_l"]] == "thigh_r"  # kept
    assert empties[name_of["thigh_l"]]["bodycal_role_from"] == "user"
    assert got[name_of["thigh_r"]] == ""  # its role is taken: not given twice
    for role in ("head", "hand_r", "pelvis", "chest", "foot_l", "foot_r", "upperarm_l", "forearm_r", "shin_r"):
        assert got[name_of[role]] == role and empties[name_of[role]]["bodycal_role_from"] == "tpose"

    assert bpy.ops.bodycal.identify_roles(everything=True) == {"FINISHED"}
    assert {n: o["bodycal_role"] for n, o in empties.items()} == truth
    assert {o["bodycal_role_from"] for o in empties.values()} == {"tpose"}
    cls = bpy.types.Operator.bl_rna_get_subclass_py("BODYCAL_OT_identify_roles")
    assert {"REGISTER", "UNDO"} <= set(cls.bl_options)
    bpy.context.scene.timeline_markers.clear()
    assert not bpy.ops.bodycal.identify_roles.poll()  # no T-pose marked


def test_a_missing_role_error_points_at_the_devices_list():
    rec, _truth = _shuffled()
    rec.segments = []  # no T-pose to identify from
    for d in rec.devices:
        d.role = None
    recording_scene.import_recording_to_scene(rec, bpy.context.scene)
    with pytest.raises(RuntimeError) as err:
        bpy.ops.bodycal.calibrate_user(show_helpers=False)
    assert "no HMD (role 'head')" in str(err.value)
    assert "Sidebar > BodyCal > Recording > Devices" in str(err.value)


def test_the_panel_shows_the_recording_and_its_devices():
    scene = bpy.context.scene
    log = ui_layout.draw(bpy.types.BODYCAL_PT_recording, bpy.context)
    assert ("operator", "bodycal.import_recording") in log and ("label", "No recording in this scene") in log
    assert not bpy.types.BODYCAL_PT_recording_devices.poll(bpy.context)
    rec, _truth = _shuffled()
    recording_scene.import_recording_to_scene(rec, scene, frame_start=11)
    labels = [e[1] for e in ui_layout.draw(bpy.types.BODYCAL_PT_recording, bpy.context) if e[0] == "label"]
    assert "15 devices (15 with a role), 0 markers" in labels
    assert f"{rec.frame_count} frames at 90 fps, from frame 11" in labels
    assert "2 calibration steps on the timeline" in labels
    assert bpy.types.BODYCAL_PT_recording_devices.poll(bpy.context)
    log = ui_layout.draw(bpy.types.BODYCAL_PT_recording_devices, bpy.context)
    assert ("operator", "bodycal.identify_roles") in log

    coll = recording_scene.scene_recording_collection(scene)
    obj = next(iter(_empties().values()))
    ul = bpy.types.BODYCAL_UL_devices
    row: list = []
    ul.draw_item(None, bpy.context, ui_layout.RecordingLayout(row), coll, obj, 0, None, "", 0)
    assert ("prop", obj, "bodycal_device_role") in row
    assert ("label", "T-pose") in row and ("label", obj["bodycal_device"]) in row
    marker = bpy.data.objects.new("m", None)
    coll.objects.link(marker)
    marker["bodycal_marker"] = "index_tip_r"
    for show, shown in ((True, 16), (False, 15)):
        fake = types.SimpleNamespace(filter_name="", bitflag_filter_item=1 << 30, show_markers=show)
        flags, _order = ul.filter_items(fake, bpy.context, coll, "objects")
        assert sum(1 for f in flags if f) == shown
