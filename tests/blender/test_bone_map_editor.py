"""The Bone Map sub-panel's editor: every canonical segment listed with its bone, edited in place
through the row's property (what the panel's bone search writes), stored in the armature's one
map, undoable, reaching what a bake keys; search; one-line refusals; back to detection."""

from __future__ import annotations

import importlib
from types import SimpleNamespace

import bpy
import numpy as np
import pytest
import ui_layout

from bodycal_addon.blender import avatar_rig, avatar_storage, calibration_scene, recording_scene
from bodycal_addon.blender.fcurves import object_fcurves, read_keys
from bodycal_addon.body import naming
from bodycal_addon.body import skeleton as sk
from bodycal_addon.core import paths
from bodycal_dev import synthetic

rigs = paths.sample_rigs()
EXT = "bl_ext.user_default.bodycal"  # the modules as the extension loaded them
editor = importlib.import_module(f"{EXT}.operators.bone_map_editor")
panel = importlib.import_module(f"{EXT}.panels.bone_map_panel")
FILTERED = 1 << 30  # UIList.bitflag_filter_item


class IconLayout(ui_layout.RecordingLayout):
    """Records each label's icon too: a row's icon says detected, set by hand or missing."""

    def label(self, text="", icon="NONE", **_kw):
        self.log.append(("label", text, icon))


def _avatar(twin: bool = False):
    """The procedural avatar, active, its editor's rows made. `twin`: a second left forearm bone
    (same rest as lowerarm_l, which hangs from it with the hand) that no naming scheme maps: either
    may be the forearm, the hand hanging from both (a limb bone must hang from the one before it)."""
    arm, _mesh, _spec = rigs.build_procedural_avatar()
    bpy.context.view_layer.objects.active = arm
    arm.select_set(True)
    if twin:
        bpy.ops.object.mode_set(mode="EDIT")
        bones = arm.data.edit_bones
        src = bones["lowerarm_l"]
        new = bones.new("forearm_twin_l")
        new.head, new.tail, new.roll = src.head, src.tail, src.roll
        new.parent, new.use_connect = src.parent, src.use_connect
        src.use_connect = False
        src.parent = new
        bpy.ops.object.mode_set(mode="OBJECT")
    assert bpy.ops.bodycal.show_bone_map() == {"FINISHED"}
    return arm


def _row(arm, segment):
    return next(r for r in arm.bodycal_bone_map_rows if r.name == segment)


def _ulist(filter_name=""):
    return SimpleNamespace(filter_name=filter_name, expanded=[g[3] for g in editor.GROUPS],
                           bitflag_filter_item=FILTERED)


def _shown(arm, ulist) -> list[str]:
    flags, order = panel.BODYCAL_UL_bone_map.filter_items(ulist, bpy.context, arm, "bodycal_bone_map_rows")
    assert order == []
    return [r.name for r, f in zip(arm.bodycal_bone_map_rows, flags) if f & FILTERED]


def _row_labels(arm) -> dict[str, str]:
    """segment -> the icon its row's label shows, drawn as the list draws it."""
    log = []
    for item in arm.bodycal_bone_map_rows:
        panel.draw_row(_ulist(), IconLayout(log), arm, item)
    return {e[1]: e[2] for e in log if e[0] == "label" and e[1] in sk.SEGMENTS}


def _stored(arm) -> dict:
    return avatar_rig.load_overrides(arm)


