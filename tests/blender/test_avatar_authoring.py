"""Per-avatar configuration authoring: the model stored on the armature (survives save/reload),
helper empties round trip, operators with undo, export/import, and the calibrate-avatar CLI."""

from __future__ import annotations

import json

import bpy
import numpy as np
import pytest
from mathutils import Matrix, Vector

from bodycal_addon.app import cli
from bodycal_addon.blender import avatar_calibration as ac
from bodycal_addon.blender import avatar_storage, surface_helpers
from bodycal_addon.body import surface_layout as sl
from bodycal_addon.body.bodymodel import BodyModel
from bodycal_addon.core.errors import BodyCalError
from sample_rigs import build_procedural_avatar


def _point_world(model, eid, name):
    p = model.element(eid).points[name]
    b = model.bones[p.bone]
    h, t = model.joints[b.head].world, model.joints[b.tail].world
    return h + sl.bone_frame(h, t, b.right) @ p.local


def _activate(obj):
    bpy.context.view_layer.objects.active = obj
    obj.select_set(True)


def test_model_survives_save_and_reload(tmp_path):
    arm, _mesh, _spec = build_procedural_avatar()
    model = ac.calibrate_avatar(arm)
    avatar_storage.store_model(arm, model)
    path = tmp_path / "avatar.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path))
    bpy.ops.wm.read_homefile(use_empty=True)
    assert bpy.data.objects.get("procedural") is None
    bpy.ops.wm.open_mainfile(filepath=str(path))
    back = avatar_storage.load_model(bpy.data.objects["procedural"])
    assert back.to_dict() == BodyModel.from_dict(json.loads(model.to_json())).to_dict()
    assert back.extra["rig"]["armature"] == "procedural"


def test_load_without_model_is_one_clear_line():
    arm, _mesh, _spec = build_procedural_avatar()
    with pytest.raises(BodyCalError, match="no avatar body model yet"):
        avatar_storage.load_model(arm)


def test_helpers_round_trip_moves_point_and_radius():
    arm, _mesh, _spec = build_procedural_avatar()
    # a moved armature: helpers must still map back to calibration-time coordinates
    arm.matrix_world = Matrix.Translation((0.5, 0.2, 0.0)) @ Matrix.Rotation(0.4, 4, "Z")
    bpy.context.view_layer.update()
    model = ac.calibrate_avatar(arm)
    avatar_storage.store_model(arm, model)
    coll = surface_helpers.edit_surface(arm)
    n_points = sum(len(e.points) for e in model.surface)
    n_caps = sum(1 for e in model.surface if e.type == "capsule")
    assert len(coll.objects) == n_points + 2 * n_caps + 1
    # nothing moved: nothing changes
    assert surface_helpers.apply_surface_edits(arm) == []
    before = _point_world(model, "mesh:torso", "belly_c2")
    helper = bpy.data.objects[f"{arm.name}:mesh:torso:belly_c2"]
    helper.location += Vector((0.0, -0.03, 0.01))
    cap = bpy.data.objects[f"{arm.name}:capsule:forearm_l:head"]
    cap.scale = (1.5, 1.5, 1.5)
    skull = bpy.data.objects[f"{arm.name}:sphere:skull"]
    skull.location += Vector((0.0, 0.0, 0.02))
    thigh_end = bpy.data.objects[f"{arm.name}:capsule:thigh_l:tail"]
    thigh_end.location += Vector((0.0, -0.015, 0.0))  # the capsule's axis moved forward at the knee
    changed = surface_helpers.apply_surface_edits(arm)
    assert changed == ["capsule:forearm_l", "capsule:thigh_l", "mesh:torso", "sphere:skull"]
    after_model = avatar_storage.load_model(arm)
    after = _point_world(after_model, "mesh:torso", "belly_c2")
    assert np.allclose(after - before, [0.0, -0.03, 0.01], atol=1e-6)
    assert after_model.bones["forearm_l"].radius_head == pytest.approx(1.5 * model.bones["forearm_l"].radius_head)
    assert after_model.bones["forearm_l"].radius_tail == pytest.approx(model.bones["forearm_l"].radius_tail)
    thigh = model.bones["thigh_l"]
    thigh_rot = sl.bone_frame(model.joints[thigh.head].world, model.joints[thigh.tail].world, thigh.right)
    moved = after_model.element("capsule:thigh_l").axis_offsets() - model.element("capsule:thigh_l").axis_offsets()
    assert np.allclose(thigh_rot @ moved[1], [0.0, -0.015, 0.0], atol=1e-6) and np.allclose(moved[0], 0.0)
    r0, r1 = model.element("sphere:skull"), after_model.element("sphere:skull")
    h, t = model.joints["skull_base"].world, model.joints["head"].world
    rot = sl.bone_frame(h, t, model.bones["head"].right)
    assert np.allclose(rot @ (r1.center - r0.center), [0, 0, 0.02], atol=1e-6)
    assert after_model.calibration["edited"] == changed
    # re-export: the edited model is what is written
    surface_helpers.remove_helpers(arm)
    assert surface_helpers.helper_collection(arm) is None


