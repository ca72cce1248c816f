"""BodyCal > Avatar: surface calibration, authoring, import/export (the bone map: its Bone Map
sub-panel, panels/bone_map_panel.py)."""

import bpy

from ..bodycal_addon.blender import avatar_storage, demo, surface_helpers
from ..operators.avatar import context_armature
from .conventions import draw_help


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
        if demo.shared_avatar_files():
            row.operator("bodycal.load_sample_avatars", text="Samples", icon="IMPORT")
        arm = context_armature(context)
        if arm is None:
            layout.label(text="Select an avatar's armature or mesh", icon="INFO")
            return
        layout.label(text=arm.name, icon="OUTLINER_OB_ARMATURE")
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
