"""Transfer Animation (issue 16): another character's action onto the avatar(s), keeping
self-contacts, with the same modal bake as Retarget and Bake (progress, Esc cancels).

The source is read into numpy on the main thread (its F-Curves, its body model); the transfer
runs in a worker thread (it never touches bpy); the bake runs on the main thread once every
target's arrays are ready. From scripts and in background mode `execute` runs the same steps."""

import math
import threading

import bpy

from ..bodycal_addon.blender import transfer_scene
from ..bodycal_addon.blender.bake import BakeOptions
from ..bodycal_addon.blender.retarget_scene import avatar_model_for
from ..bodycal_addon.errors import BodyCalError, Cancelled
from ..bodycal_addon.keyreduce import DEFAULT_LOCATION_TOLERANCE_MM, DEFAULT_TOLERANCE_DEG
from ..bodycal_addon.retarget.placement import avatar_warnings
from .reporting import reports_errors
from .retarget import METHOD_ITEMS, RIGIFY_TARGET_ITEMS, ROOT_MOTION_ITEMS

TRANSFER_METHOD_ITEMS = [m for m in METHOD_ITEMS if m[0] in ("egocentric", "rotations")]
PLACEMENT_ITEMS = [  # retarget/placement.py, the source's motion relative to its own armature object
    ("object", "Avatar's Spot", "The motion plays relative to the avatar: the source's place and heading land on "
     "the armature's origin and the way the avatar faces"),
    ("performer", "Source's Spot", "The avatar plays where the source is in the world, on its own floor"),
]


def _is_armature(_self, obj):
    return obj.type == "ARMATURE"


class BODYCAL_PG_transfer_settings(bpy.types.PropertyGroup):
    source: bpy.props.PointerProperty(name="Source", type=bpy.types.Object, poll=_is_armature,
                                      description="The animated character whose action is transferred")
    action: bpy.props.PointerProperty(name="Action", type=bpy.types.Action,
                                      description="The source's action (default: its active one)")
    armature: bpy.props.PointerProperty(
        name="Target", type=bpy.types.Object, poll=_is_armature,
        description="Armature to animate (default: the selected armatures other than the source)")
    method: bpy.props.EnumProperty(name="Method", items=TRANSFER_METHOD_ITEMS, default="egocentric")
    placement: bpy.props.EnumProperty(name="Placement", items=PLACEMENT_ITEMS, default="object")
    root_motion: bpy.props.EnumProperty(name="Root Motion", items=ROOT_MOTION_ITEMS, default="root")
    rigify_target: bpy.props.EnumProperty(name="Rigify Target", items=RIGIFY_TARGET_ITEMS, default="fk")
    plant_feet: bpy.props.BoolProperty(name="Plant Feet", default=True,
                                       description="Hold each foot still and on the floor while the source stands "
                                                   "on it")
    replace: bpy.props.BoolProperty(name="Replace Action", default=False,
                                    description="Overwrite an existing action of the same name")
    push_to_nla: bpy.props.BoolProperty(name="Push to NLA", default=False,
                                        description="Put the baked action on a new NLA track")
    tolerance: bpy.props.FloatProperty(
        name="Key Tolerance", default=math.radians(DEFAULT_TOLERANCE_DEG), min=0.0, soft_max=math.radians(2.0),
        precision=3, subtype="ANGLE",
        description="Key reduction: every bone's rotation stays within this angle of the every-frame bake")
    location_tolerance: bpy.props.FloatProperty(
        name="Location Tolerance", default=DEFAULT_LOCATION_TOLERANCE_MM / 1000.0, min=0.0, soft_max=0.01,
        precision=4, subtype="DISTANCE", unit="LENGTH",
        description="Key reduction of the root bone's location")
    output_fps: bpy.props.IntProperty(name="Frame Rate", default=0, min=0, max=1000,
                                      description="Frame rate of the baked action (0: the scene's rate)")
    last_result: bpy.props.StringProperty(name="Last Result", default="", options={"SKIP_SAVE"})


def _targets(context) -> list:
    st = context.scene.bodycal_transfer
    if st.armature is not None:
        return [st.armature]
    active = context.active_object
    chosen = ([active] if active is not None and active.type == "ARMATURE" else []) + [
        o for o in context.selected_objects if o.type == "ARMATURE" and o != active]
    return [o for o in chosen if o != st.source]


class BODYCAL_OT_transfer_animation(bpy.types.Operator):
    """Transfer the source character's action onto the target avatar(s), keeping its self-contacts, and
bake a new action on each"""

    bl_idname = "bodycal.transfer_animation"
    bl_label = "Transfer and Bake"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        if context.mode not in {"OBJECT", "POSE"}:
            cls.poll_message_set("Switch to Object or Pose Mode to bake")
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
        options = BakeOptions(math.degrees(st.tolerance),
                              st.location_tolerance * 1000.0 * context.scene.unit_settings.scale_length,
                              float(st.output_fps) if st.output_fps else None, st.root_motion, st.rigify_target)
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
        self._progress = 0.0
        self._cancel = threading.Event()
        self._result = {}

        def work():
            try:
                self._result["anims"] = self._compute(context, self._source, self._targets,
                                                      progress=lambda f: setattr(self, "_progress", f),
                                                      cancel=self._cancel.is_set)
            except BaseException as exc:  # reported on the main thread
                self._result["error"] = exc

        self._thread = threading.Thread(target=work, name="bodycal-transfer", daemon=True)
        self._thread.start()
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.1, window=context.window)
        wm.progress_begin(0, 100)
        wm.modal_handler_add(self)
        context.workspace.status_text_set("BodyCal: transferring... (Esc to cancel)")
        return {"RUNNING_MODAL"}

    def _cleanup(self, context):
        wm = context.window_manager
        wm.event_timer_remove(self._timer)
        wm.progress_end()
        context.workspace.status_text_set(None)

    @reports_errors
    def modal(self, context, event):
        if event.type == "ESC":
            self._cancel.set()
        if event.type != "TIMER":
            return {"RUNNING_MODAL"}
        context.window_manager.progress_update(int(100 * self._progress))
        if self._thread.is_alive():
            return {"RUNNING_MODAL"}
        self._cleanup(context)
        error = self._result.get("error")
        if isinstance(error, Cancelled):
            self.report({"WARNING"}, "Transfer cancelled: nothing was written")
            return {"CANCELLED"}
        if error is not None:
            raise error
        return self._finish(context, self._source, self._targets, self._result["anims"])


CLASSES = (BODYCAL_PG_transfer_settings, BODYCAL_OT_transfer_animation)


def register_properties():
    bpy.types.Scene.bodycal_transfer = bpy.props.PointerProperty(type=BODYCAL_PG_transfer_settings)


def unregister_properties():
    del bpy.types.Scene.bodycal_transfer
