"""BodyCal > Avatar: bone map status and fixes, surface calibration, authoring, import/export."""

import bpy

from ..bodycal_addon.blender import avatar_rig, avatar_storage, surface_helpers
from ..bodycal_addon.core import paths
from ..bodycal_addon.core.errors import BodyCalError
from ..operators.avatar import context_armature
from .conventions import draw_help

_cache: dict = {}


def _bone_map(arm):
    """Detection runs regexes over every bone: cache it per armature state for redraws."""
    key = (arm.name, hash(tuple(b.name for b in arm.data.bones)), str(arm.get(avatar_rig.BONE_MAP_PROP, "")))
    if _cache.get("key") != key:
        try:
            _cache.update(key=key, value=avatar_rig.bone_map_for(arm), error=None)
        except BodyCalError as exc:
            _cache.update(key=key, value=None, error=exc.line())
    return _cache["value"], _cache["error"]


class BODYCAL_PT_avatar(bpy.types.Panel):
    """The avatar's bone map and its surface measured from its mesh"""

    bl_idname = "BODYCAL_PT_avatar"
    bl_label = "Avatar"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "BodyCal"
    bl_parent_id = "BODYCAL_PT_main"

    def draw_header_preset(self, _context):
        draw_help(self.layout, "Avatar")

    def draw(self, context):
        layout = self.layout
        col = layout.column(align=True)
        col.operator("bodycal.import_avatar", icon="IMPORT")
        row = col.row(align=True)
        row.operator("bodycal.add_procedural_avatar", text="Procedural", icon="OUTLINER_OB_ARMATURE")
        # The samples come with the source repository, not the extension zip: an installed
        # extension would show the button greyed out for good.
        if paths.shared_avatar_files():
            row.operator("bodycal.load_sample_avatars", text="Samples", icon="IMPORT")
        arm = context_armature(context)
        if arm is None:
            layout.label(text="Select an avatar's armature or mesh", icon="INFO")
            return
        layout.label(text=arm.name, icon="OUTLINER_OB_ARMATURE")
        bm, error = _bone_map(arm)
        box = layout.box()
        row = box.row()
        row.label(text="Bone Map", icon="BONE_DATA")
        row.operator("bodycal.detect_bone_map", text="", icon="FILE_REFRESH")
        if error:
            box.label(text=error, icon="ERROR")
        elif bm is not None:
            missing = bm.missing()
            mapped = len(bm.bones) + sum(1 for c in bm.chains.values() if c)
            box.label(text=f"{bm.scheme}: {mapped} segments mapped",
                      icon="ERROR" if missing else "CHECKMARK")
            fingers = [s for s in bm.missing(with_fingers=True) if s not in missing]
            if fingers:
                box.label(text=f"No finger bones for {len(fingers)} phalanges", icon="INFO")
            active = arm.data.bones.active
            for seg in missing:
                row = box.row(align=True)
                row.label(text=seg)
                op = row.operator("bodycal.assign_bone", text=active.name if active else "Assign Active Bone",
                                  icon="EYEDROPPER")
                op.segment = seg
                op.bone = ""
            if missing and not active:
                box.label(text="Select the bone in Pose Mode, then assign", icon="INFO")
            box.operator("bodycal.set_hinge_axis", icon="CON_ROTLIKE")
        # Presets: a naming scheme forced, or a saved map (FORMATS.md §5); the map stays on the armature.
        row = box.row(align=True)
        row.prop(context.window_manager, "bodycal_bone_map_preset", text="")
        row.operator("bodycal.apply_bone_map_preset", text="Apply", icon="CHECKMARK")
        row = box.row(align=True)
        row.operator("bodycal.export_bone_map", text="Export Map", icon="EXPORT")
        row.operator("bodycal.import_bone_map", text="Import Map", icon="IMPORT")
        col = layout.column(align=True)
        col.operator("bodycal.calibrate_avatar", icon="MOD_MESHDEFORM")
        if avatar_storage.has_model(arm):
            col.label(text="Avatar model stored on the armature", icon="CHECKMARK")
            row = col.row(align=True)
            row.operator("bodycal.edit_surface", icon="EMPTY_DATA")
            if surface_helpers.helper_collection(arm) is not None:
                row.operator("bodycal.apply_surface_edits", icon="CHECKMARK")
        row = col.row(align=True)
        row.operator("bodycal.export_avatar_model", icon="EXPORT", text="Export")
        row.operator("bodycal.import_avatar_model", icon="IMPORT", text="Import")


CLASSES = (BODYCAL_PT_avatar,)
