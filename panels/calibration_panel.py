"""The user-calibration wizard (sidebar sub-panel of BodyCal): the steps found in the scene's
recording (its `bodycal:<step>...` timeline markers, or its stored steps when imported without),
each with its status and quality from the stored user model (residual mm, points kept, motion
range), and the run / save / load buttons."""

import json

import bpy

from ..bodycal_addon.blender import recording_scene
from ..bodycal_addon.blender.calibration_scene import BODY_JOINTS, CALIBRATION_STEPS, MODEL_PROP, coverage
from ..operators.calibration import REFUSED
from .conventions import draw_help, wrapped_label

_STEP_ORDER = (*CALIBRATION_STEPS, "touch")
_cache = {"raw": None, "cal": {}, "extra": {}}


def _parsed(scene) -> None:
    """The stored model's calibration report and extras, parsed once per change (draw runs often)."""
    raw = scene.get(MODEL_PROP)
    if raw != _cache["raw"]:
        _cache["raw"] = raw
        try:
            doc = json.loads(raw) if raw else {}
            _cache["cal"], _cache["extra"] = doc.get("calibration", {}), doc.get("extra", {}) or {}
        except (TypeError, ValueError, AttributeError):
            _cache["cal"], _cache["extra"] = {}, {}


def _calibration(scene) -> dict:
    _parsed(scene)
    return _cache["cal"]


def _extra(scene) -> dict:
    _parsed(scene)
    return _cache["extra"]


def steps_in_scene(scene) -> dict[str, int]:
    """{step: count} from the timeline markers `bodycal:<step>[:<point>[:<by>]]` (or the stored
    steps of a recording imported without markers)."""
    return recording_scene.steps_in_scene(scene)


def quality_text(q: dict) -> str:
    parts = []
    if "rms_mm" in q:
        parts.append(f"{q['rms_mm']:.1f} mm")
    if "kept" in q and "of" in q:
        parts.append(f"{q['kept']}/{q['of']} pts")
    if "range_deg" in q:
        parts.append(f"{q['range_deg']:.0f}°")
    if "spread_mm" in q and "rms_mm" not in q:
        parts.append(f"±{q['spread_mm']:.1f} mm")
    return ", ".join(parts)


class BODYCAL_PT_calibration(bpy.types.Panel):
    """The performer's body measured from the recording's calibration steps"""

    bl_idname = "BODYCAL_PT_calibration"
    bl_label = "User Calibration"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "BodyCal"
    bl_parent_id = "BODYCAL_PT_main"

    def draw_header_preset(self, _context):
        draw_help(self.layout, "User Calibration")

    def draw(self, context):
        layout = self.layout
        scene = context.scene
        found = steps_in_scene(scene)
        cal = _calibration(scene)
        quality = cal.get("quality", {})
        used = set(cal.get("steps_used", []))
        box = layout.box()
        if not found:
            box.label(text="No calibration steps in the recording", icon="INFO")
        for step in sorted(found, key=lambda s: _STEP_ORDER.index(s) if s in _STEP_ORDER else 99):
            row = box.row()
            label = step if step != "touch" else f"touch ({found[step]} points)"
            if step in quality:
                row.label(text=label, icon="CHECKMARK")
                row.label(text=quality_text(quality[step]))
            elif step in used or (step == "touch" and cal):
                row.label(text=label, icon="CHECKMARK")
            elif cal:
                row.label(text=label, icon="ERROR")
                row.label(text="not used")
            else:
                row.label(text=label, icon="RADIOBUT_OFF")
        for line in cal.get("warnings", []):
            wrapped_label(layout, context, line, icon="ERROR")
        if cal:
            cov = coverage(cal, _extra(scene))
            wrapped_label(layout, context, f"Measured {len(cov.measured)} of {len(BODY_JOINTS)} body joints, "
                                           f"{len(cov.defaulted)} defaulted",
                          icon="ERROR" if cov.mostly_guessed else "INFO")
            if cal.get("defaulted"):
                wrapped_label(layout, context, f"{len(cal['defaulted'])} values defaulted from the eye height",
                              icon="INFO")
            if cov.estimated_devices:
                what = " and ".join(p for p, r in (("pelvis", "pelvis"), ("feet", "foot_l"))
                                    if r in cov.estimated_devices)
                wrapped_label(layout, context, f"{cov.kit}: the {what} estimated from the head and hands "
                                               f"({', '.join(cal.get('estimated', []))})", icon="INFO")
        col = layout.column(align=True)
        col.operator("bodycal.calibrate_user", icon="PLAY")
        refused = REFUSED.get(scene.name)
        if refused is not None:
            wrapped_label(layout, context, refused)
        row = col.row(align=True)
        row.operator("bodycal.save_user_model", icon="EXPORT", text="Save")
        row.operator("bodycal.load_user_model", icon="IMPORT", text="Load")
        col.operator("bodycal.show_calibration_helpers", icon="HIDE_OFF")


CLASSES = (BODYCAL_PT_calibration,)
