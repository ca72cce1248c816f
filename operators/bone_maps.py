"""Bone map presets in the Avatar panel (FORMATS.md §5): pick one (built-in per naming scheme, or
yours), Apply it to the armature, Export the armature's map as a preset, Import a preset file
into your presets. The map itself is kept on the armature (`avatar_rig`): one storage."""

import os

import bpy
from bpy_extras.io_utils import ExportHelper, ImportHelper

from ..bodycal_addon.blender import BodyCalError, avatar_rig, bone_map_presets
from .avatar import context_armature, poll_armature
from .reporting import reports_errors

_items_alive: list = []  # Blender keeps only pointers to a dynamic enum's strings: hold them here


def _preset_items(_self, _context):
    try:
        entries = bone_map_presets.preset_entries()
    except (BodyCalError, OSError, ValueError) as exc:  # the user folder cannot be read: built-ins only
        entries = bone_map_presets.builtin_entries(exc)
    _items_alive[:] = [(ident, label, desc, i) for i, (ident, label, desc) in enumerate(entries)]
    return _items_alive


def _report_map(op, arm, bm, dropped: bool, what: str) -> None:
    missing = bm.missing()
    mapped = len(bm.bones) + sum(1 for c in bm.chains.values() if c)
    text = f"{arm.name}: {what}, {mapped} segments mapped"
    if missing:
        op.report({"WARNING"}, f"{text}; missing {', '.join(missing)}: assign them in the Avatar panel")
    elif dropped:
        op.report({"WARNING"}, f"{text}; {avatar_rig.MODEL_DROPPED}")
    else:
        op.report({"INFO"}, text)


class BODYCAL_OT_apply_bone_map_preset(bpy.types.Operator):
    """Map the armature's bones with a preset (a naming scheme, or one of your bone map files);
    saved with the armature"""

    bl_idname = "bodycal.apply_bone_map_preset"
    bl_label = "Apply Bone Map Preset"
    bl_options = {"REGISTER", "UNDO"}

    preset: bpy.props.StringProperty(
        name="Preset", options={"SKIP_SAVE"},
        description="builtin:<scheme> or user:<file>; empty: the preset chosen in the Avatar panel")

    @classmethod
    def poll(cls, context):
        if not poll_armature(cls, context, object_mode=False):
            return False
        if not getattr(context.window_manager, "bodycal_bone_map_preset", ""):
            cls.poll_message_set("Choose a bone map preset first")
            return False
        return True

    @reports_errors
    def execute(self, context):
        arm = context_armature(context)
        preset = bone_map_presets.preset_for(self.preset or context.window_manager.bodycal_bone_map_preset)
        bm, dropped = avatar_rig.apply_preset(arm, preset)
        _report_map(self, arm, bm, dropped, f"preset '{preset.name}'")
        return {"FINISHED"}


class BODYCAL_OT_export_bone_map(bpy.types.Operator, ExportHelper):
    """Write the armature's bone map as a preset file (JSON); saved in your presets folder it
    appears in the preset list"""

    bl_idname = "bodycal.export_bone_map"
    bl_label = "Export Bone Map"
    bl_options = {"REGISTER"}

    filename_ext = ".json"
    filter_glob: bpy.props.StringProperty(default="*.json", options={"HIDDEN"})
    preset_name: bpy.props.StringProperty(name="Preset Name", description="Shown in the preset list "
                                          "(default: the armature's name)")

    @classmethod
    def poll(cls, context):
        return poll_armature(cls, context, object_mode=False)

    @reports_errors
    def invoke(self, context, event):
        arm = context_armature(context)
        self.preset_name = self.preset_name or arm.name
        folder = bone_map_presets.user_preset_dir()
        self.filepath = os.path.join(str(folder), bpy.path.clean_name(arm.name) + ".json")
        return super().invoke(context, event)

    @reports_errors
    def execute(self, context):
        arm = context_armature(context)
        path, preset = bone_map_presets.export_bone_map(arm, self.filepath, self.preset_name or arm.name)
        if path.resolve().parent == bone_map_presets.user_preset_dir().resolve():
            context.window_manager.bodycal_bone_map_preset = f"{bone_map_presets.USER}{path.name}"
        self.report({"INFO"}, f"Wrote bone map preset '{preset.name}' to {path}")
        return {"FINISHED"}


class BODYCAL_OT_import_bone_map(bpy.types.Operator, ImportHelper):
    """Check a bone map preset file and keep it in your presets folder; with Apply, map the
    armature's bones with it"""

    bl_idname = "bodycal.import_bone_map"
    bl_label = "Import Bone Map"
    bl_options = {"REGISTER", "UNDO"}

    filename_ext = ".json"
    filter_glob: bpy.props.StringProperty(default="*.json", options={"HIDDEN"})
    apply: bpy.props.BoolProperty(name="Apply", default=True,
                                  description="Also map the active armature's bones with it")

    @reports_errors
    def execute(self, context):
        arm = context_armature(context) if self.apply else None
        if arm is not None:  # checked on the armature before anything is kept
            bone_map_presets.check_fits(self.filepath, arm)
        ident, preset = bone_map_presets.import_preset_file(self.filepath)
        context.window_manager.bodycal_bone_map_preset = ident
        if arm is None:
            self.report({"INFO"}, f"Added bone map preset '{preset.name}' to your presets")
            return {"FINISHED"}
        bm, dropped = avatar_rig.apply_preset(arm, preset)
        _report_map(self, arm, bm, dropped, f"imported preset '{preset.name}'")
        return {"FINISHED"}


CLASSES = (BODYCAL_OT_apply_bone_map_preset, BODYCAL_OT_export_bone_map, BODYCAL_OT_import_bone_map)


def register_properties():
    bpy.types.WindowManager.bodycal_bone_map_preset = bpy.props.EnumProperty(
        name="Bone Map Preset", items=_preset_items,
        description="Built-in presets force a naming scheme; yours are the files in your presets folder")


def unregister_properties():
    del bpy.types.WindowManager.bodycal_bone_map_preset
