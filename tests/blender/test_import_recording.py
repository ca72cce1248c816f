"""Recording -> Blender scene: animated empties written with foreach_set, timeline markers for the
steps, fps and frame range, the recording stored on the scene and rebuilt after save/reload; the
File > Import operator and its errors."""

from __future__ import annotations

import json

import bpy
import numpy as np
import pytest
from recording_fixtures import recording_doc, tpose_recording

from bodycal_addon.blender import recording_scene as rs
from bodycal_addon.blender.fcurves import object_fcurves, read_keys
from bodycal_addon.core import paths
from bodycal_addon.core.errors import BodyCalError
from bodycal_addon.recording import io as rio
from bodycal_addon.recording.model import Segment


def _recording():
    rec = tpose_recording(leds=True, seconds=3.0)
    rec.valid[40:80, 2] = False  # a long dropout stays untracked
    rec.marker_valid[100:130, 1] = False
    # Steps without overlaps (start markers end at the next marker), with a gap before `motion`.
    rec.segments = [Segment("tpose", 0.2, 1.0), Segment("touch", 1.1, 1.3, point="wrist_top_l", by="index_tip_r"),
                    Segment("motion", 1.5, 2.9)]
    return rio.finish_recording(rec, fill_gaps_s=0.0)


def _keys(obj, path, index):
    fc = object_fcurves(obj)[(path, index)]
    return read_keys(fc)


def test_import_builds_animated_empties_markers_and_range():
    rec = _recording()
    scene = bpy.context.scene
    coll = rs.import_recording_to_scene(rec, scene, step_markers="bounds")
    assert coll.name == rec.name
    assert len(coll.objects) == len(rec.devices) + len(rec.marker_names)
    assert scene.render.fps == 90 and scene.render.fps_base == pytest.approx(1.0)
    assert (scene.frame_start, scene.frame_end) == (1, rec.frame_count)
    head = next(o for o in coll.objects if o.get("bodycal_device") == rec.devices[0].name)
    assert head.rotation_mode == "QUATERNION"
    frames, x = _keys(head, "location", 0)
    assert len(frames) == rec.frame_count
    np.testing.assert_allclose(frames, 1 + np.arange(rec.frame_count), atol=1e-3)
    np.testing.assert_allclose(x, rec.positions[:, 0, 0], atol=1e-6)
    _, w = _keys(head, "rotation_quaternion", 0)
    np.testing.assert_allclose(np.abs(w), np.abs(rec.rotations[:, 0, 0]), atol=1e-6)
    dropped = next(o for o in coll.objects if o.get("bodycal_device") == rec.devices[2].name)
    _, tracked = _keys(dropped, '["bodycal_tracked"]', 0)
    assert tracked[:40].all() and not tracked[40:80].any() and tracked[80:].all()
    # Evaluating the scene at a frame gives the recorded pose.
    scene.frame_set(200)
    np.testing.assert_allclose(np.array(head.location), rec.positions[199, 0], atol=1e-5)
    names = [(m.name, m.frame) for m in sorted(scene.timeline_markers, key=lambda m: m.frame)]
    assert names[0] == ("bodycal:tpose", 19)
    assert ("bodycal:touch:wrist_top_l:index_tip_r", 100) in names
    assert ("bodycal:end", 118) in names
    assert ("bodycal:motion", 136) in names
    assert rs.scene_recording_collection(scene) == coll


def test_a_role_set_on_a_device_empty_is_the_role_read_back():
    """The `bodycal_role` a device's empty shows is the role: the user swaps two, clears one (to be
    identified from the T-pose again), and the rebuilt recording says so; a role that is not one, or
    given to two devices, is one line naming the empty or the collection."""
    rec = _recording()
    bpy.ops.wm.read_homefile(use_empty=True)
    coll = rs.import_recording_to_scene(rec, bpy.context.scene)
    empty = {o["bodycal_device"]: o for o in coll.objects if "bodycal_device" in o}
    (a, ra), (b, rb), (c, _rc) = [(d.name, d.role) for d in rec.devices[:3]]
    empty[a]["bodycal_role"], empty[b]["bodycal_role"], empty[c]["bodycal_role"] = rb, ra, ""
    roles = {d.name: d.role for d in rs.recording_from_scene(bpy.context.scene).devices}
    assert (roles[a], roles[b], roles[c]) == (rb, ra, None)
    assert all(roles[d.name] == d.role for d in rec.devices[3:])
    empty[c]["bodycal_role"] = "left_hand"
    with pytest.raises(BodyCalError, match="'left_hand' is not a device role") as err:
        rs.recording_from_scene(bpy.context.scene)
    assert err.value.line().count("\n") == 0 and empty[c].name in err.value.line()
    empty[c]["bodycal_role"] = ra
    with pytest.raises(BodyCalError, match=f"both have the role '{ra}'"):
        rs.recording_from_scene(bpy.context.scene)


