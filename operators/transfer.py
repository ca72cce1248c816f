"""Transfer Animation (issue 16): another character's action onto the avatar(s), keeping
self-contacts, with the same modal bake as Retarget and Bake (progress, Esc cancels).

The source is read into numpy on the main thread (its F-Curves, its body model); the transfer
runs in a worker thread (it never touches bpy); the bake runs on the main thread once every
target's arrays are ready. From scripts and in background mode `execute` runs the same steps."""


import bpy

from ..bodycal_addon.blender import transfer_scene
from ..bodycal_addon.blender.retarget_scene import avatar_model_for
from ..bodycal_addon.core.errors import BodyCalError
from ..bodycal_addon.retarget.placement import avatar_warnings
from .background_work import BackgroundWork
from .bake_settings import BakeSettings, can_bake_in
from .reporting import reports_errors
from .retarget import METHOD_ITEMS

TRANSFER_METHOD_ITEMS = [m for m in METHOD_ITEMS if m[0] in ("egocentric", "rotations")]
PLACEMENT_ITEMS = [  # retarget/placement.py, the source's motion relative to its own armature object
    ("object", "Avatar's Spot", "The motion plays relative to the avatar: the source's place and heading land on "
     "the armature's origin and the way the avatar faces"),
    ("performer", "Source's Spot", "The avatar plays where the source is in the world, on its own floor"),
]


def _is_armature(_self, obj):
    return obj.type == "ARMATURE"


class BODYCAL_PG_transfer_settings(BakeSettings, bpy.types.PropertyGroup):
    source: bpy.props.PointerProperty(name="Source", type=bpy.types.Object, poll=_is_armature,
                                      description="The animated character whose action is transferred")
    action: bpy.props.PointerProperty(name="Action", type=bpy.types.Action,
                                      description="The source's action (default: its active one)")
    armature: bpy.props.PointerProperty(
        name="Target", type=bpy.types.Object, poll=_is_armature,
        description="Armature to animate (default: the selected armatures other than the source)")
    method: bpy.props.EnumProperty(name="Method", items=TRANSFER_METHOD_ITEMS, default="egocentric")
    placement: bpy.props.EnumProperty(name="Placement", items=PLACEMENT_ITEMS, default="object")
    plant_feet: bpy.props.BoolProperty(name="Plant Feet", default=True,
                                       description="Hold each foot still and on the floor while the source stands "
                                                   "on it")
    output_fps: bpy.props.IntProperty(name="Frame Rate", default=0, min=0, max=1000,
                                      description="Frame rate of the baked action, timing kept (0: the source's "
                                                  "rate); the scene is set to it")


def _targets(context) -> list:
    st = context.scene.bodycal_transfer
    if st.armature is not None:
        return [st.armature]
    active = context.active_object
    chosen = ([active] if active is not None and active.type == "ARMATURE" else []) + [
        o for o in context.selected_objects if o.type == "ARMATURE" and o != active]
    return [o for o in chosen if o != st.source]


class BODYCAL_OT_transfer_animation(BackgroundWork, bpy.types.Operator):
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
        if not _targets(context):
            cls.poll_message_set("Pick a target armature (or select armatures other than the source)")
            return False
        return True

    def _inputs(self, context):
        st = context.scene.bodycal_transfer
        source = transfer_scene.read_source(st.source, st.action)
        targets = []
        for arm in _targets(context):
            model, fresh = avatar_model_for(arm)
            for line in avatar_warnings(model):
                self.report({"WARNING"}, line)
            targets.append((arm, model, fresh))
        for note in source.notes:
            self.report({"INFO"}, note)
        return source, targets

    def _compute(self, context, source, targets, progress=None, cancel=None):
        st = context.scene.bodycal_transfer
        n = len(targets)
        return [transfer_scene.compute(source, model, st.method, plant_feet=st.plant_feet, placement=st.placement,
                                       progress=None if progress is None else (lambda f, k=k: progress((k + f) / n)),
                                       cancel=cancel)
                for k, (_arm, model, _fresh) in enumerate(targets)]

    def _finish(self, context, source, targets, anims):
        st = context.scene.bodycal_transfer
        options = st.bake_options(context, float(st.output_fps) if st.output_fps else None)
        lines = [transfer_scene.bake_transfer(source, anim, arm, options=options, replace=st.replace,
                                              push_to_nla=st.push_to_nla, set_scene_rate=True,
                                              avatar=model if fresh else None).line()
                 for (arm, model, fresh), anim in zip(targets, anims)]
        st.last_result = "; ".join(lines)
        for line in lines:
            self.report({"INFO"}, line)
        return {"FINISHED"}

    @reports_errors
    def execute(self, context):
        source, targets = self._inputs(context)
        return self._finish(context, source, targets, self._compute(context, source, targets))

    @reports_errors
    def invoke(self, context, _event):
        self._source, self._targets = self._inputs(context)
        if not self._targets:
            raise BodyCalError("no target armature")
        return self._start(context, lambda progress, cancel: self._compute(context, self._source, self._targets,
                                                                            progress=progress, cancel=cancel))

    def _done(self, context, anims):
        return self._finish(context, self._source, self._targets, anims)


CLASSES = (BODYCAL_PG_transfer_settings, BODYCAL_OT_transfer_animation)


def register_properties():
    bpy.types.Scene.bodycal_transfer = bpy.props.PointerProperty(type=BODYCAL_PG_transfer_settings)


def unregister_properties():
    del bpy.types.Scene.bodycal_transfer
