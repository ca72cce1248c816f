"""The Recording panel (sidebar sub-panel of BodyCal): import a recording or make one from
animated objects, the scene's recording at a glance, and its Devices list: each device's name,
kind, role (a drop-down writing the empty's `bodycal_role`) and whether the role came from the
file, was identified from the T-pose or was set by the user."""

import json

import bpy

from ..bodycal_addon.blender import device_roles
from ..bodycal_addon.blender.recording_scene import (
    DEVICE_PROP,
    MARKER_PROP,
    META_KEY,
    TIME_KEY,
    scene_recording_collection,
)
from .calibration_panel import steps_in_scene
from .conventions import draw_help, wrapped_label

KIND_LABELS = {"hmd": "HMD", "controller": "Controller", "tracker": "Tracker", "rigid_body": "Rigid Body"}
KIND_ICONS = {"hmd": "HIDE_OFF", "controller": "OBJECT_DATA", "tracker": "EMPTY_AXIS", "rigid_body": "HAND"}
ORIGIN_LABELS = {"file": "File", "tpose": "T-pose", "user": "Set", "": "—"}
ORIGIN_HINTS = {"file": "given by the recording", "tpose": "identified from the T-pose", "user": "set by you",
                "": "identified from the T-pose when calibrating"}
_cache = {"raw": None, "meta": {}}


def recording_meta(coll) -> dict:
    """The stored recording's header (name, devices, markers, rate, ...), parsed once per change."""
    raw = coll.get(META_KEY)
    if raw != _cache["raw"]:
        _cache["raw"] = raw
        try:
            _cache["meta"] = json.loads(raw) if raw else {}
        except (TypeError, ValueError):
            _cache["meta"] = {}
    return _cache["meta"]


def summary_lines(scene) -> list[str]:
    """The scene's recording in a few lines: name, devices and markers, frames and rate, steps."""
    coll = scene_recording_collection(scene)
    if coll is None:
        return []
    meta = recording_meta(coll)
    frames = len(coll.get(TIME_KEY, ()))
    steps = sum(steps_in_scene(scene).values())
    roles = sum(1 for o in device_roles.device_empties(coll) if device_roles.role_of(o))
    devices = len(device_roles.device_empties(coll))
    return [f"{meta.get('name', coll.name)} ({coll.name})",
            f"{devices} devices ({roles} with a role), {len(device_roles.marker_empties(coll))} markers",
            f"{frames} frames at {float(meta.get('rate', 0.0)):.4g} fps, from frame {meta.get('frame_start', '?')}",
            f"{steps} calibration steps on the timeline"]


class BODYCAL_UL_devices(bpy.types.UIList):
    """The recording's device empties (and its markers): name, kind, role, where the role came from."""

    show_markers: bpy.props.BoolProperty(name="Markers", default=True, description="List the markers too")

    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index):
        obj = item
        split = layout.split(factor=0.4)
        if DEVICE_PROP in obj:
            problem = device_roles.role_problems(data).get(obj.name)
            kind = str(obj.get("bodycal_kind", ""))
            split.label(text=str(obj[DEVICE_PROP]), icon="ERROR" if problem else KIND_ICONS.get(kind, "EMPTY_AXIS"))
            row = split.split(factor=0.3)
            row.label(text=KIND_LABELS.get(kind, kind))
            role = row.split(factor=0.72)
            role.prop(obj, "bodycal_device_role", text="")
            role.label(text=ORIGIN_LABELS[device_roles.origin_of(obj)])
        else:
            split.label(text=str(obj.get(MARKER_PROP, obj.name)), icon="SPHERE")
            row = split.split(factor=0.3)
            row.label(text="Marker")
            row.label(text="")

    def draw_filter(self, context, layout):
        row = layout.row()
        row.prop(self, "filter_name", text="")
        row.prop(self, "show_markers")

    def filter_items(self, context, data, propname):
        items = getattr(data, propname)
        flags = bpy.types.UI_UL_list.filter_items_by_name(self.filter_name, self.bitflag_filter_item, items, "name") \
            if self.filter_name else [self.bitflag_filter_item] * len(items)
        keep = [DEVICE_PROP in o or (self.show_markers and MARKER_PROP in o) for o in items]
        return [f if k else 0 for f, k in zip(flags, keep)], []


class BODYCAL_PT_recording(bpy.types.Panel):
    """The scene's recording: import one or make one from animated objects, and what it holds"""

    bl_idname = "BODYCAL_PT_recording"
    bl_label = "Recording"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "BodyCal"
    bl_parent_id = "BODYCAL_PT_main"

    def draw_header_preset(self, _context):
        draw_help(self.layout, "Recording")

    def draw(self, context):
        layout = self.layout
        col = layout.column(align=True)
        col.operator("bodycal.import_recording", icon="IMPORT")
        col.operator("bodycal.recording_from_objects", icon="OUTLINER_OB_EMPTY")
        lines = summary_lines(context.scene)
        if not lines:
            layout.label(text="No recording in this scene", icon="INFO")
            return
        box = layout.box().column(align=True)
        wrapped_label(box, context, lines[0], icon="ANIM_DATA")
        for line in lines[1:]:
            wrapped_label(box, context, line)


class BODYCAL_PT_recording_devices(bpy.types.Panel):
    """The recording's devices and markers, each device's role editable: where every error about a missing role
    points"""

    bl_idname = "BODYCAL_PT_recording_devices"
    bl_label = "Devices"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "BodyCal"
    bl_parent_id = "BODYCAL_PT_recording"

    @classmethod
    def poll(cls, context):
        return scene_recording_collection(context.scene) is not None

    def draw(self, context):
        layout = self.layout
        coll = scene_recording_collection(context.scene)
        layout.template_list("BODYCAL_UL_devices", "", coll, "objects", context.scene, "bodycal_device_index",
                             rows=6)
        for name, problem in device_roles.role_problems(coll).items():
            wrapped_label(layout, context, f"{coll.objects[name].get(DEVICE_PROP, name)}: {problem}", icon="ERROR")
        active = context.scene.bodycal_device_index
        if 0 <= active < len(coll.objects) and DEVICE_PROP in coll.objects[active]:
            origin = device_roles.origin_of(coll.objects[active])
            wrapped_label(layout, context, f"{coll.objects[active][DEVICE_PROP]}: role {ORIGIN_HINTS[origin]}",
                          icon="INFO")
        row = layout.row(align=True)
        row.operator("bodycal.identify_roles", icon="OUTLINER_OB_ARMATURE")
        row.operator("bodycal.identify_roles", text="All Devices").everything = True


CLASSES = (BODYCAL_UL_devices, BODYCAL_PT_recording, BODYCAL_PT_recording_devices)
