"""What Retarget and Bake and Transfer Animation share, declared once: the settings group
`scene.bodycal_bake` (the avatar to animate, where the performance plays, feet, root motion, the
Rigify target, key reduction and frame rate) and the operator mixin `BakeOperator`, which runs
any take through the one session path (`bodycal_addon/blender/session.py`): read the take and
the targets on the main thread, compute in a worker thread (progress, Esc cancels), bake on the
main thread once every target is computed."""

import math

import bpy

from ..bodycal_addon.blender import BodyCalError, preview, session
from ..bodycal_addon.blender.bake import BakeOptions
from .background_work import BackgroundWork
from .reporting import reports_errors
from .review import store_flags

PLACEMENT_ITEMS = [  # retarget/placement.py
    ("object", "Avatar's Spot", "The performance plays relative to the avatar: the performer's (or source "
     "character's) place and heading land on the armature's origin and the way the avatar faces"),
    ("performer", "Performer's Spot", "The avatar plays where the performer (or the source character) was, on "
     "its own floor"),
]
ROOT_MOTION_ITEMS = [  # output/root_motion.py
    ("root", "Root Bone", "The travel and heading on the rig's root bone when it has one above the pelvis "
     "(game engines' root motion); else on the pelvis"),
    ("pelvis", "Pelvis", "The travel on the pelvis; the root bone stays at rest"),
    ("in-place", "In Place", "No horizontal travel: the character stays on its spot"),
]
RIGIFY_TARGET_ITEMS = [  # output/rigify.py
    ("fk", "FK Controls", "A generated Rigify rig is keyed on its FK controls (IK switched to FK): ready to edit"),
    ("def", "DEF Bones", "A generated Rigify rig is keyed on its deforming DEF- bones: for export"),
]


INTERPOLATION_ITEMS = [  # output/keyreduce.py INTERPOLATIONS
    ("linear", "Linear", "Linear keys: straight between the kept keys"),
    ("bezier", "Bézier", "Bézier keys with Auto Clamped handles, smooth to edit; keys are added where the curve "
     "would stray beyond the tolerance"),
]
FRAME_RANGE_ITEMS = [
    ("scene", "Scene Range", "The frames the timeline plays: the scene's frame range, or its preview range when "
     "that is on"),
    ("take", "Whole Take", "Every frame of the recording or the source action"),
    ("custom", "Custom", "The frames typed below"),
]


def method_items(source_kind: str) -> list[tuple[str, str, str]]:
    """The sidebar's method menu for a kind of take, from the one registry (retarget/methods.py)."""
    return session.method_choices(source_kind)


def _is_armature(_self, obj):
    return obj.type == "ARMATURE"


class BODYCAL_PG_bake_settings(bpy.types.PropertyGroup):
    armature: bpy.props.PointerProperty(
        name="Avatar", type=bpy.types.Object, poll=_is_armature,
        description="Armature to animate (default: the selected armatures)")
    placement: bpy.props.EnumProperty(name="Placement", items=PLACEMENT_ITEMS, default="object",
                                      description="Where the performance plays")
    plant_feet: bpy.props.BoolProperty(
        name="Plant Feet", default=True,
        description="Hold each foot still and on the floor while the performer stands on it (every method)")
    root_motion: bpy.props.EnumProperty(name="Root Motion", items=ROOT_MOTION_ITEMS, default="root",
                                        description="Which bone carries the travel and heading")
    rigify_target: bpy.props.EnumProperty(name="Rigify Target", items=RIGIFY_TARGET_ITEMS, default="fk",
                                          description="Which bones of a generated Rigify rig get the keys")
    replace: bpy.props.BoolProperty(
        name="Replace Action", default=False,
        description="Overwrite an existing action of the same name instead of creating a new one")
    push_to_nla: bpy.props.BoolProperty(name="Push to NLA", default=False,
                                        description="Put the baked action on a new NLA track")
    output_fps: bpy.props.IntProperty(
        name="Frame Rate", default=0, min=0, max=1000,
        description="Frame rate of the baked action, timing kept (0: the scene's rate; another rate also "
                    "becomes the scene's)")
    tolerance: bpy.props.FloatProperty(
        name="Key Tolerance", default=math.radians(session.DEFAULT_TOLERANCE_DEG), min=0.0, soft_max=math.radians(2.0),
        precision=3, subtype="ANGLE",
        description="Key reduction: every bone's rotation stays within this angle of the every-frame bake "
                    "(linear keys); 0 keys every frame")
    interpolation: bpy.props.EnumProperty(
        name="Keys", items=INTERPOLATION_ITEMS, default="linear",
        description="Interpolation of the baked keys; either way every frame stays within the tolerances")
    frame_range: bpy.props.EnumProperty(
        name="Frame Range", items=FRAME_RANGE_ITEMS, default="scene",
        description="Which frames are baked; keys land on the frames the recording was imported at (a "
                    "transfer: the source action's own frames)")
    frame_first: bpy.props.IntProperty(name="First", default=1, description="First frame baked (Custom range)")
    frame_last: bpy.props.IntProperty(name="Last", default=250, description="Last frame baked (Custom range)")
    set_scene_range: bpy.props.BoolProperty(
        name="Set Scene Range", default=False,
        description="Make the scene's frame range the baked action's (otherwise it is left as it is)")
    location_tolerance: bpy.props.FloatProperty(
        name="Location Tolerance", default=session.DEFAULT_LOCATION_TOLERANCE_MM / 1000.0, min=0.0, soft_max=0.01,
        precision=4, subtype="DISTANCE", unit="LENGTH",
        description="Key reduction of the root bone's location: stays within this distance of the every-frame bake")

    def bake_options(self, context) -> BakeOptions:
        """The settings as the bake takes them: degrees, world millimetres whatever the scene's
        unit scale, and the output rate (the scene's when 0)."""
        render = context.scene.render
        fps = float(self.output_fps) if self.output_fps else render.fps / render.fps_base
        return BakeOptions(math.degrees(self.tolerance),
                           self.location_tolerance * 1000.0 * context.scene.unit_settings.scale_length, fps,
                           self.root_motion, self.rigify_target, self.interpolation)

    def window(self, context) -> tuple[int, int] | None:
        """The frames to bake, (first, last); None: the whole take."""
        scene = context.scene
        if self.frame_range == "take":
            return None
        if self.frame_range == "custom":
            first, last = self.frame_first, self.frame_last
        elif scene.use_preview_range:
            first, last = scene.frame_preview_start, scene.frame_preview_end
        else:
            first, last = scene.frame_start, scene.frame_end
        if last < first:
            raise BodyCalError(f"the frame range {first}-{last} ends before it starts", field="Frame Range",
                               hint="set the last frame at or after the first")
        return first, last

    def session_settings(self, method: str) -> session.Settings:
        return session.Settings(method, self.plant_feet, self.placement)


