"""`make demo` runs the whole pipeline; here on the procedural avatar only, to stay quick."""

import bpy
import numpy as np

from bodycal_addon.blender.demo import ROW_SPACING, run_demo
from bodycal_addon.retarget.pipeline import METHODS


def test_demo_bakes_every_method_and_prints_the_table(tmp_path):
    lines = []
    out = run_demo(tmp_path, log=lines.append, only_avatars=["procedural"])
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
