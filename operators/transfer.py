"""Transfer Animation: another character's action onto the avatar(s), keeping self-contacts, as
the take of the shared bake (operators/bake_settings.BakeOperator: progress, Esc cancels). The
source is read into numpy on the main thread (its F-Curves, its body model)."""

import bpy

from ..bodycal_addon.blender import session
from ..bodycal_addon.blender.fcurves import action_bones
from .bake_settings import BakeOperator, can_bake_in, method_items, selected_armatures
from .preferences import method_property
from .review import BODYCAL_PG_review_flag


def _is_armature(_self, obj):
    return obj.type == "ARMATURE"


def _animates_source(self, action) -> bool:
    """The action picker lists the actions that animate the source's bones (all, before a source)."""
    if self.source is None or self.source.type != "ARMATURE":
        return True
    return not action_bones(action).isdisjoint(self.source.pose.bones.keys())


class BODYCAL_PG_transfer_settings(bpy.types.PropertyGroup):
    """What only a transfer has (the shared bake settings: scene.bodycal_bake)."""

    source: bpy.props.PointerProperty(name="Source", type=bpy.types.Object, poll=_is_armature,
                                      description="The animated character whose action is transferred")
    action: bpy.props.PointerProperty(name="Action", type=bpy.types.Action, poll=_animates_source,
                                      description="The source's action (default: its active one); "
                                                  "only actions that animate the source's bones are listed")
    method: method_property(method_items(session.ANIMATION), "Method",
                            "How the source character's motion drives the avatar")
    use_filter: bpy.props.BoolProperty(
        name="Smooth Source", default=False,
        description="One Euro filter on the source's pose before transferring (its action is not changed)")
    last_result: bpy.props.StringProperty(name="Last Result", default="", options={"SKIP_SAVE"},
                                          description="The last transfer's figures, per avatar")
    review_flags: bpy.props.CollectionProperty(type=BODYCAL_PG_review_flag, name="Review",
                                               description="The last bake\'s review: its figures against their limits")


class BODYCAL_OT_transfer_animation(BakeOperator, bpy.types.Operator):
    """Transfer the source character's action onto the target avatar(s), keeping its self-contacts, and
bake a new action on each"""

    _doing, _cancelled = "transferring", "Transfer cancelled"
    bl_idname = "bodycal.transfer_animation"
    bl_label = "Transfer and Bake"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        if not can_bake_in(cls, context):
            return False
        st = context.scene.bodycal_transfer
        if st.source is None:
            cls.poll_message_set("Pick the animated source armature in the Transfer Animation panel")
            return False
        if st.action is None and (st.source.animation_data is None or st.source.animation_data.action is None):
            cls.poll_message_set("The source has no active action: pick one")
            return False
        if not selected_armatures(context, exclude=st.source):
            cls.poll_message_set("Pick a target armature (or select armatures other than the source)")
            return False
        return True

    def _read_take(self, context) -> session.CharacterTake:
        st = self._own_settings(context)
        return session.source_take(st.source, st.action, smooth=st.use_filter)

    def _armatures(self, context) -> list:
        return selected_armatures(context, exclude=self._own_settings(context).source)

    def _method(self, context) -> str:
        return self._own_settings(context).method

    def _own_settings(self, context):
        return context.scene.bodycal_transfer


CLASSES = (BODYCAL_PG_transfer_settings, BODYCAL_OT_transfer_animation)


def register_properties():
    bpy.types.Scene.bodycal_transfer = bpy.props.PointerProperty(
        type=BODYCAL_PG_transfer_settings, description="BodyCal: what only Transfer Animation has")


def unregister_properties():
    del bpy.types.Scene.bodycal_transfer
