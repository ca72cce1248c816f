"""Sidebar: pick the avatar and the method, retarget and bake, see the result's figures."""

import bpy


class BODYCAL_PT_retarget(bpy.types.Panel):
    bl_idname = "BODYCAL_PT_retarget"
    bl_label = "Retarget and Bake"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "BodyCal"
    bl_parent_id = "BODYCAL_PT_main"

    def draw(self, context):
        layout = self.layout
        settings = context.scene.bodycal_retarget
        col = layout.column()
        col.prop(settings, "armature")
        col.prop(settings, "method")
        col.prop(settings, "placement")
        col.prop(settings, "root_motion")
        col.prop(settings, "rigify_target")
        row = col.row(align=True)
        row.prop(settings, "replace", toggle=True)
        row.prop(settings, "push_to_nla", toggle=True)
        col.prop(settings, "plant_feet")
        col.prop(settings, "use_filter")
        if settings.use_filter:
            sub = col.column(align=True)
            sub.prop(settings, "filter_min_cutoff")
            sub.prop(settings, "filter_beta")
            sub.prop(settings, "filter_rot_min_cutoff")
            sub.prop(settings, "filter_rot_beta")
        sub = col.column(align=True)
        sub.prop(settings, "output_fps")
        sub.prop(settings, "tolerance")
        sub.prop(settings, "location_tolerance")
        col.operator("bodycal.retarget_bake", icon="ACTION")
        col.operator("bodycal.export_animation", icon="EXPORT")
        if settings.last_result:
            box = layout.box()
            for part in settings.last_result.split("; "):
                box.label(text=part)


CLASSES = (BODYCAL_PT_retarget,)