def can_bake_in(cls, context) -> bool:
    """A bake operator's first poll check: the mode the bake writes in (its poll message says so)."""
    if context.mode not in {"OBJECT", "POSE"}:
        cls.poll_message_set("Switch to Object or Pose Mode to bake")
        return False
    return True


def selected_armatures(context, exclude=None) -> list:
    """The avatar picked in the bake settings, else every selected armature (the active one first)
    but `exclude` (a transfer's source)."""
    picked = context.scene.bodycal_bake.armature
    if picked is not None:
        return [picked]
    active = context.active_object
    chosen = ([active] if active is not None and active.type == "ARMATURE" else []) + [
        o for o in context.selected_objects if o.type == "ARMATURE" and o != active]
    return [o for o in chosen if o != exclude]


class BakeOperator(BackgroundWork):
    """Mixin for an operator that bakes a take onto armatures. The operator says where its take
    comes from (`_read_take(context)`), which armatures it animates (`_armatures(context)`), the
    method (`_method(context)`) and its own settings group (`_own_settings(context)`, which keeps
    `last_result`); this mixin does the rest the same way for every kind of take. From scripts and
    in background mode `execute` runs the same steps synchronously."""

    def _read_take(self, context):
        raise NotImplementedError

    def _armatures(self, context) -> list:
        raise NotImplementedError

    def _method(self, context) -> str:
        raise NotImplementedError

    def _own_settings(self, context):
        raise NotImplementedError

    def _prepare(self, context):
        """The take, the targets and the settings, read on the main thread (the worker touches no
        Blender data); what the take and targets say is reported first, like the command line,
        before the (long) work."""
        take = self._read_take(context)
        window = context.scene.bodycal_bake.window(context)
        if window is not None:
            take = take.window(*window)
        armatures = self._armatures(context)
        for arm in armatures:  # its pose put back first: the bake starts from the armature as it was
            preview.stop(arm.name)
        targets = [session.prepare_target(arm) for arm in armatures]
        for target in targets:
            for line in target.warnings:
                self.report({"WARNING"}, line)
        for note in take.notes:
            self.report({"INFO"}, note)
        return take, targets, context.scene.bodycal_bake.session_settings(self._method(context))

    @staticmethod
    def _compute(take, targets, settings, progress=None, cancel=None) -> list:
        n = len(targets)
        return [session.compute(take, target, settings, cancel=cancel,
                                progress=None if progress is None else (lambda f, k=k: progress((k + f) / n)))
                for k, target in enumerate(targets)]

    def _finish(self, context, take, targets, computed):
        """Bake every target: only once all of them were computed."""
        bake = context.scene.bodycal_bake
        summaries = [session.bake(take, target, result, options=bake.bake_options(context), replace=bake.replace,
                                  push_to_nla=bake.push_to_nla, set_scene_rate=bool(bake.output_fps),
                                  set_scene_range=bake.set_scene_range, review=True)
                     for target, result in zip(targets, computed)]
        own = self._own_settings(context)
        own.last_result = "; ".join(s.line() for s in summaries)
        store_flags(own.review_flags, summaries, [t.armature for t in targets])
        for summary in summaries:
            for line in summary.report_lines():
                self.report({"INFO"}, line)
        return {"FINISHED"}

    @reports_errors
    def execute(self, context):
        take, targets, settings = self._prepare(context)
        return self._finish(context, take, targets, self._compute(take, targets, settings))

    @reports_errors
    def invoke(self, context, _event):
        take, targets, settings = self._prepared = self._prepare(context)
        return self._start(context, lambda progress, cancel: self._compute(take, targets, settings,
                                                                            progress=progress, cancel=cancel))

    def _done(self, context, computed):
        take, targets, _settings = self._prepared
        return self._finish(context, take, targets, computed)


CLASSES = (BODYCAL_PG_bake_settings,)


def register_properties():
    bpy.types.Scene.bodycal_bake = bpy.props.PointerProperty(
        type=BODYCAL_PG_bake_settings, description="BodyCal: the bake settings Retarget and Transfer share")


def unregister_properties():
    del bpy.types.Scene.bodycal_bake
