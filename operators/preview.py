"""Preview: the avatar(s) follow the scene's recording (or a transfer's source action) as the
timeline plays or is scrubbed, with the Retarget and Bake (or Transfer) settings, before anything
is baked (bodycal_addon/blender/preview.py)."""

import bpy

from ..bodycal_addon.blender import (
    BodyCalError,
    avatar_rig,
    avatar_storage,
    calibration_scene,
    preview,
    recording_scene,
    session,
)
from ..bodycal_addon.blender.character_source import read_source
from .bake_settings import can_bake_in, selected_armatures
from .reporting import reports_errors

KINDS = [("recording", "Recording", "The scene's recording, with the Retarget and Bake settings"),
         ("transfer", "Transfer", "The source character's action, with the Transfer Animation settings")]


def settings_key(scene, arm, kind: str) -> tuple:
    """Everything a preview is made from: when any of it changes, the preview is made again."""
    bake = scene.bodycal_bake
    try:
        window = bake.window(bpy.context)
    except BodyCalError:  # a range that ends before it starts: the bake says so; the preview keeps the take
        window = None
    common = (kind, bake.plant_feet, bake.placement, bake.root_motion, window,
              hash(str(arm.get(avatar_storage.MODEL_PROP))), str(arm.get(avatar_rig.BONE_MAP_PROP, "")))
    if kind == "transfer":
        st = scene.bodycal_transfer
        source = st.source
        action = st.action or (source.animation_data.action if source and source.animation_data else None)
        return (*common, st.method, getattr(source, "name", None), getattr(action, "name", None),
                hash(str(source.get(avatar_storage.MODEL_PROP))) if source else None)
    settings = scene.bodycal_retarget
    euro = settings.one_euro()
    coll = recording_scene.scene_recording_collection(scene)
    return (*common, settings.method,
            None if euro is None else (euro.min_cutoff, euro.beta, euro.rot_min_cutoff, euro.rot_beta),
            getattr(coll, "name", None), hash(str(coll.get(recording_scene.META_KEY))) if coll else None,
            hash(str(scene.get(calibration_scene.MODEL_PROP))))


def start_preview(scene, arm, kind: str) -> preview.Preview:
    """Read the take (the bake's frame range of it) and the armature's avatar model, and start."""
    if kind == "transfer":
        st = scene.bodycal_transfer
        take, method = read_source(st.source, st.action), st.method
    else:
        take, method = scene.bodycal_retarget.scene_take(scene), scene.bodycal_retarget.method
    window = scene.bodycal_bake.window(bpy.context)
    if window is not None:
        take = take.window(*window)
    old = preview.active(arm)
    key = settings_key(scene, arm, kind)
    # The avatar model is measured once (a mesh's raycasts take seconds), not stored: a preview
    # leaves the file as it was.
    target = old.target if old is not None and old.key[5:7] == key[5:7] else session.prepare_target(arm)
    return preview.start(arm, take, target, scene.bodycal_bake.session_settings(method),
                         scene.bodycal_bake.root_motion, key)


def _key_now(scene, arm, key):
    return settings_key(scene, arm, key[0])


def _rebuild(scene, arm, key) -> None:
    start_preview(scene, arm, key[0])


class BODYCAL_OT_preview_retarget(bpy.types.Operator):
    """Show the take on the avatar as you play or scrub the timeline, before baking (click again to stop)"""

    bl_idname = "bodycal.preview_retarget"
    bl_label = "Preview"
    bl_options = {"REGISTER"}  # a preview is put back when it stops: nothing to undo

    take: bpy.props.EnumProperty(name="Take", items=KINDS, default="recording",
                                 description="What the avatars follow")

    @classmethod
    def poll(cls, context):
        if not can_bake_in(cls, context):
            return False
        if preview.any_active():
            return True  # it can always be stopped
        if not selected_armatures(context):
            cls.poll_message_set("Pick an avatar armature in the BodyCal tab (or select armatures)")
            return False
        return True

    def _armatures(self, context) -> list:
        return selected_armatures(context, exclude=context.scene.bodycal_transfer.source
                                  if self.take == "transfer" else None)

    def _missing(self, context) -> str | None:
        if self.take == "recording":
            return session.scene_take_missing(context.scene)
        st = context.scene.bodycal_transfer
        if st.source is None:
            return "Pick the animated source armature in the Transfer Animation panel"
        if st.action is None and (st.source.animation_data is None or st.source.animation_data.action is None):
            return "The source has no active action: pick one"
        if not self._armatures(context):
            return "Pick a target armature (or select armatures other than the source)"
        return None

    @reports_errors
    def execute(self, context):
        if preview.any_active():
            preview.stop_all()
            self.report({"INFO"}, "Preview stopped: the avatars' poses are as they were")
            return {"FINISHED"}
        problem = self._missing(context)
        if problem:
            raise BodyCalError(problem)
        shown = [start_preview(context.scene, arm, self.take) for arm in self._armatures(context)]
        ms = max(pv.solve_ms for pv in shown)
        self.report({"INFO"}, f"Previewing on {', '.join(pv.armature for pv in shown)} ({ms:.0f} ms a frame): "
                              "play or scrub the timeline; Bake writes the action")
        return {"FINISHED"}


CLASSES = (BODYCAL_OT_preview_retarget,)


def register_handlers():
    preview.follow(_key_now, _rebuild)
    preview.register_handlers()


def unregister_handlers():
    preview.unregister_handlers()
    preview.follow(None, None)
