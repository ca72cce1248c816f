"""The BodyCal sidebar tab: one panel per stage of the pipeline."""

import bpy

from ..bodycal_addon.core import paths


class BODYCAL_PT_main(bpy.types.Panel):
    """BodyCal: VR tracker recordings onto any humanoid avatar, keeping self-contacts"""

    bl_idname = "BODYCAL_PT_main"
    bl_label = "BodyCal"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "BodyCal"

    def draw(self, context):
        layout = self.layout
        col = layout.column(align=True)
        col.label(text="Avatars", icon="ARMATURE_DATA")
        col.operator("bodycal.add_procedural_avatar", icon="OUTLINER_OB_ARMATURE")
        # The samples come with the source repository, not the extension zip: an installed
        # extension would show the button greyed out for good.
        if paths.shared_avatar_files():
            col.operator("bodycal.load_sample_avatars", icon="IMPORT")


CLASSES = (BODYCAL_PT_main,)
