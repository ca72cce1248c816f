"""Sidebar: transfer another character's animation onto the avatar(s) (DESIGN.md §8)."""

import bpy

from ..bodycal_addon.blender import preview
from .bake_presets import draw_presets_button
from .bake_rows import draw_keys, draw_last_result, draw_placement
from .conventions import draw_help


class BODYCAL_PT_transfer(bpy.types.Panel):
    """Another character's animation onto the avatar(s), keeping its self-contacts"""

    bl_idname = "BODYCAL_PT_transfer"
    bl_label = "Transfer Animation"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "BodyCal"
    bl_parent_id = "BODYCAL_PT_main"
    bl_options = {"DEFAULT_CLOSED"}

    def draw_header_preset(self, _context):
        draw_presets_button(self.layout)
        draw_help(self.layout, "Transfer Animation")

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        st, bake = context.scene.bodycal_transfer, context.scene.bodycal_bake
        col = layout.column()
        col.prop(st, "source")
        col.prop(st, "action")
        col.prop(bake, "armature", text="Target")
        col.prop(st, "method")
        col.prop(st, "use_filter")
        draw_placement(col, bake)
        draw_keys(col, bake)
        on = preview.any_active()
        col.operator("bodycal.preview_retarget", text="Stop Preview" if on else "Preview", icon="PLAY",
                     depress=on).take = "transfer"
        col.operator("bodycal.transfer_animation", icon="ACTION")
        draw_last_result(layout, st, context)


CLASSES = (BODYCAL_PT_transfer,)
