"""Add the sample avatars: the procedural avatar of known dimensions and the shared MakeHuman ones."""

import bpy

from .. import sample_rigs
from ..bodycal_addon.blender import demo


class BODYCAL_OT_add_procedural_avatar(bpy.types.Operator):
    """Add the procedural avatar whose surface dimensions are known exactly (capsule limbs,
    ellipsoid torso, sphere head)"""

    bl_idname = "bodycal.add_procedural_avatar"
    bl_label = "Add Procedural Avatar"
    bl_options = {"REGISTER", "UNDO"}

    scale: bpy.props.FloatProperty(name="Scale", default=1.0, min=0.3, max=3.0,
                                   description="Uniform scale (1.0 is a 1.76 m tall avatar)")
    arm_drop: bpy.props.FloatProperty(name="Arm Drop", default=0.0, min=0.0, max=60.0, subtype="NONE",
                                      description="Degrees the arms are lowered from a T-pose (A-pose rest)")
    belly: bpy.props.FloatProperty(name="Belly", default=0.0, min=0.0, max=0.3, unit="LENGTH",
                                   description="How far the belly pushes the torso's front out")

    @classmethod
    def poll(cls, context):
        if context.mode != "OBJECT":
            cls.poll_message_set("Switch to Object Mode to add an avatar")
            return False
        return True

    def execute(self, context):
        arm, _mesh, spec = sample_rigs.build_procedural_avatar(
            scale=self.scale, arm_drop_deg=self.arm_drop, belly=self.belly)
        self.report({"INFO"}, f"Added {arm.name}: {spec.truth['height']:.2f} m tall, {len(spec.bones)} bones")
        return {"FINISHED"}


class BODYCAL_OT_load_sample_avatars(bpy.types.Operator):
    """Import the shared MakeHuman sample avatars (adult, child, heavy belly, long arms)"""

    bl_idname = "bodycal.load_sample_avatars"
    bl_label = "Load Sample Avatars"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        if context.mode != "OBJECT":
            cls.poll_message_set("Switch to Object Mode to load avatars")
            return False
        if not demo.shared_avatar_files():
            cls.poll_message_set("No sample avatars: they come with the source repository (sample_data/), "
                                 "or set BODYCAL_DATA")
            return False
        return True

    def execute(self, context):
        loaded = []
        for i, path in enumerate(demo.shared_avatar_files()):
            try:
                arm, _mesh = sample_rigs.load_glb_avatar(path)
            except sample_rigs.SampleRigError as exc:
                self.report({"WARNING"}, str(exc))
                continue
            arm.location.x += 1.0 * i  # side by side
            loaded.append(arm.name)
        if not loaded:
            self.report({"ERROR"}, "No sample avatar could be loaded")
            return {"CANCELLED"}
        self.report({"INFO"}, f"Loaded {len(loaded)} sample avatars: {', '.join(loaded)}")
        return {"FINISHED"}


CLASSES = (BODYCAL_OT_add_procedural_avatar, BODYCAL_OT_load_sample_avatars)