def test_operators_calibrate_edit_apply_export_import_and_undo(tmp_path):
    arm, mesh, _spec = build_procedural_avatar()
    _activate(mesh)  # the mesh selected: the operators act on its armature
    assert bpy.ops.bodycal.detect_bone_map() == {"FINISHED"}
    assert bpy.ops.bodycal.calibrate_avatar() == {"FINISHED"}
    assert avatar_storage.has_model(arm)
    assert bpy.ops.bodycal.edit_surface() == {"FINISHED"}
    helper = bpy.data.objects[f"{arm.name}:mesh:jaw:chin"]
    before = _point_world(avatar_storage.load_model(arm), "mesh:jaw", "chin")
    helper.location += Vector((0.0, -0.02, 0.0))
    bpy.ops.ed.undo_push(message="move chin")
    assert bpy.ops.bodycal.apply_surface_edits() == {"FINISHED"}
    arm = bpy.data.objects["procedural"]
    moved = _point_world(avatar_storage.load_model(arm), "mesh:jaw", "chin")
    assert np.allclose(moved - before, [0, -0.02, 0], atol=1e-6)
    out = tmp_path / "proc.body.json"
    assert bpy.ops.bodycal.export_avatar_model(filepath=str(out)) == {"FINISHED"}
    exported = BodyModel.load(out)
    assert np.allclose(_point_world(exported, "mesh:jaw", "chin"), moved, atol=1e-6)
    # import the exported (edited) model back onto a cleared armature
    avatar_storage.clear_model(arm)
    _activate(arm)
    assert bpy.ops.bodycal.import_avatar_model(filepath=str(out)) == {"FINISHED"}
    assert np.allclose(_point_world(avatar_storage.load_model(arm), "mesh:jaw", "chin"), moved, atol=1e-6)


def test_data_changing_operators_are_undoable():
    import importlib

    ops = importlib.import_module("bl_ext.user_default.bodycal.operators.avatar")  # as the extension loads it

    for cls in ops.CLASSES:
        if cls is not ops.BODYCAL_OT_export_avatar_model:
            assert "UNDO" in cls.bl_options, cls.bl_idname


def test_hinge_axis_operator_and_panel_registered():
    arm, _mesh, _spec = build_procedural_avatar()
    _activate(arm)
    assert bpy.ops.bodycal.set_hinge_axis(bone="shin_l", axis="-X") == {"FINISHED"}
    assert bpy.ops.bodycal.calibrate_avatar() == {"FINISHED"}
    model = avatar_storage.load_model(arm)
    x = np.array(arm.data.bones["calf_l"].matrix_local)[:3, 0]
    assert np.allclose(model.bones["shin_l"].right, -x, atol=1e-6)
    assert bpy.types.BODYCAL_PT_avatar.bl_parent_id == "BODYCAL_PT_main"


class _Layout:
    """Stands in for a UI layout in background mode: records labels, accepts everything else."""

    def __init__(self, log):
        self.log = log

    def label(self, text="", **_kw):
        self.log.append(text)

    def __getattr__(self, name):
        return lambda *a, **k: _Layout(self.log)


def test_avatar_panel_draws_status_and_missing_segments():
    arm, _mesh, _spec = build_procedural_avatar()
    arm.data.bones["calf_l"].name = "LegLower_Left"
    _activate(arm)
    log = []
    panel = type("P", (), {"layout": _Layout(log)})()
    bpy.types.BODYCAL_PT_avatar.draw(panel, bpy.context)
    assert "procedural" in log
    bpy.types.BODYCAL_PT_bone_map.draw(panel, bpy.context)  # its sub-panel: the bone map
    assert "Missing: shin_l" in log
    arm.data.bones["LegLower_Left"].name = "calf_l"
    bpy.ops.bodycal.calibrate_avatar()
    log.clear()
    bpy.types.BODYCAL_PT_avatar.draw(panel, bpy.context)
    bpy.types.BODYCAL_PT_bone_map.draw(panel, bpy.context)
    assert "Avatar model stored on the armature" in log and not [t for t in log if "shin_l" in t]


def test_operator_poll_explains_without_armature():
    bpy.ops.object.empty_add()
    assert not bpy.ops.bodycal.calibrate_avatar.poll()
    with pytest.raises(RuntimeError, match="armature"):
        bpy.ops.bodycal.calibrate_avatar()


def test_import_rejects_a_user_model(tmp_path):
    arm, _mesh, _spec = build_procedural_avatar()
    _activate(arm)
    user = BodyModel("user", "someone")
    path = user.save(tmp_path / "user.body.json")
    with pytest.raises(RuntimeError, match="not an avatar model"):
        bpy.ops.bodycal.import_avatar_model(filepath=str(path))


def test_cli_calibrate_avatar(tmp_path, capsys):
    arm, _mesh, _spec = build_procedural_avatar()
    blend = tmp_path / "avatar.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    out = tmp_path / "avatar.body.json"
    assert cli.main(["calibrate-avatar", str(blend), "-o", str(out)]) == 0
    model = BodyModel.load(out)
    assert model.kind == "avatar"
    assert sorted(e.id for e in model.surface) == sorted(sl.element_ids())
    capsys.readouterr()
    # --overwrite: the existing output is allowed, so the input's own error is the one reported
    assert cli.main(["calibrate-avatar", str(blend), "--armature", "nope", "-o", str(out), "--overwrite"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no armature named 'nope'" in err and "procedural" in err
    assert cli.main(["calibrate-avatar", str(tmp_path / "missing.blend"), "-o", str(out), "--overwrite"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no such file" in err
