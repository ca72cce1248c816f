"""File > Import and a dropped file with the three-point kits' own files (FORMATS.md §2.6, §2.7): a
real A-Frame motion capture and a real Beat Saber replay become the scene's recording (a head and
two hands, their roles from where they are, or as the Hands option says), and a file that only
looks like one by its name is one line with nothing imported."""

from __future__ import annotations

from types import SimpleNamespace

import bpy
import numpy as np
import pytest

from bodycal_addon.blender import recording_scene as rs
from bodycal_addon.recording import io as rio


@pytest.fixture(scope="module")
def takes(data_dir):
    return {"aframe": data_dir / "real_vr" / "aframe_vive" / "grabLeft.json",
            "bsor": data_dir / "real_vr" / "beat_saber" / "simsaber_sample.bsor"}


def _roles(scene):
    coll = rs.scene_recording_collection(scene)
    return {o["bodycal_device"]: (o["bodycal_kind"], o["bodycal_role"]) for o in coll.objects if "bodycal_device" in o}


@pytest.mark.parametrize("kind, names", [("aframe", ("camera", "left", "right")),
                                          ("bsor", ("head", "left_hand", "right_hand"))])
def test_a_real_three_point_take_imports_as_head_and_hands(takes, kind, names):
    path = takes[kind]
    assert bpy.ops.bodycal.import_recording(filepath=str(path)) == {"FINISHED"}
    scene = bpy.context.scene
    head, left, right = names
    assert _roles(scene) == {head: ("hmd", "head"), left: ("controller", "hand_l"), right: ("controller", "hand_r")}
    rec = rio.load_recording(path)
    back = rs.recording_from_scene(scene)
    assert back.frame_count == rec.frame_count and back.segments == []
    assert (scene.frame_start, scene.frame_end) == (1, rec.frame_count)
    assert scene.render.fps / scene.render.fps_base == pytest.approx(rec.fps, rel=1e-3)
    for role in ("head", "hand_l", "hand_r"):  # the scene holds the reader's poses
        np.testing.assert_allclose(back.pose(role)[0], rec.pose(role)[0], atol=1e-5)


@pytest.mark.parametrize("kind", ["aframe", "bsor"])
def test_the_hands_option_swaps_the_labels_for_that_import_only(takes, kind):
    assert bpy.ops.bodycal.import_recording(filepath=str(takes[kind]), hands="swapped") == {"FINISHED"}
    roles = {role: name for name, (_kind, role) in _roles(bpy.context.scene).items()}
    assert roles["hand_r"] in ("left", "left_hand") and roles["hand_l"] in ("right", "right_hand")
    # Not remembered for the next import (the file browser reuses an operator's last values): SKIP_SAVE.
    assert bpy.ops.bodycal.import_recording.get_rna_type().properties["hands"].is_skip_save


def test_dropped_three_point_files_go_to_the_dialog_and_a_fake_one_is_one_line(takes, tmp_path):
    op_type = bpy.types.BODYCAL_OT_import_recording
    dialogs, reports = [], []
    context = SimpleNamespace(window_manager=SimpleNamespace(
        invoke_props_dialog=lambda op, **kw: dialogs.append(kw) or {"RUNNING_MODAL"}))

    def dropped(path):
        return SimpleNamespace(filepath=str(path), properties=SimpleNamespace(is_property_set=lambda name: True),
                               report=lambda kind, line: reports.append((kind, line)))

    for path in takes.values():
        assert op_type.invoke(dropped(path), context, None) == {"RUNNING_MODAL"}
    assert [d["title"] for d in dialogs] == ["grabLeft.json", "simsaber_sample.bsor"] and not reports
    fake = tmp_path / "song.bsor"
    fake.write_bytes(b"OggS" + bytes(60))
    before = (len(bpy.data.objects), len(bpy.data.collections), len(bpy.data.actions))
    assert op_type.invoke(dropped(fake), context, None) == {"CANCELLED"}
    (kind, line), = reports
    assert kind == {"ERROR"} and line.startswith("song.bsor: not a Beat Saber replay") and "\n" not in line
    assert (len(bpy.data.objects), len(bpy.data.collections), len(bpy.data.actions)) == before
