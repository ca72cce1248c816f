"""The BodyCal sidebar tab: one sub-panel per stage of the work, in the order of
panels/conventions.ORDER (docs/SIDEBAR.md)."""

import bpy

from .conventions import draw_help


class BODYCAL_PT_main(bpy.types.Panel):
    """BodyCal: VR tracker recordings onto any humanoid avatar, keeping self-contacts"""

    bl_idname = "BODYCAL_PT_main"
    bl_label = "BodyCal"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "BodyCal"

    def draw_header_preset(self, _context):
        draw_help(self.layout, "The BodyCal sidebar")

    def draw(self, _context):
        pass  # the stages are its sub-panels


CLASSES = (BODYCAL_PT_main,)