def test_rebuild_after_save_and_reload_is_exact_to_float32(tmp_path):
    rec = _recording()
    rs.import_recording_to_scene(rec, bpy.context)
    path = tmp_path / "rec.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.read_homefile(use_empty=True)
    with pytest.raises(BodyCalError, match="no recording"):
        rs.recording_from_scene(bpy.context.scene)
    bpy.ops.wm.open_mainfile(filepath=str(path))
    back = rs.recording_from_scene(bpy.context.scene)
    assert [d.name for d in back.devices] == [d.name for d in rec.devices]
    assert [d.role for d in back.devices] == [d.role for d in rec.devices]
    assert [d.kind for d in back.devices] == [d.kind for d in rec.devices]
    assert back.marker_names == rec.marker_names
    np.testing.assert_array_equal(back.time, rec.time)
    f32 = np.finfo(np.float32).eps
    np.testing.assert_allclose(back.positions, rec.positions, atol=4 * f32 * 2.0)
    same_sign = np.sign((back.rotations * rec.rotations).sum(-1, keepdims=True))
    np.testing.assert_allclose(back.rotations * same_sign, rec.rotations, atol=4 * f32)
    np.testing.assert_array_equal(back.valid, rec.valid)
    np.testing.assert_allclose(back.markers, rec.markers, atol=4 * f32 * 2.0)
    np.testing.assert_array_equal(back.marker_valid, rec.marker_valid)
    assert [(s.label, s.start, s.end) for s in back.segments] == \
        [(s.label, s.start, s.end) for s in sorted(rec.segments, key=lambda s: s.start)]


def test_edited_timeline_markers_are_the_steps():
    rec = _recording()
    scene = bpy.context.scene
    rs.import_recording_to_scene(rec, scene, step_markers="bounds")
    tpose = next(m for m in scene.timeline_markers if m.name == "bodycal:tpose")
    tpose.frame = 10
    scene.timeline_markers.new("bodycal:stand", frame=50)
    scene.timeline_markers.new("not ours", frame=60)  # other markers are ignored
    back = rs.recording_from_scene(scene)
    tp = back.segments_of("tpose")[0]
    assert tp.start == pytest.approx(9 / 90) and tp.end == pytest.approx(49 / 90)
    st = back.segments_of("stand")[0]
    assert st.start == pytest.approx(49 / 90) and st.end == pytest.approx(90 / 90)  # to the old tpose's end
    scene.timeline_markers.new("bodycal:dance", frame=70)
    with pytest.raises(BodyCalError, match="names no step"):
        rs.recording_from_scene(scene)


def test_operator_imports_file_and_menu_entry_exists(tmp_path):
    rec = tpose_recording(seconds=2.0)
    path = tmp_path / "session.bcrec.json"
    path.write_text(json.dumps(recording_doc(rec)))
    assert bpy.ops.bodycal.import_recording(filepath=str(path), fill_gaps=0.05) == {"FINISHED"}
    coll = rs.scene_recording_collection(bpy.context.scene)
    assert coll is not None and len(coll.objects) == len(rec.devices)
    menu = bpy.types.TOPBAR_MT_file_import._dyn_ui_initialize()
    assert any(getattr(f, "__name__", "") == "menu_import" for f in menu)


def test_operator_error_is_one_line_and_writes_nothing(tmp_path):
    doc = recording_doc(tpose_recording(seconds=1.0))
    doc["poses"]["head"][5][3:] = [0.0, 0.0, 0.0, 0.0]
    path = tmp_path / "bad.bcrec.json"
    path.write_text(json.dumps(doc))
    before = (len(bpy.data.objects), len(bpy.data.collections), len(bpy.data.actions))
    with pytest.raises(RuntimeError) as info:
        bpy.ops.bodycal.import_recording(filepath=str(path))
    msg = str(info.value)
    assert "bad.bcrec.json" in msg and "poses.head" in msg and "frame 5" in msg and "zero" in msg
    assert "Traceback" not in msg
    assert (len(bpy.data.objects), len(bpy.data.collections), len(bpy.data.actions)) == before
    assert rs.scene_recording_collection(bpy.context.scene) is None


