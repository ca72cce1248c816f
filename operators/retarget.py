"""Retarget and bake: the last step of the sidebar flow.

The numpy pipeline runs in a worker thread (it never touches bpy) while a modal timer shows
progress and listens for Esc; the bake (the only scene write) runs on the main thread once the
arrays are ready. From scripts and in background mode `execute` runs the same steps synchronously.
"""

from pathlib import Path

import bpy
from bpy_extras.io_utils import ExportHelper

from ..bodycal_addon.blender import retarget_scene
from ..bodycal_addon.blender.export import EXPORT_SUFFIXES, export_avatar
from ..bodycal_addon.recording.filters import OneEuro
from .background_work import BackgroundWork
from .bake_settings import BakeSettings, can_bake_in
from .reporting import reports_errors

METHOD_ITEMS = [
    ("egocentric", "Egocentric", "Keep self-contacts: egocentric mapping onto the avatar's surface + IK"),
    ("offsets", "Exact Offsets", "AvatarGo: exact tracker-to-joint offsets from the T-pose + IK"),
    ("rotations", "Rotation Copy", "Copy the performer's bone rotations (the usual retargeting baseline)"),
]
PLACEMENT_ITEMS = [  # retarget/placement.py
    ("object", "Avatar's Spot", "The performance plays relative to the avatar: the performer's play-area origin "
     "and forward land on the armature's origin and the way the avatar faces"),
    ("performer", "Performer's Spot", "The avatar plays where the performer was in the room (with the imported "
     "devices), on its own floor"),
]

class BODYCAL_PG_retarget_settings(BakeSettings, bpy.types.PropertyGroup):
    method: bpy.props.EnumProperty(name="Method", items=METHOD_ITEMS, default="egocentric")
    armature: bpy.props.PointerProperty(
        name="Avatar", type=bpy.types.Object, poll=lambda _self, obj: obj.type == "ARMATURE",
        description="Armature to animate (default: the selected armatures)")
    placement: bpy.props.EnumProperty(name="Placement", items=PLACEMENT_ITEMS, default="object")
    plant_feet: bpy.props.BoolProperty(
        name="Plant Feet", default=True,
        description="Hold each foot still and on the floor while the performer stands on it (every method)")
    use_filter: bpy.props.BoolProperty(
        name="Smooth Devices", default=False,
        description="One Euro filter on the tracker poses before retargeting (the recording itself is not changed)")
    filter_min_cutoff: bpy.props.FloatProperty(
        name="Min Cutoff", default=OneEuro.min_cutoff, min=0.01, soft_max=20.0,
        description="Cutoff (Hz) of a still device's position: lower smooths more")
    filter_beta: bpy.props.FloatProperty(
        name="Beta", default=OneEuro.beta, min=0.0, soft_max=50.0,
        description="How fast the position's cutoff rises with speed (Hz per m/s): higher follows quick moves")
    filter_rot_min_cutoff: bpy.props.FloatProperty(
        name="Rotation Min Cutoff", default=OneEuro.rot_min_cutoff, min=0.01, soft_max=20.0,
        description="Cutoff (Hz) of a still device's rotation")
    filter_rot_beta: bpy.props.FloatProperty(
        name="Rotation Beta", default=OneEuro.rot_beta, min=0.0, soft_max=20.0,
        description="How fast the rotation's cutoff rises with angular speed (Hz per rad/s)")
    output_fps: bpy.props.IntProperty(
        name="Frame Rate", default=0, min=0, max=1000,
        description="Frame rate of the baked action, timing kept (0: the scene's rate; another rate also "
                    "becomes the scene's)")


def _target_armatures(context) -> list:
    """The avatar picked in the panel, else every selected armature (the active one first)."""
    settings = context.scene.bodycal_retarget
    if settings.armature is not None:
        return [settings.armature]
    active = context.active_object
    selected = [o for o in context.selected_objects if o.type == "ARMATURE" and o != active]
    return ([active] if active is not None and active.type == "ARMATURE" else []) + selected