def test_the_list_shows_every_segment_with_its_detected_bone():
    arm, _mesh, _spec = rigs.build_procedural_avatar()
    bpy.context.view_layer.objects.active = arm
    log = ui_layout.draw(bpy.types.BODYCAL_PT_bone_map, bpy.context)
    assert ("operator", "bodycal.show_bone_map") in log and not editor.rows_ready(arm)  # drawing wrote nothing
    assert bpy.ops.bodycal.show_bone_map() == {"FINISHED"}
    rows = arm.bodycal_bone_map_rows
    segments = [r.name for r in rows if r.kind != "GROUP"]
    assert sorted(segments) == sorted(sk.SEGMENTS)  # every canonical segment, once
    bm = avatar_rig.bone_map_for(arm)
    for r in rows:
        if r.kind == "SEGMENT":
            assert r.bone == bm.bones.get(r.name, ""), r.name
    shown = {r.name: r.bones if r.kind == "CHAIN" else r.bone for r in rows if r.kind != "GROUP"}
    assert {"root": "Root", "pelvis": "pelvis", "spine": "spine_01, spine_02, spine_03", "neck": "neck_01",
            "forearm_l": "lowerarm_l", "shin_r": "calf_r", "thumb_2_l": "thumb_02_l", "toe_l": "ball_l",
            "metacarpal_index_l": "", "breast_r": ""}.items() <= shown.items()
    assert {r.name for r in rows if r.kind == "CHAIN"} == set(sk.CHAIN_SEGMENTS)
    # the panel: the scheme detection found, the list, no line of trouble
    log = ui_layout.draw(bpy.types.BODYCAL_PT_bone_map, bpy.context)
    labels = [e[1] for e in log if e[0] == "label"]
    assert f"Detected: {naming.UNREAL.title}" in labels
    assert f"{sum(1 for v in shown.values() if v)} of {len(sk.SEGMENTS)} segments mapped, 0 set by hand" in labels
    assert not [t for t in labels if t.startswith("Missing")]
    assert ("template_list", "BODYCAL_UL_bone_map", arm, "bodycal_bone_map_rows") in log
    # each single segment's bone is a search over the armature's bones; a chain is its list
    log = []
    for item in rows:
        panel.draw_row(_ulist(), ui_layout.RecordingLayout(log), arm, item)
    searches = [e for e in log if e[0] == "prop_search"]
    assert len(searches) == len(sk.SEGMENTS) - len(sk.CHAIN_SEGMENTS)
    assert all(e[2] == "bone" and e[3] == arm.data and e[4] == "bones" for e in searches)
    assert sorted(e[1].name for e in log if e[0] == "prop" and e[2] == "bones") == sorted(sk.CHAIN_SEGMENTS)
    icons = _row_labels(arm)
    assert icons["forearm_l"] == "CHECKMARK" and icons["breast_l"] == "DOT"


def _bake_rotations(arm, rec, truth):
    scene = bpy.context.scene
    if not scene.get("bodycal_imported"):
        recording_scene.import_recording_to_scene(rec, scene)
        calibration_scene.store_user_model(scene, truth.body_model())
        scene["bodycal_imported"] = True
    scene.bodycal_bake.armature = arm
    scene.bodycal_retarget.method = "rotations"
    assert bpy.ops.bodycal.retarget_bake() == {"FINISHED"}
    curves = object_fcurves(arm)
    keyed = np.concatenate([read_keys(fc)[0] for fc in curves.values()])
    frames = np.arange(int(keyed.min()), int(keyed.max()) + 1)
    return {path: np.array([[curves[path, i].evaluate(f) for i in range(4)] for f in frames])
            for path, _i in curves if "rotation_quaternion" in path}


def _turns(q) -> bool:
    """A keyed rotation that moves (an unmapped bone is keyed at rest or not at all)."""
    return q is not None and not np.allclose(np.abs(q[:, 0]), 1.0, atol=1e-6)


