"""A bake's review in the sidebar (docs/SIDEBAR.md, "Review"): the figures the review sheet and the
batch's page flag (bodycal_addon/output/review.py), kept per avatar after every bake, and a button
per figure that jumps the timeline to its frame. The flags need no plotting library."""

import math

import bpy


class BODYCAL_PG_review_flag(bpy.types.PropertyGroup):
    """One figure of a bake's review (output/review.Flag)."""

    armature: bpy.props.StringProperty(name="Avatar", description="The armature the bake animated")
    text: bpy.props.StringProperty(name="Figure", description="The figure against its limit")
    over: bpy.props.BoolProperty(name="Past Its Limit", description="The figure is past its limit: look at it")
    frame: bpy.props.FloatProperty(name="Frame", default=math.nan,
                                   description="The scene frame to look at (none: not a figure of one frame)")


class BODYCAL_OT_jump_to_flag(bpy.types.Operator):
    """Jump the timeline to the frame of this review figure (the worst contact gap, the lowest foot skin, ...)"""

    bl_idname = "bodycal.jump_to_flag"
    bl_label = "Jump to Frame"
    bl_options = {"REGISTER"}

    frame: bpy.props.FloatProperty(name="Frame", description="The scene frame to jump to")

    @classmethod
    def poll(cls, context):
        if context.scene is None:
            cls.poll_message_set("Needs a scene")
            return False
        return True

    def execute(self, context):
        if not math.isfinite(self.frame):
            self.report({"WARNING"}, "This figure has no frame to jump to")
            return {"CANCELLED"}
        whole = math.floor(self.frame)
        context.scene.frame_set(int(whole), subframe=self.frame - whole)
        return {"FINISHED"}


def store_flags(flags, summaries, armatures) -> None:
    """The reviews of the last bake (`Summary.review`, one per armature) into the settings' `flags`
    collection, worst first within each avatar."""
    flags.clear()
    for summary, arm in zip(summaries, armatures):
        review = getattr(summary, "review", None)
        for flag in review.flags if review is not None else ():
            item = flags.add()
            item.armature, item.text, item.over = arm.name, flag.text, flag.over
            item.frame = math.nan if flag.frame is None else float(flag.frame)


CLASSES = (BODYCAL_PG_review_flag, BODYCAL_OT_jump_to_flag)
