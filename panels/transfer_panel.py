"""Sidebar: transfer another character's animation onto the avatar(s) (issue 16)."""

import bpy


class BODYCAL_PT_transfer(bpy.types.Panel):
    bl_idname = "BODYCAL_PT_transfer"
    bl_label = "Transfer Animation"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "BodyCal"
    bl_parent_id = "BODYCAL_PT_main"
    bl_options = {"DEFAULT_CLOSED"}

    def draw(self, context):
        layout = self.layout
        st = context.scene.bodycal_transfer
        col = layout.column()
        col.prop(st, "source")
        col.prop(st, "action")
        col.prop(st, "armature")
        col.prop(st, "method")
        col.prop(st, "placement")
        col.prop(st, "root_motion")
        col.prop(st, "rigify_target")
        col.prop(st, "plant_feet")
        row = col.row(align=True)
        row.prop(st, "replace", toggle=True)
        row.prop(st, "push_to_nla", toggle=True)
        sub = col.column(align=True)
        sub.prop(st, "output_fps")
        sub.prop(st, "tolerance")
        sub.prop(st, "location_tolerance")
        col.operator("bodycal.transfer_animation", icon="ACTION")
        if st.last_result:
            box = layout.box()
            for part in st.last_result.split("; "):
                box.label(text=part)


CLASSES = (BODYCAL_PT_transfer,)
