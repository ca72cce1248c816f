"""`make demo` runs the whole pipeline; here on the procedural avatar only, to stay quick."""

import bpy

from bodycal_addon.blender.demo import run_demo
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
    for method in METHODS:
        arm = bpy.data.objects[f"procedural.{method}"]
        assert arm.animation_data.action.name == f"demo_full|procedural|{method}"
    assert "bodycal_user_model" in bpy.context.scene
