"""File > Import > BodyCal recording: read a tracker recording and put it in the scene."""

import bpy
from bpy_extras.io_utils import ImportHelper, poll_file_object_drop

from ..bodycal_addon.blender import recording_scene
from ..bodycal_addon.recording import io as recording_io
from ..bodycal_addon.recording.io.reader import RECORDING_SUFFIXES
from .preferences import StartsInFolder
from .reporting import reports_errors


class BODYCAL_OT_import_recording(StartsInFolder, bpy.types.Operator, ImportHelper):
    """Import a tracker recording (.bcrec.json, .csv, .c3d): one animated empty per device and
    marker, timeline markers for the calibration steps"""

    bl_idname = "bodycal.import_recording"
    bl_label = "Import BodyCal Recording"
    bl_options = {"REGISTER", "UNDO"}
    _folder = "recordings_folder"

    filter_glob: bpy.props.StringProperty(default=";".join(f"*{s}" for s in RECORDING_SUFFIXES),
                                          options={"HIDDEN"})
    fill_gaps: bpy.props.FloatProperty(
        name="Fill Gaps Shorter Than", default=recording_io.DEFAULT_FILL_GAPS_S, min=0.0, max=2.0, unit="TIME_ABSOLUTE",
        description="Untracked stretches shorter than this (seconds) are interpolated; 0 keeps every dropout")

    @classmethod
    def poll(cls, context):
        if context.mode != "OBJECT":
            cls.poll_message_set("Switch to Object Mode to import a recording")
            return False
        if context.scene is None:
            cls.poll_message_set("No scene to import into")
            return False
        return True

    @reports_errors
    def execute(self, context):
        # Compute first (read + validate), write last: on error the scene is untouched.
        rec = recording_io.load_recording(self.filepath, fill_gaps_s=self.fill_gaps)
        coll = recording_scene.import_recording_to_scene(rec, context)
        summary = f"Imported {coll.name}: {len(rec.devices)} devices, {len(rec.marker_names)} markers, " \
                  f"{rec.frame_count} frames at {rec.fps:.4g} Hz, {len(rec.segments)} steps"
        for note in rec.notes:
            self.report({"INFO"}, note)
        self.report({"INFO"}, summary)
        return {"FINISHED"}


class BODYCAL_FH_recording(bpy.types.FileHandler):
    """Drop a recording file on the 3D viewport or the outliner to import it (Blender 4.1+)."""

    bl_idname = "BODYCAL_FH_recording"
    bl_label = "BodyCal recording"
    bl_import_operator = BODYCAL_OT_import_recording.bl_idname
    bl_file_extensions = ".bcrec.json;.csv;.c3d"

    @classmethod
    def poll_drop(cls, context):
        return poll_file_object_drop(context)


def menu_import(self, context):
    self.layout.operator(BODYCAL_OT_import_recording.bl_idname, text="BodyCal recording (.bcrec.json, .csv, .c3d)")


def register_menus():
    bpy.types.TOPBAR_MT_file_import.append(menu_import)


def unregister_menus():
    bpy.types.TOPBAR_MT_file_import.remove(menu_import)


CLASSES = (BODYCAL_OT_import_recording, BODYCAL_FH_recording)
