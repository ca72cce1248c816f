"""File > Import > BodyCal recording: read a tracker recording and put it in the scene."""

import bpy
from bpy_extras.io_utils import ImportHelper, poll_file_object_drop

from ..bodycal_addon.blender import recording_scene
from .preferences import StartsInFolder
from .reporting import reports_errors

STEP_MARKER_ITEMS = [  # recording_scene.STEP_MARKERS
    ("starts", "At Step Starts", "One timeline marker where each calibration step starts"),
    ("bounds", "Starts and Ends", "A marker where each step starts, and one where it ends when a pause follows"),
    ("none", "None", "No timeline markers: the recording's steps are used until a bodycal: marker is added"),
]


HANDS_ITEMS = [  # recording/io/hands.py's HANDS
    ("geometry", "Where They Are", "The controller on the headset's right most of the time is the right hand "
     "(the file's labels when that does not decide)"),
    ("labels", "As Labelled", "The file's left / right labels (an A-Frame entity's id, a replay's hands)"),
    ("swapped", "Labels Swapped", "The opposite of the file's left / right labels"),
]


def _takes_hands(filepath: str) -> bool:
    """Whether the file may be a three-point kit's own (an A-Frame .json, a .bsor), whose hands the
    import tells: by name only, as the side panel redraws often."""
    name = filepath.lower()
    return name.endswith(".bsor") or name.endswith(".json") and not name.endswith(recording_scene.JSON_SUFFIX)


class BODYCAL_OT_import_recording(StartsInFolder, bpy.types.Operator, ImportHelper):
    """Import a tracker recording (.bcrec.json, .csv, .c3d, A-Frame .json, Beat Saber .bsor) as animated empties"""

    bl_idname = "bodycal.import_recording"
    bl_label = "Import BodyCal Recording"
    bl_options = {"REGISTER", "UNDO"}
    _folder = "recordings_folder"

    filter_glob: bpy.props.StringProperty(default=";".join(recording_scene.RECORDING_GLOBS), options={"HIDDEN"})
    frame_start: bpy.props.IntProperty(
        name="Start Frame", default=1,
        description="Frame the recording's first sample is keyed on")
    update_scene_rate: bpy.props.BoolProperty(
        name="Set Scene Frame Rate", default=True,
        description="Set the scene's frame rate to the recording's; off: keep it and time the samples to it")
    update_scene_range: bpy.props.BoolProperty(
        name="Set Scene Frame Range", default=True,
        description="Set the scene's frame range to the recording's frames")
    step_markers: bpy.props.EnumProperty(
        name="Step Markers", items=STEP_MARKER_ITEMS, default="starts",
        description="Timeline markers for the calibration steps (bodycal:<step>); moving them edits the steps")
    fill_gaps: bpy.props.FloatProperty(
        name="Fill Gaps Shorter Than", default=recording_scene.DEFAULT_FILL_GAPS_S, min=0.0, max=2.0,
        unit="TIME_ABSOLUTE",
        description="Untracked stretches shorter than this (seconds) are interpolated; 0 keeps every dropout")
    hands: bpy.props.EnumProperty(  # not remembered: a swap chosen for one file must not swap the next
        name="Hands", items=HANDS_ITEMS, default="geometry", options={"SKIP_SAVE"},
        description="A-Frame motion captures and Beat Saber replays: which controller is the right hand")

    @classmethod
    def poll(cls, context):
        if context.mode != "OBJECT":
            cls.poll_message_set("Switch to Object Mode to import a recording")
            return False
        if context.scene is None:
            cls.poll_message_set("No scene to import into")
            return False
        return True

    def draw(self, _context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        header, body = layout.panel("BODYCAL_import_timing", default_closed=False)
        header.label(text="Frames")
        if body:
            body.prop(self, "frame_start")
            body.prop(self, "update_scene_rate")
            body.prop(self, "update_scene_range")
        header, body = layout.panel("BODYCAL_import_steps", default_closed=False)
        header.label(text="Steps and Tracking")
        if body:
            body.prop(self, "step_markers")
            body.prop(self, "fill_gaps")
            if _takes_hands(self.filepath):
                body.prop(self, "hands")

    @reports_errors
    def invoke(self, context, event):
        if not self.properties.is_property_set("filepath"):
            return StartsInFolder.invoke(self, context, event)  # the file browser, in the Recordings folder
        # A file dropped on the viewport or the outliner (Blender 4.2+ passes its path): the
        # handler claims every .json, .csv, .c3d and .bsor, so only a recording goes on to the options.
        recording_scene.check_recording_file(self.filepath)
        return context.window_manager.invoke_props_dialog(self, title=bpy.path.basename(self.filepath),
                                                          confirm_text="Import")

    @reports_errors
    def execute(self, context):
        # Compute first (read + validate), write last: on error the scene is untouched.
        rec, coll = recording_scene.import_recording_file(
            self.filepath, context, fill_gaps_s=self.fill_gaps, hands=self.hands, frame_start=self.frame_start,
            set_scene_rate=self.update_scene_rate, set_scene_range=self.update_scene_range,
            step_markers=self.step_markers)
        for note in rec.notes:
            self.report({"INFO"}, note)
        self.report({"INFO"}, recording_scene.import_summary(rec, coll, context.scene))
        return {"FINISHED"}


class BODYCAL_FH_recording(bpy.types.FileHandler):
    """Drop a recording file on the 3D viewport or the outliner to import it (Blender 4.2+)."""

    bl_idname = "BODYCAL_FH_recording"
    bl_label = "BodyCal recording"
    bl_import_operator = BODYCAL_OT_import_recording.bl_idname
    # Blender matches a dropped file by its last suffix only: `.bcrec.json` is `.json` here, and the
    # operator's invoke refuses a file that is not a recording (recording_scene.check_recording_file).
    bl_file_extensions = ".json;.csv;.c3d;.bsor"

    @classmethod
    def poll_drop(cls, context):
        return poll_file_object_drop(context)


def menu_import(self, context):
    self.layout.operator(BODYCAL_OT_import_recording.bl_idname,
                         text="BodyCal recording (.bcrec.json, .csv, .c3d, .json, .bsor)")


def register_menus():
    bpy.types.TOPBAR_MT_file_import.append(menu_import)


def unregister_menus():
    bpy.types.TOPBAR_MT_file_import.remove(menu_import)


CLASSES = (BODYCAL_OT_import_recording, BODYCAL_FH_recording)
