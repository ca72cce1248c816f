"""`make demo` runs the whole pipeline; here on the procedural avatar only, to stay quick."""

import json

import bpy
import numpy as np

from bodycal_addon.blender.demo import ROW_SPACING, THREE_POINT_AVATAR, run_demo, run_three_point_demo
from bodycal_addon.retarget.pipeline import METHODS


def test_demo_bakes_every_method_and_prints_the_table(tmp_path):
    lines = []
    out = run_demo(tmp_path, log=lines.append, only_avatars=["procedural"], three_point=False)
    assert out.is_file()
    table = [ln for ln in lines if ln.startswith("procedural ")]
    assert [ln.split()[1] for ln in table] == list(METHODS)
    for ln in table:
        assert ln.count("mm") == 3  # contact gap median, p95, floor error
    bpy.ops.wm.open_mainfile(filepath=str(out))
    scene = bpy.context.scene
    for row, method in enumerate(METHODS):
        arm = bpy.data.objects[f"procedural.{method}"]
        assert arm.animation_data.action.name == f"demo_full|procedural|{method}"
        # the layout: each avatar plays on its own spot, one row per method (placement.py)
        np.testing.assert_allclose(arm.location, (0.0, ROW_SPACING * row, 0.0), atol=1e-6)
        for frame in (scene.frame_start, (scene.frame_start + scene.frame_end) // 2, scene.frame_end):
            scene.frame_set(frame)
            pelvis = arm.matrix_world @ arm.pose.bones["pelvis"].head
            assert np.linalg.norm(np.array(pelvis.xy) - np.array(arm.location.xy)) < 0.5 * ROW_SPACING, (method, frame)
    assert "bodycal_user_model" in bpy.context.scene


def test_the_demo_bakes_a_real_three_point_take_with_every_method(tmp_path):
    """A real HTC Vive take (HMD and wands, no calibration steps) onto the adult avatar: every
    method baked (each bake verified on the evaluated rig), the devices and the user model kept."""
    lines = []
    out = run_three_point_demo(tmp_path, log=lines.append)
    assert out is not None and out.is_file()
    assert any("devices estimated from the head and hands" in ln for ln in lines)
    bpy.ops.wm.open_mainfile(filepath=str(out))
    scene = bpy.context.scene
    for method in METHODS:
        arm = bpy.data.objects[f"{THREE_POINT_AVATAR}.{method}"]
        assert arm.animation_data.action.name.endswith(f"|{THREE_POINT_AVATAR}|{method}")
        scene.frame_set(scene.frame_end)
        for s in "lr":  # the feet stand on the floor (the object's height) at the take's end
            foot = arm.matrix_world @ arm.pose.bones[f"foot_{s}"].head
            assert abs(foot.z - arm.location.z) < 0.2, (method, s)
    assert "bodycal_user_model" in scene
    for method in METHODS:  # each bake's review: its sheet and its record, verified
        sheet = tmp_path / "review" / f"three_point_{THREE_POINT_AVATAR}__{method}.review.png"
        record = json.loads(sheet.with_suffix("").with_suffix(".review.json").read_text())
        assert sheet.stat().st_size > 10_000 and record["verified"] and record["method"] == method
