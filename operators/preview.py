"""Preview: the avatar(s) follow the scene's recording as the timeline plays or is scrubbed, with
the Retarget and Bake settings, before anything is baked (bodycal_addon/blender/preview.py)."""

import bpy

from ..bodycal_addon.blender import avatar_rig, avatar_storage, calibration_scene, preview, recording_scene, session
from ..bodycal_addon.core.errors import BodyCalError
from .bake_settings import can_bake_in, selected_armatures
from .reporting import reports_errors


def settings_key(scene, arm) -> tuple:
    """Everything a preview is made from: when any of it changes, the preview is made again."""
    settings, bake = scene.bodycal_retarget, scene.bodycal_bake
    euro = settings.one_euro()
    coll = recording_scene.scene_recording_collection(scene)
    try:
        window = bake.window(bpy.context)
    except BodyCalError:  # a range that ends before it starts: the bake says so; the preview keeps the take
        window = None
    return (settings.method, bake.plant_feet, bake.placement, bake.root_motion, window,
            None if euro is None else (euro.min_cutoff, euro.beta, euro.rot_min_cutoff, euro.rot_beta),
            getattr(coll, "name", None), hash(str(coll.get(recording_scene.META_KEY))) if coll else None,
            hash(str(scene.get(calibration_scene.MODEL_PROP))), hash(str(arm.get(avatar_storage.MODEL_PROP))),
            str(arm.get(avatar_rig.BONE_MAP_PROP, "")))


def start_preview(scene, arm) -> preview.Preview:
    """Read the scene's take (the bake's frame range) and the armature's avatar model, and start."""
    context = bpy.context
    take = session.scene_take(scene, scene.bodycal_retarget.one_euro())
    window = scene.bodycal_bake.window(context)
    if window is not None:
        take = take.window(*window)
    old = preview.active(arm)
    key = settings_key(scene, arm)
    # The avatar model is measured once (a mesh's raycasts take seconds), not stored: a preview
    # leaves the file as it was.
    target = old.target if old is not None and old.key[-2:] == key[-2:] else session.prepare_target(arm)
    return preview.start(arm, take, target, scene.bodycal_bake.session_settings(scene.bodycal_retarget.method),
                         scene.bodycal_bake.root_motion, key)


def _rebuild(scene, arm) -> None:
    start_preview(scene, arm)


class BODYCAL_OT_preview_retarget(bpy.types.Operator):
    """Show the recording on the avatar as you play or scrub the timeline, before baking (click again to stop)"""

    bl_idname = "bodycal.preview_retarget"
    bl_label = "Preview"
    bl_options = {"REGISTER"}  # a preview is put back when it stops: nothing to undo

    @classmethod
    def poll(cls, context):
        if not can_bake_in(cls, context):
            return False
        if preview.any_active():
            return True  # it can always be stopped
        if not selected_armatures(context):
            cls.poll_message_set("Pick an avatar armature in the BodyCal tab (or select armatures)")
            return False
        problem = session.scene_take_missing(context.scene)
        if problem:
            cls.poll_message_set(problem)
            return False
        return True

    @reports_errors
    def execute(self, context):
        if preview.any_active():
            preview.stop_all()
            self.report({"INFO"}, "Preview stopped: the avatars' poses are as they were")
            return {"FINISHED"}
        shown = [start_preview(context.scene, arm) for arm in selected_armatures(context)]
        ms = max(pv.solve_ms for pv in shown)
        self.report({"INFO"}, f"Previewing on {', '.join(pv.armature for pv in shown)} ({ms:.0f} ms a frame): "
                              "play or scrub the timeline; Bake writes the action")
        return {"FINISHED"}


CLASSES = (BODYCAL_OT_preview_retarget,)


def register_handlers():
    preview.follow(settings_key, _rebuild)
    preview.register_handlers()


def unregister_handlers():
    preview.unregister_handlers()
    preview.follow(None, None)