class BODYCAL_OT_retarget_bake(BackgroundWork, bpy.types.Operator):
    """Retarget the scene's recording onto the avatar(s) with the chosen method and bake a new action
on each"""

    _doing, _cancelled = "retargeting", "Retargeting cancelled"
    bl_idname = "bodycal.retarget_bake"
    bl_label = "Retarget and Bake"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        if not can_bake_in(cls, context):
            return False
        if not _target_armatures(context):
            cls.poll_message_set("Pick an avatar armature in the BodyCal tab (or select armatures)")
            return False
        problem = retarget_scene.missing_inputs(context.scene)
        if problem:
            cls.poll_message_set(problem)
            return False
        return True

    def _inputs(self, context) -> list:
        st = context.scene.bodycal_retarget
        cfg = OneEuro(st.filter_min_cutoff, st.filter_beta, st.filter_rot_min_cutoff, st.filter_rot_beta) \
            if st.use_filter else None
        inputs = [retarget_scene.gather_inputs(context.scene, arm, st.method, filter=cfg, plant_feet=st.plant_feet,
                                               placement=st.placement) for arm in _target_armatures(context)]
        for i in inputs:  # said before the (long) work, like the command line
            for line in i.warnings:
                self.report({"WARNING"}, line)
        return inputs

    def _finish(self, context, inputs: list, anims: list):
        """Bake every avatar's animation: only once all of them were computed."""
        settings = context.scene.bodycal_retarget
        render = context.scene.render
        fps = float(settings.output_fps) if settings.output_fps else render.fps / render.fps_base
        options = settings.bake_options(context, fps)
        lines = [retarget_scene.bake_and_measure(i, a, replace=settings.replace, push_to_nla=settings.push_to_nla,
                                                 options=options, set_scene_rate=bool(settings.output_fps)
                                                 ).line() for i, a in zip(inputs, anims)]
        settings.last_result = "; ".join(lines)
        for line in lines:
            self.report({"INFO"}, line)
        return {"FINISHED"}

    @reports_errors
    def execute(self, context):
        inputs = self._inputs(context)
        anims = [retarget_scene.compute(i) for i in inputs]
        return self._finish(context, inputs, anims)

    # --- modal: compute in a worker thread, Esc cancels, bake on the main thread --------------

    @reports_errors
    def invoke(self, context, _event):
        inputs = self._inputs(context)
        self._inputs_cache = inputs
        n = len(inputs)

        def work(progress, cancel):
            return [retarget_scene.compute(i, progress=lambda f, k=k: progress((k + f) / n), cancel=cancel)
                    for k, i in enumerate(inputs)]

        return self._start(context, work)

    def _done(self, context, anims):
        return self._finish(context, self._inputs_cache, anims)


class BODYCAL_OT_export_animation(bpy.types.Operator, ExportHelper):
    """Export the active armature with its meshes and its baked action (FBX, glTF or BVH), with the
options a game engine expects"""

    bl_idname = "bodycal.export_animation"
    bl_label = "Export Baked Avatar"
    bl_options = {"REGISTER"}

    filename_ext = ".fbx"
    filter_glob: bpy.props.StringProperty(default=";".join(f"*{s}" for s in EXPORT_SUFFIXES), options={"HIDDEN"})
    file_format: bpy.props.EnumProperty(
        name="Format", default=".fbx",
        items=[(".fbx", "FBX", "Armature, meshes and the action; Y up, no leaf bones (Unity, Unreal)"),
               (".glb", "glTF Binary (.glb)", "One binary file: armature, skinned meshes and the action"),
               (".gltf", "glTF (.gltf)", "One text file with its buffers embedded"),
               (".bvh", "BVH", "The armature's motion only")],
        update=lambda self, _context: self._use_format())

    def _use_format(self):
        self.filename_ext = self.file_format
        if self.filepath:
            self.filepath = str(Path(self.filepath).with_suffix(self.file_format))

    def check(self, context):
        self.filename_ext = self.file_format
        return super().check(context)

    @classmethod
    def poll(cls, context):
        obj = context.active_object
        if obj is None or obj.type != "ARMATURE":
            cls.poll_message_set("Make an armature the active object")
            return False
        if obj.animation_data is None or obj.animation_data.action is None:
            cls.poll_message_set("The armature has no action: retarget and bake first")
            return False
        return True

    @reports_errors
    def execute(self, context):
        path = Path(self.filepath)
        if path.suffix.lower() not in EXPORT_SUFFIXES:
            path = path.with_suffix(self.file_format)
        # The file browser already asked before replacing an existing file.
        export_avatar(context.active_object, path, overwrite=True, field="file")
        self.report({"INFO"}, f"Exported {context.active_object.name} to {path}")
        return {"FINISHED"}


CLASSES = (BODYCAL_PG_retarget_settings, BODYCAL_OT_retarget_bake, BODYCAL_OT_export_animation)


def register_properties():
    bpy.types.Scene.bodycal_retarget = bpy.props.PointerProperty(type=BODYCAL_PG_retarget_settings)


def unregister_properties():
    del bpy.types.Scene.bodycal_retarget
