"""User calibration operators: run it on the scene's recording, save / load the `*.body.json`,
show the fitted joints, spheres, circles and surface elements as helper objects."""

import bpy
from bpy_extras.io_utils import ExportHelper, ImportHelper

from ..bodycal_addon.core.errors import BodyCalError
from .preferences import StartsInFolder
from .reporting import reports_errors

# {scene name: the last refusal's line}: what the panel shows until the next calibration of that scene.
REFUSED: dict[str, str] = {}


def _has_recording(context) -> bool:
    from ..bodycal_addon.blender.recording_scene import scene_recording_collection

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
        from ..bodycal_addon.blender import calibration_scene as cs
        from ..bodycal_addon.blender.recording_scene import recording_from_scene
        from ..bodycal_addon.calibration import calibrate_user, check_usable

        rec = recording_from_scene(context.scene)
        model = calibrate_user(rec)
        REFUSED.pop(context.scene.name, None)
        try:
            cov = check_usable(model)
        except BodyCalError as exc:  # the panel shows it
            REFUSED[context.scene.name] = exc.line()
            raise
        cs.store_user_model(context.scene, model)
        if self.show_helpers:
            cs.show_helpers(context.scene, model)
        cal = model.calibration
        for line in cal.get("warnings", []) + cov.warnings():
            self.report({"WARNING"}, line)
        self.report({"INFO"}, f"Calibrated from {len(cal['steps_used'])} steps: {cov.line()}; "
                              f"{len(cal['missing'])} steps missing"
                              + (f", {len(cal['warnings'])} not usable (see the panel)" if cal.get("warnings") else ""))
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
        from ..bodycal_addon.blender.calibration_scene import has_user_model

        if not has_user_model(context.scene):
            cls.poll_message_set("Calibrate the user (or load a user model) first")
            return False
        return True

    def _suggested_name(self, context) -> str:
        from ..bodycal_addon.blender.calibration_scene import load_user_model

        return bpy.path.clean_name(load_user_model(context.scene).name) + self.filename_ext

    @reports_errors
    def execute(self, context):
        from ..bodycal_addon.blender.calibration_scene import load_user_model

        path = load_user_model(context.scene).save(self.filepath)
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
        from ..bodycal_addon.blender import calibration_scene as cs
        from ..bodycal_addon.body.bodymodel import BodyModel

        model = BodyModel.load(self.filepath)
        if model.kind != "user":
            raise BodyCalError(f"this is an {model.kind} body model, not a user one", source=self.filepath)
        cs.store_user_model(context.scene, model)
        self.report({"INFO"}, f"Loaded user model '{model.name}' ({len(model.joints)} joints)")
        return {"FINISHED"}


class BODYCAL_OT_show_calibration_helpers(bpy.types.Operator):
    """Show the user model's fitted joints, spheres, hinge circles and crude meshes as helper objects"""

    bl_idname = "bodycal.show_calibration_helpers"
    bl_label = "Show Calibration Helpers"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        from ..bodycal_addon.blender.calibration_scene import has_user_model

        if context.mode != "OBJECT":
            cls.poll_message_set("Switch to Object Mode to show the helpers")
            return False
        if not has_user_model(context.scene):
            cls.poll_message_set("Calibrate the user (or load a user model) first")
            return False
        return True

    @reports_errors
    def execute(self, context):
        from ..bodycal_addon.blender import calibration_scene as cs

        coll = cs.show_helpers(context.scene, cs.load_user_model(context.scene))
        self.report({"INFO"}, f"{len(coll.objects)} helper objects in '{coll.name}'")
        return {"FINISHED"}


CLASSES = (BODYCAL_OT_calibrate_user, BODYCAL_OT_save_user_model, BODYCAL_OT_load_user_model,
           BODYCAL_OT_show_calibration_helpers)