def test_synthetic_session_survives_the_scene(tmp_path):
    from bodycal_dev import synthetic
    perf = synthetic.make_performer(build="thin", seed=4)
    rec, _truth = synthetic.record_session(perf, profile="minimal", motions=("hand_on_head",), seed=4,
                                           dropout_rate=0.01, calibration=["tpose", "stand", "touch"],
                                           touch_points=["chin", "wrist_top_l"])
    assert any(s.step == "touch" for s in rec.segments)
    rs.import_recording_to_scene(rec, bpy.context)
    path = tmp_path / "synthetic.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.open_mainfile(filepath=str(path))
    back = rs.recording_from_scene(bpy.context.scene)
    assert [(s.label, s.start, s.end) for s in back.segments] == \
        [(s.label, s.start, s.end) for s in sorted(rec.segments, key=lambda s: s.start)]
    np.testing.assert_array_equal(back.valid, rec.valid)
    np.testing.assert_allclose(back.positions, rec.positions, atol=1e-5)
    np.testing.assert_allclose(back.markers, rec.markers, atol=1e-5)


def _tracker_frames(coll) -> np.ndarray:
    obj = next(o for o in coll.objects if rs.DEVICE_PROP in o)
    return _keys(obj, "location", 0)[0]


def test_import_options_start_frame_and_the_scene_left_as_it_was(tmp_path):
    """Import options (FORMATS.md §2.5): the first sample on the start frame; with the scene's rate
    and range kept, the samples are timed to the scene's rate (the take plays in real time) and the
    scene's rate and range are what they were; with them set, the scene is the recording's."""
    rec = tpose_recording(seconds=2.0)
    rec.segments = [Segment("tpose", 0.2, 1.0), Segment("motion", 1.2, 1.9)]
    path = tmp_path / "take.bcrec.json"
    path.write_text(json.dumps(recording_doc(rec)))
    scene = bpy.context.scene
    scene.render.fps, scene.render.fps_base, scene.frame_start, scene.frame_end = 24, 1.0, 5, 60
    assert bpy.ops.bodycal.import_recording(filepath=str(path), frame_start=1000, update_scene_rate=False,
                                            update_scene_range=False) == {"FINISHED"}
    assert (scene.render.fps, scene.render.fps_base, scene.frame_start, scene.frame_end) == (24, 1.0, 5, 60)
    coll = rs.scene_recording_collection(scene)
    frames = _tracker_frames(coll)
    np.testing.assert_allclose(frames, 1000 + (rec.time - rec.time[0]) * 24, atol=1e-3)
    assert {(m.name, m.frame) for m in scene.timeline_markers} == {("bodycal:tpose", 1000 + round(0.2 * 24)),
                                                                    ("bodycal:motion", 1000 + round(1.2 * 24))}
    assert rs.frame_mapping_in_scene(scene) == (1000.0, 24.0)
    back = rs.recording_from_scene(scene)  # the steps read back from frames at the scene's rate
    assert [(s.label, s.start, s.end) for s in back.segments] == [("tpose", 0.2, 1.0), ("motion", 1.2, 1.9)]

    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    scene.render.fps = 24
    assert bpy.ops.bodycal.import_recording(filepath=str(path), frame_start=1000) == {"FINISHED"}
    frames = _tracker_frames(rs.scene_recording_collection(scene))
    np.testing.assert_allclose(frames, 1000 + np.arange(rec.frame_count), atol=1e-3)
    assert (scene.render.fps, scene.frame_start, scene.frame_end) == (90, 1000, 1000 + rec.frame_count - 1)


@pytest.fixture(scope="module")
def sample_take():
    return rio.load_recording(paths.ROOT_DIR / "sample_rigs" / "recordings" / "demo_full.bcrec.json")


@pytest.mark.parametrize("layout, markers, ends", [("starts", 91, 0), ("bounds", 182, 91), ("none", 0, 0)])
def test_step_markers_do_not_flood_the_timeline(sample_take, layout, markers, ends):
    """The sample take's 91 steps, each followed by a pause: one marker per step by default (it was
    a start and an end marker each, 182), both on request, or none; whichever the layout, the steps
    read back are the recording's own, to the sample, and the wizard counts them all."""
    rec = sample_take
    assert len(rec.segments) == 91
    scene = bpy.context.scene
    rs.import_recording_to_scene(rec, scene, step_markers=layout)
    names = [m.name for m in scene.timeline_markers]
    assert (len(names), names.count("bodycal:end")) == (markers, ends)
    back = rs.recording_from_scene(scene)
    want = sorted((s.label, s.start, s.end) for s in rec.segments)
    assert sorted((s.label, s.start, s.end) for s in back.segments) == want
    counts = rs.steps_in_scene(scene)
    assert sum(counts.values()) == 91 and counts["touch"] == 76
    if layout == "none":  # a marker added: the timeline decides from then on
        scene.timeline_markers.new("bodycal:stand", frame=40)
        assert rs.steps_in_scene(scene) == {"stand": 1}
        assert [s.step for s in rs.recording_from_scene(scene).segments] == ["stand"]