def test_an_edit_changes_the_stored_map_and_what_a_bake_keys_and_is_undone():
    performer = synthetic.make_performer(seed=3)
    rec, truth = synthetic.record_session(performer, profile="full", motions=("hand_on_belly",),
                                          calibration=["tpose"], seed=3)
    arm = _avatar(twin=True)
    before = _bake_rotations(arm, rec, truth)  # calibrates the avatar and keeps its model
    lower, twin = 'pose.bones["lowerarm_l"].rotation_quaternion', 'pose.bones["forearm_twin_l"].rotation_quaternion'
    assert _turns(before[lower]) and not _turns(before.get(twin)) and avatar_storage.has_model(arm)
    bpy.ops.ed.undo_push(message="baked")
    _row(arm, "forearm_l").bone = "forearm_twin_l"  # what the row's bone search writes
    bpy.ops.ed.undo_push(message="forearm_l")
    assert _stored(arm) == {"forearm_l": "forearm_twin_l"}
    assert avatar_rig.bone_map_for(arm).bones["forearm_l"] == "forearm_twin_l"
    assert not avatar_storage.has_model(arm)  # made with the other forearm: removed
    labels = [e[1] for e in ui_layout.draw(bpy.types.BODYCAL_PT_bone_map, bpy.context) if e[0] == "label"]
    assert f"procedural: {avatar_rig.MODEL_DROPPED}" in labels and any("1 set by hand" in t for t in labels)
    assert _row_labels(arm)["forearm_l"] == "HAND"
    # undo and redo: the map and the model come back, then the edit again
    assert bpy.ops.ed.undo() == {"FINISHED"}
    arm = bpy.data.objects["procedural"]
    assert _stored(arm) == {} and _row(arm, "forearm_l").bone == "lowerarm_l" and avatar_storage.has_model(arm)
    assert bpy.ops.ed.redo() == {"FINISHED"}
    arm = bpy.data.objects["procedural"]
    assert _row(arm, "forearm_l").bone == "forearm_twin_l" and not avatar_storage.has_model(arm)
    after = _bake_rotations(arm, rec, truth)
    assert _turns(after[twin]) and not _turns(after.get(lower))  # the forearm's motion is on the new bone
    np.testing.assert_allclose(after[twin], before[lower], atol=1e-5)  # the same rest: the same motion


def test_the_search_finds_segments_by_name_or_bone_in_any_group():
    arm = _avatar()
    assert _shown(arm, _ulist("forearm")) == ["arm_l", "forearm_l", "arm_r", "forearm_r"]
    assert _shown(arm, _ulist("CALF")) == ["leg_l", "shin_l", "leg_r", "shin_r"]  # by bone, any case
    assert _shown(arm, _ulist("thumb_?_r")) == ["fingers_r", "thumb_1_r", "thumb_2_r", "thumb_3_r"]  # wildcards
    assert _shown(arm, _ulist("nothing like it")) == []
    # no search: every group's header, the rows of open groups (fingers and auxiliary start closed)
    shown = _shown(arm, _ulist())
    assert [g[0] for g in editor.GROUPS] == [n for n in shown if n not in sk.SEGMENTS]
    assert "forearm_l" in shown and "spine" in shown and "index_1_l" not in shown and "heel_r" not in shown
    ulist = _ulist()
    ulist.expanded[[g[0] for g in editor.GROUPS].index("fingers_l")] = True
    assert "index_1_l" in _shown(arm, ulist) and "index_1_r" not in _shown(arm, ulist)
    _row(arm, "toe_l").bone = ""  # the search looks at the map as it is now
    assert _shown(arm, _ulist("ball")) == ["leg_r", "toe_r"]


def test_an_invalid_edit_changes_nothing_and_is_one_line():
    arm = _avatar()
    cases = [("forearm_l", "bone", "lowerarmm_l",
              "procedural: forearm_l: the armature has no bone 'lowerarmm_l' (did you mean 'lowerarm_l'?)"),
             ("hand_l", "bone", "lowerarm_l", "procedural: bone 'lowerarm_l' is given to forearm_l and hand_l "
              "(a bone can serve one segment only: clear forearm_l first, or pick another bone)"),
             ("spine", "bones", "spine_01, spine_01", "is given to spine[0] and spine[1]"),
             ("spine", "bones", "spine_01, spine_02, spine_03, head", "is given to head and spine[3]")]
    for segment, prop, value, words in cases:
        setattr(_row(arm, segment), prop, value)
        assert avatar_rig.BONE_MAP_PROP not in arm  # nothing stored
        icon, line = editor.note(arm)
        assert icon == "ERROR" and words in line and "\n" not in line, segment
        labels = [e[1] for e in ui_layout.draw(bpy.types.BODYCAL_PT_bone_map, bpy.context) if e[0] == "label"]
        assert line in labels
    assert _row(arm, "hand_l").bone == "hand_l"  # the field shows the map, not the refused text
    with pytest.raises(RuntimeError, match="is given to forearm_l and hand_l"):
        bpy.ops.bodycal.assign_bone(segment="hand_l", bone="lowerarm_l")  # the same rule for Assign Bone
    # a good edit clears the line; a chain takes its list
    _row(arm, "spine").bones = "spine_01,spine_02"
    assert editor.note(arm) is None and avatar_rig.bone_map_for(arm).chains["spine"] == ["spine_01", "spine_02"]
    assert _row(arm, "spine").bones == "spine_01, spine_02"
    # picking the bone already there stores nothing: the segment stays detected
    _row(arm, "forearm_r").bone = "lowerarm_r"
    assert "forearm_r" not in _stored(arm)
    # a stored map that names a bone the armature no longer has (renamed) is one line in the panel
    _row(arm, "forearm_l").bone = "lowerarm_l"  # the same as detection: nothing stored
    bpy.ops.bodycal.assign_bone(segment="toe_l", bone="ball_l")
    arm.data.bones["ball_l"].name = "Ball_Left"
    labels = [e[1] for e in ui_layout.draw(bpy.types.BODYCAL_PT_bone_map, bpy.context) if e[0] == "label"]
    assert [t for t in labels if t.startswith("procedural: toe_l: the armature has no bone 'ball_l'")]


