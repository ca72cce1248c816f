"""Sidebar: pick the avatar and the method, retarget and bake, see the result's figures."""

import bpy

from ..bodycal_addon.blender import preview
from .bake_presets import draw_presets_button
from .bake_rows import draw_keys, draw_last_result, draw_placement
from .conventions import draw_help


class BODYCAL_PT_retarget(bpy.types.Panel):
    """Retarget the recording onto the avatar(s) and bake a new action"""

    bl_idname = "BODYCAL_PT_retarget"
    bl_label = "Retarget and Bake"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "BodyCal"
    bl_parent_id = "BODYCAL_PT_main"

    def draw_header_preset(self, _context):
        draw_presets_button(self.layout)
        draw_help(self.layout, "Retarget and Bake")

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        settings, bake = context.scene.bodycal_retarget, context.scene.bodycal_bake
        col = layout.column()
        col.prop(bake, "armature")
        col.prop(settings, "method")
        draw_placement(col, bake)
        row = col.row(heading="Seated")
        row.prop(settings, "seated", text="")
        sub = row.row()
        sub.active = settings.seated
        sub.prop(settings, "seat_height", text="")
        draw_smoothing(layout, settings)
        col = layout.column()
        draw_keys(col, bake)
        on = preview.any_active()
        col.operator("bodycal.preview_retarget", text="Stop Preview" if on else "Preview", icon="PLAY",
                     depress=on)
        col.operator("bodycal.retarget_bake", icon="ACTION")
        col.operator("bodycal.export_animation", icon="EXPORT")
        draw_last_result(layout, settings, context)


def draw_smoothing(layout, settings) -> None:
    """Smooth Devices, an optional block: its checkbox in its header, its values greyed out while
    it is off (Blender's convention for an optional block)."""
    header, body = layout.panel("BODYCAL_retarget_smoothing", default_closed=True)
    header.use_property_split = False
    header.prop(settings, "use_filter")
    if body is not None:
        body.active = settings.use_filter
        col = body.column(align=True)
        col.prop(settings, "filter_min_cutoff")
        col.prop(settings, "filter_beta")
        col.prop(settings, "filter_rot_min_cutoff")
        col.prop(settings, "filter_rot_beta")


CLASSES = (BODYCAL_PT_retarget,)