def test_a_step_left_where_it_was_keeps_its_end_and_a_moved_one_runs_to_the_next_marker():
    rec = _recording()  # tpose 0.2-1.0, touch 1.1-1.3, motion 1.5-2.9 at 90 Hz
    scene = bpy.context.scene
    rs.import_recording_to_scene(rec, scene)
    assert sorted((m.frame, m.name) for m in scene.timeline_markers) == [
        (19, "bodycal:tpose"), (100, "bodycal:touch:wrist_top_l:index_tip_r"), (136, "bodycal:motion")]
    touch = next(m for m in scene.timeline_markers if m.name.startswith("bodycal:touch"))
    touch.frame = 95
    scene.timeline_markers.new("bodycal:end", frame=60)  # ends the T-pose early
    got = {s.step: (s.start, s.end) for s in rs.recording_from_scene(scene).segments}
    assert got["tpose"] == pytest.approx((0.2, 59 / 90))
    assert got["touch"] == pytest.approx((94 / 90, 135 / 90))  # moved: to the next marker
    assert got["motion"] == pytest.approx((1.5, 2.9))


def test_the_file_filter_lists_recordings_and_a_dropped_file_must_be_one(tmp_path):
    """The file browser lists `*.json` (BodyCal's `*.bcrec.json` and A-Frame captures), `*.csv`, `*.c3d`
    and `*.bsor`; a drop (Blender gives the path to invoke) is claimed by suffix, and a
    file that is not a recording is one line, with nothing imported; a recording goes on to the
    options dialog. (Background Blender runs no invoke: it is called as the drop calls it.)"""
    from types import SimpleNamespace

    from bodycal_addon.recording.io import RECORDING_GLOBS

    op_type = bpy.types.BODYCAL_OT_import_recording
    glob = bpy.ops.bodycal.import_recording.get_rna_type().properties["filter_glob"].default
    assert glob == "*.json;*.csv;*.c3d;*.bsor" == ";".join(RECORDING_GLOBS)
    assert set(bpy.types.BODYCAL_FH_recording.bl_file_extensions.split(";")) == {".json", ".csv", ".c3d", ".bsor"}
    sheet = tmp_path / "sheet.csv"
    sheet.write_text("subject,height\nann,1.7\n")
    take = tmp_path / "take.bcrec.json"
    take.write_text(json.dumps(recording_doc(tpose_recording(seconds=0.5))))
    dialogs, reports = [], []
    context = SimpleNamespace(window_manager=SimpleNamespace(
        invoke_props_dialog=lambda op, **kw: dialogs.append(kw) or {"RUNNING_MODAL"}))

    def dropped(path):
        return SimpleNamespace(filepath=str(path), properties=SimpleNamespace(is_property_set=lambda name: True),
                               report=lambda kind, line: reports.append((kind, line)))

    before = (len(bpy.data.objects), len(bpy.data.collections), len(bpy.data.actions))
    assert op_type.invoke(dropped(sheet), context, None) == {"CANCELLED"}
    (kind, line), = reports
    assert kind == {"ERROR"} and line.startswith("sheet.csv: not a BodyCal recording") and "\n" not in line
    assert not dialogs and (len(bpy.data.objects), len(bpy.data.collections), len(bpy.data.actions)) == before
    assert op_type.invoke(dropped(take), context, None) == {"RUNNING_MODAL"}
    assert dialogs == [{"title": "take.bcrec.json", "confirm_text": "Import"}] and len(reports) == 1


@pytest.mark.parametrize("filepath, hands", [("/takes/take.bcrec.json", False), ("/takes/take.csv", False),
                                              ("/takes/replay.bsor", True), ("/takes/grabLeft.json", True)])
def test_the_file_browser_side_panel_shows_the_import_options(filepath, hands):
    """The options; Hands (which controller is the right hand) only for a file that may be a
    three-point kit's own: an A-Frame .json or a Beat Saber .bsor (FORMATS.md §2.6, §2.7)."""
    import ui_layout

    log = []
    op = type("Op", (), {"layout": ui_layout.RecordingLayout(log), "filepath": filepath})()
    bpy.types.BODYCAL_OT_import_recording.draw(op, bpy.context)
    shown = [entry[2] for entry in log if entry[0] == "prop"]
    assert shown == ["frame_start", "update_scene_rate", "update_scene_range", "step_markers", "fill_gaps"] + (
        ["hands"] if hands else [])
    assert [entry[1] for entry in log if entry[0] == "panel"] == ["BODYCAL_import_timing", "BODYCAL_import_steps"]