def test_clear_revert_and_reset_give_back_the_detected_map():
    arm = _avatar(twin=True)
    detected = avatar_rig.bone_map_for(arm)
    assert bpy.ops.bodycal.calibrate_avatar() == {"FINISHED"}
    _row(arm, "forearm_l").bone = "forearm_twin_l"
    assert bpy.ops.bodycal.clear_bone_map_entry(segment="hand_r") == {"FINISHED"}
    _row(arm, "metacarpal_index_l").bone = "lowerarm_l"  # the bone the edit freed
    assert _stored(arm) == {"forearm_l": "forearm_twin_l", "hand_r": "", "metacarpal_index_l": "lowerarm_l"}
    icons = _row_labels(arm)
    assert icons["hand_r"] == "ERROR" and icons["forearm_l"] == "HAND" and icons["hand_l"] == "CHECKMARK"
    labels = [e[1] for e in ui_layout.draw(bpy.types.BODYCAL_PT_bone_map, bpy.context) if e[0] == "label"]
    assert "Missing: hand_r" in labels
    # revert one entry: refused while its detected bone serves another segment, then given back
    with pytest.raises(RuntimeError, match="is given to metacarpal_index_l and forearm_l"):
        bpy.ops.bodycal.revert_bone_map_entry(segment="forearm_l")
    assert bpy.ops.bodycal.revert_bone_map_entry(segment="metacarpal_index_l") == {"FINISHED"}
    assert bpy.ops.bodycal.revert_bone_map_entry(segment="forearm_l") == {"FINISHED"}
    assert _stored(arm) == {"hand_r": ""} and _row(arm, "forearm_l").bone == "lowerarm_l"
    # a model calibrated with an edited map, then Reset to Detected: the map detection gives, the model removed
    assert bpy.ops.bodycal.revert_bone_map_entry(segment="hand_r") == {"FINISHED"}
    _row(arm, "forearm_l").bone = "forearm_twin_l"
    assert bpy.ops.bodycal.calibrate_avatar() == {"FINISHED"}
    assert bpy.ops.bodycal.detect_bone_map(reset=True) == {"FINISHED"}
    assert avatar_rig.BONE_MAP_PROP not in arm and not avatar_storage.has_model(arm)
    assert avatar_rig.bone_map_for(arm) == detected
    assert all(r.bone == detected.bones.get(r.name, "") for r in arm.bodycal_bone_map_rows if r.kind == "SEGMENT")
    assert set(_row_labels(arm).values()) <= {"CHECKMARK", "DOT"}


def test_rows_are_made_after_drawing_not_during_it():
    arm, _mesh, _spec = rigs.build_procedural_avatar()
    assert not editor.rows_ready(arm)
    editor._build_later(arm.name)  # the timer a window's draw asks for
    assert editor.rows_ready(arm) and len(arm.bodycal_bone_map_rows) == len(editor.ROWS)
    bpy.context.view_layer.objects.active = arm
    assert bpy.ops.bodycal.show_bone_map() == {"FINISHED"} and len(arm.bodycal_bone_map_rows) == len(editor.ROWS)
    for cls in editor.CLASSES:  # every edit is undoable
        if issubclass(cls, bpy.types.Operator):
            assert "UNDO" in cls.bl_options, cls.bl_idname

