"""User calibration operators: run it on the scene's recording, save / load the `*.body.json`,
show the fitted joints, spheres, circles and surface elements as helper objects."""

import bpy
from bpy_extras.io_utils import ExportHelper, ImportHelper

from ..bodycal_addon.blender import calibration_scene as cs
from ..bodycal_addon.blender.recording_scene import scene_recording_collection
from .preferences import StartsInFolder
from .reporting import reports_errors

REFUSED = cs.REFUSED  # {scene name: the last refusal's line}, which the panel shows


def _has_recording(context) -> bool:
    return scene_recording_collection(context.scene) is not None


class BODYCAL_OT_calibrate_user(bpy.types.Operator):
    """Run every calibration step the scene's recording allows (Delahaye 2023, appendix B) and store the
    user body model on the scene"""

    bl_idname = "bodycal.calibrate_user"
    bl_label = "Calibrate User"
    bl_options = {"REGISTER", "UNDO"}

    show_helpers: bpy.props.BoolProperty(name="Show Helpers", default=True,
                                         description="Show the fitted joints and surfaces as helper objects")

    @classmethod
    def poll(cls, context):
        if context.mode != "OBJECT":
            cls.poll_message_set("Switch to Object Mode to calibrate")
            return False
        if not _has_recording(context):
            cls.poll_message_set("Import a recording first (File > Import > BodyCal Recording)")
            return False
        return True

    @reports_errors
    def execute(self, context):
        summary, warnings = cs.calibration_report(*cs.calibrate_scene(context.scene, show=self.show_helpers))
        for line in warnings:
            self.report({"WARNING"}, line)
        self.report({"INFO"}, summary)
        return {"FINISHED"}


class BODYCAL_OT_save_user_model(StartsInFolder, bpy.types.Operator, ExportHelper):
    """Save the scene's user body model as a .body.json file"""

    bl_idname = "bodycal.save_user_model"
    bl_label = "Save User Model"
    _folder = "recordings_folder"
    filename_ext = ".body.json"
    filter_glob: bpy.props.StringProperty(default="*.body.json", options={"HIDDEN"})

    @classmethod
    def poll(cls, context):
        if not cs.has_user_model(context.scene):
            cls.poll_message_set("Calibrate the user (or load a user model) first")
            return False
        return True

    def _suggested_name(self, context) -> str:
        return bpy.path.clean_name(cs.load_user_model(context.scene).name) + self.filename_ext

    @reports_errors
    def execute(self, context):
        path = cs.load_user_model(context.scene).save(self.filepath)
        self.report({"INFO"}, f"Saved {path}")
        return {"FINISHED"}


class BODYCAL_OT_load_user_model(StartsInFolder, bpy.types.Operator, ImportHelper):
    """Load a user body model (.body.json) into the scene"""

    bl_idname = "bodycal.load_user_model"
    bl_label = "Load User Model"
    bl_options = {"REGISTER", "UNDO"}
    _folder = "recordings_folder"
    filename_ext = ".json"
    filter_glob: bpy.props.StringProperty(default="*.body.json;*.json", options={"HIDDEN"})

    @classmethod
    def poll(cls, context):
        if context.mode != "OBJECT":
            cls.poll_message_set("Switch to Object Mode to load a user model")
            return False
        return True

    @reports_errors
    def execute(self, context):
        model = cs.load_user_model_file(context.scene, self.filepath)
        self.report({"INFO"}, f"Loaded user model '{model.name}' ({len(model.joints)} joints)")
        return {"FINISHED"}


class BODYCAL_OT_show_calibration_helpers(bpy.types.Operator):
    """Show the user model's fitted joints, spheres, hinge circles and crude meshes as helper objects"""

    bl_idname = "bodycal.show_calibration_helpers"
    bl_label = "Show Calibration Helpers"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        if context.mode != "OBJECT":
            cls.poll_message_set("Switch to Object Mode to show the helpers")
            return False
        if not cs.has_user_model(context.scene):
            cls.poll_message_set("Calibrate the user (or load a user model) first")
            return False
        return True

    @reports_errors
    def execute(self, context):
        coll = cs.show_helpers(context.scene, cs.load_user_model(context.scene))
        self.report({"INFO"}, f"{len(coll.objects)} helper objects in '{coll.name}'")
        return {"FINISHED"}


CLASSES = (BODYCAL_OT_calibrate_user, BODYCAL_OT_save_user_model, BODYCAL_OT_load_user_model,
           BODYCAL_OT_show_calibration_helpers)
