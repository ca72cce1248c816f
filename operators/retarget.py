"""Retarget and bake: the last step of the sidebar flow, the scene's recording as the take of the
shared bake (operators/bake_settings.BakeOperator); and the export of a baked avatar (also in
File > Export)."""

from pathlib import Path

import bpy
from bpy_extras.io_utils import ExportHelper

from ..bodycal_addon.blender import session
from ..bodycal_addon.blender.export import EXPORT_SUFFIXES, export_avatar
from .bake_settings import BakeOperator, can_bake_in, method_items, selected_armatures
from .preferences import StartsInFolder, method_property
from .reporting import reports_errors
from .review import BODYCAL_PG_review_flag


class BODYCAL_PG_retarget_settings(bpy.types.PropertyGroup):
    """What only a recording's bake has (the shared bake settings: scene.bodycal_bake)."""

    method: method_property(method_items(session.RECORDING), "Method", "How the recording drives the avatar")
    use_filter: bpy.props.BoolProperty(
        name="Smooth Devices", default=True,
        description="One Euro filter on the tracker poses before retargeting (the recording itself is not changed)")
    filter_min_cutoff: bpy.props.FloatProperty(
        name="Min Cutoff", default=session.OneEuro.min_cutoff, min=0.01, soft_max=20.0,
        description="Cutoff (Hz) of a still device's position: lower smooths more")
    filter_beta: bpy.props.FloatProperty(
        name="Beta", default=session.OneEuro.beta, min=0.0, soft_max=50.0,
        description="How fast the position's cutoff rises with speed (Hz per m/s): higher follows quick moves")
    filter_rot_min_cutoff: bpy.props.FloatProperty(
        name="Rotation Min Cutoff", default=session.OneEuro.rot_min_cutoff, min=0.01, soft_max=20.0,
        description="Cutoff (Hz) of a still device's rotation")
    filter_rot_beta: bpy.props.FloatProperty(
        name="Rotation Beta", default=session.OneEuro.rot_beta, min=0.0, soft_max=20.0,
        description="How fast the rotation's cutoff rises with angular speed (Hz per rad/s)")
    last_result: bpy.props.StringProperty(name="Last Result", default="", options={"SKIP_SAVE"},
                                          description="The last bake's figures, per avatar")
    review_flags: bpy.props.CollectionProperty(type=BODYCAL_PG_review_flag, name="Review",
                                               description="The last bake\'s review: its figures against their limits")
    seated: bpy.props.BoolProperty(
        name="Seated", default=False,
        description="The performer sits on a seat (a kit without foot trackers: the estimated pelvis stays on the "
                    "seat, the estimated feet planted in front; with foot trackers the feet are measured)")
    seat_height: bpy.props.FloatProperty(
        name="Seat Height", default=0.45, min=0.1, max=1.2, precision=3, subtype="DISTANCE", unit="LENGTH",
        description="How high the seat is above the floor (a chair: about 0.45 m)")

    def scene_take(self, scene) -> session.RecordingTake:
        """The scene's recording as these settings take it: smoothed, seated or not."""
        return session.scene_take(scene, self.one_euro(), seat_height=self.seat_height if self.seated else None)

    def one_euro(self) -> session.OneEuro | None:
        if not self.use_filter:
            return None
        return session.OneEuro(self.filter_min_cutoff, self.filter_beta, self.filter_rot_min_cutoff,
                               self.filter_rot_beta)


class BODYCAL_OT_retarget_bake(BakeOperator, bpy.types.Operator):
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
        if not selected_armatures(context):
            cls.poll_message_set("Pick an avatar armature in the BodyCal tab (or select armatures)")
            return False
        problem = session.scene_take_missing(context.scene)
        if problem:
            cls.poll_message_set(problem)
            return False
        return True

    def _read_take(self, context) -> session.RecordingTake:
        return self._own_settings(context).scene_take(context.scene)

    def _armatures(self, context) -> list:
        return selected_armatures(context)

    def _method(self, context) -> str:
        return self._own_settings(context).method

    def _own_settings(self, context):
        return context.scene.bodycal_retarget


class BODYCAL_OT_export_animation(StartsInFolder, bpy.types.Operator, ExportHelper):
    """Export the active armature with its meshes and its baked action (FBX, glTF or BVH), with the
options a game engine expects"""

    bl_idname = "bodycal.export_animation"
    bl_label = "Export Baked Avatar"
    bl_options = {"REGISTER"}
    _folder = "export_folder"

    filename_ext = ".fbx"
    filter_glob: bpy.props.StringProperty(default=";".join(f"*{s}" for s in EXPORT_SUFFIXES), options={"HIDDEN"})
    file_format: bpy.props.EnumProperty(
        name="Format", default=".fbx", description="The file format: sets the file name's extension",
        items=[(".fbx", "FBX", "Armature, meshes and the action; Y up, no leaf bones (Unity, Unreal)"),
               (".glb", "glTF Binary (.glb)", "One binary file: armature, skinned meshes and the action"),
               (".gltf", "glTF (.gltf)", "One text file with its buffers embedded"),
               (".bvh", "BVH", "The armature's motion only")],
        update=lambda self, _context: self._use_format())

    def _use_format(self):
        self.filename_ext = self.file_format
        if self.filepath:
            self.filepath = str(Path(self.filepath).with_suffix(self.file_format))

    def _suggested_name(self, context) -> str:
        return bpy.path.clean_name(context.active_object.name) + self.file_format

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


def menu_export(self, _context):
    self.layout.operator(BODYCAL_OT_export_animation.bl_idname, text="BodyCal Baked Avatar (.fbx, .glb, .gltf, .bvh)")


def register_menus():
    bpy.types.TOPBAR_MT_file_export.append(menu_export)


def unregister_menus():
    bpy.types.TOPBAR_MT_file_export.remove(menu_export)


def register_properties():
    bpy.types.Scene.bodycal_retarget = bpy.props.PointerProperty(
        type=BODYCAL_PG_retarget_settings, description="BodyCal: what only Retarget and Bake has")


def unregister_properties():
    del bpy.types.Scene.bodycal_retarget
