"""The scene's devices: each device empty's role as a drop-down (the Recording panel's Devices
list; it reads and writes the empty's `bodycal_role`, so an edit is undone like any property
edit and saved with the .blend), Identify Roles from the T-pose, and Recording from Objects (the
selected animated objects as the scene's recording)."""

import bpy

from ..bodycal_addon.blender import device_roles, scene_objects
from ..bodycal_addon.blender.device_roles import ROLES
from ..bodycal_addon.blender.recording_scene import scene_recording_collection
from .reporting import reports_errors

NONE = "none"


def role_label(role: str) -> str:
    """"hand_l" -> "Left Hand", "upperarm_r" -> "Right Upper Arm"."""
    base, _, side = role.rpartition("_") if role.endswith(("_l", "_r")) else (role, "", "")
    words = base.replace("upperarm", "upper arm").split()
    return " ".join(([{"l": "Left", "r": "Right"}[side]] if side else []) + [w.capitalize() for w in words])


ROLE_ITEMS = [(NONE, "None", "No role: identified from the T-pose when calibrating", 0)] + [
    (r, role_label(r), f"The device is on the performer's {role_label(r).lower()} ({r})", i + 1)
    for i, r in enumerate(ROLES)]
_NUMBER = {r: i + 1 for i, r in enumerate(ROLES)}


def _get_role(obj) -> int:
    return _NUMBER.get(device_roles.role_of(obj), 0)


def _set_role(obj, value: int) -> None:
    device_roles.set_role(obj, ROLES[value - 1] if value else "")


def _tpose_marked(scene) -> bool:
    return any(m.name == "bodycal:tpose" or m.name.startswith("bodycal:tpose:") for m in scene.timeline_markers)


class BODYCAL_OT_identify_roles(bpy.types.Operator):
    """Identify the devices' roles from the T-pose (AvatarGo: the devices' places on the plane through them),
    keeping the roles you set unless All Devices is on"""

    bl_idname = "bodycal.identify_roles"
    bl_label = "Identify Roles"
    bl_options = {"REGISTER", "UNDO"}

    everything: bpy.props.BoolProperty(
        name="All Devices", default=False,
        description="Also replace the roles you set in the list (otherwise they are kept, and not given to others)")

    @classmethod
    def poll(cls, context):
        if context.mode != "OBJECT":
            cls.poll_message_set("Switch to Object Mode to identify roles")
            return False
        if scene_recording_collection(context.scene) is None:
            cls.poll_message_set("Import a recording (or make one from objects) first")
            return False
        if not _tpose_marked(context.scene):
            cls.poll_message_set("Mark the T-pose on the timeline first (a marker named bodycal:tpose)")
            return False
        return True

    @reports_errors
    def execute(self, context):
        written, missing = device_roles.identify_scene_roles(context.scene, everything=self.everything)
        text = ", ".join(f"{n}={r}" for n, r in written.items()) or "none"
        self.report({"WARNING"} if missing else {"INFO"},
                    f"Roles from the T-pose: {text}" + (f"; no role for {', '.join(missing)}" if missing else ""))
        return {"FINISHED"}


class BODYCAL_OT_recording_from_objects(bpy.types.Operator):
    """Read the selected animated objects (trackers and controllers another tool recorded, any keyed empties)
    over the scene's frame range as the scene's recording: one new empty per device and marker, the originals
    left as they are"""

    bl_idname = "bodycal.recording_from_objects"
    bl_label = "Recording from Objects"
    bl_options = {"REGISTER", "UNDO"}

    name: bpy.props.StringProperty(name="Name", default=scene_objects.DEFAULT_NAME,
                                   description="The recording's name (its collection's, and the baked actions')")

    @classmethod
    def poll(cls, context):
        if context.mode != "OBJECT":
            cls.poll_message_set("Switch to Object Mode to read objects")
            return False
        if not context.selected_objects:
            cls.poll_message_set("Select the animated tracker objects first")
            return False
        return True

    @reports_errors
    def execute(self, context):
        coll, rec = scene_objects.recording_from_objects(context.scene, context.selected_objects, self.name)
        for note in rec.notes:
            self.report({"INFO"}, note)
        roles = sum(1 for d in rec.devices if d.role)
        self.report({"INFO"}, f"Recording {coll.name}: {len(rec.devices)} devices ({roles} with a role), "
                              f"{len(rec.marker_names)} markers, {rec.frame_count} frames, {len(rec.segments)} steps")
        return {"FINISHED"}


def register_properties():
    bpy.types.Object.bodycal_device_role = bpy.props.EnumProperty(
        name="Role", items=ROLE_ITEMS, get=_get_role, set=_set_role,
        description="The body part this device is on (its bodycal_role): what calibration and retargeting use")
    bpy.types.Scene.bodycal_device_index = bpy.props.IntProperty(name="Active Device", default=0, min=0,
                                                                 description="The Devices list's active row")


def unregister_properties():
    del bpy.types.Scene.bodycal_device_index
    del bpy.types.Object.bodycal_device_role


CLASSES = (BODYCAL_OT_identify_roles, BODYCAL_OT_recording_from_objects)
