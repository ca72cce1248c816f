"""BodyCal > Avatar > Bone Map: the whole map of the armature (every canonical segment and its
bone, grouped, searchable, editable in place: operators/bone_map_editor.py), the detected naming
scheme, what is missing, hinge axes and bone map presets."""

import fnmatch

import bpy

from ..bodycal_addon.blender import avatar_storage
from ..bodycal_addon.blender.avatar_rig import SCHEME_BY_NAME, SEGMENTS, segment_value
from ..operators import bone_map_editor as editor
from ..operators.avatar import context_armature

_STATUS_ICONS = {"missing": "ERROR", "set": "HAND", "detected": "CHECKMARK", "unmapped": "DOT"}


def row_visibility(rows, pattern: str, expanded, value_of) -> list[bool]:
    """Which rows the list shows. `rows`: (kind, group index, name); without a search, the group
    headers and the rows of open groups; with one (Blender's wildcards, letter case ignored), the
    segments whose name or bone matches, in any group, and their groups' headers."""
    text = pattern.strip().lower()
    if not text:
        return [kind == "GROUP" or bool(expanded[g]) for kind, g, _name in rows]
    if not any(c in text for c in "*?["):
        text = f"*{text}*"
    hit = [kind != "GROUP" and (fnmatch.fnmatchcase(name.lower(), text)
                                or fnmatch.fnmatchcase(value_of(name).lower(), text)) for kind, _g, name in rows]
    groups = {g for (_kind, g, _name), h in zip(rows, hit) if h}
    return [h or (kind == "GROUP" and g in groups) for (kind, g, _name), h in zip(rows, hit)]


def draw_row(ulist, layout, arm, item) -> None:
    state = editor.editor_state(arm)
    if item.kind == "GROUP":
        _title_id, title, segments, _open = editor.GROUPS[item.group]
        mapped = sum(1 for s in segments if segment_value(state.bm, s))
        row = layout.row(align=True)
        row.alert = any(editor.row_status(state, s) == "missing" for s in segments)
        row.prop(ulist, "expanded", index=item.group, text=title, emboss=False,
                 icon="TRIA_DOWN" if ulist.expanded[item.group] else "TRIA_RIGHT")
        row.label(text=f"{mapped}/{len(segments)}")
        return
    segment = item.name
    status = editor.row_status(state, segment)
    split = layout.split(factor=0.38, align=True)
    left = split.row()
    left.alert = status == "missing"
    left.label(text=segment, icon=_STATUS_ICONS[status])
    row = split.row(align=True)
    row.alert = status == "missing"
    if item.kind == "CHAIN":  # the chain's bones as its list, bottom-up
        row.prop(item, "bones", text="")
    else:
        row.prop_search(item, "bone", arm.data, "bones", text="")
    if status == "set" and segment_value(state.detected, segment) != segment_value(state.bm, segment):
        op = row.operator("bodycal.revert_bone_map_entry", text="", icon="LOOP_BACK")
        op.segment = segment
    else:
        row.label(text="", icon="BLANK1")
    if status in ("set", "detected"):
        op = row.operator("bodycal.clear_bone_map_entry", text="", icon="X")
        op.segment = segment
    else:
        row.label(text="", icon="BLANK1")


class BODYCAL_UL_bone_map(bpy.types.UIList):
    """The armature's bone map: a row per canonical segment, grouped; search by segment or bone."""

    expanded: bpy.props.BoolVectorProperty(name="Open", size=len(editor.GROUPS), options=set(),
                                           default=tuple(g[3] for g in editor.GROUPS),
                                           description="Show this group's segments")

    def draw_item(self, context, layout, data, item, icon, active_data, active_propname, index=0, flt_flag=0):
        draw_row(self, layout, data, item)

    def draw_filter(self, context, layout):
        layout.prop(self, "filter_name", text="", icon="VIEWZOOM")

    def filter_items(self, context, data, propname):
        rows = getattr(data, propname)
        bm = editor.editor_state(data).bm
        shown = row_visibility([(r.kind, r.group, r.name) for r in rows], self.filter_name, self.expanded,
                               lambda seg: segment_value(bm, seg))
        return [self.bitflag_filter_item if s else 0 for s in shown], []


def _summary(layout, arm, state) -> None:
    scheme = SCHEME_BY_NAME.get(state.detected.scheme)
    row = layout.row()
    row.label(text=f"Detected: {scheme.title if scheme else state.detected.scheme}", icon="BONE_DATA")
    row.operator("bodycal.detect_bone_map", text="", icon="FILE_REFRESH")
    missing = state.bm.missing()
    mapped = sum(1 for s in SEGMENTS if segment_value(state.bm, s))
    by_hand = sum(1 for s in state.overrides if s in SEGMENTS)
    layout.label(text=f"{mapped} of {len(SEGMENTS)} segments mapped, {by_hand} set by hand",
                 icon="ERROR" if missing else "CHECKMARK")
    lines = [("ERROR", state.problem)] if state.problem else []
    last = editor.note(arm)
    if last and (last[0] == "ERROR" or not avatar_storage.has_model(arm)):
        lines.append(last)
    if missing:
        lines.append(("ERROR", f"Missing: {', '.join(missing)}"))
    for icon, text in lines:
        col = layout.column()
        col.alert = icon == "ERROR"
        col.label(text=text, icon=icon)


class BODYCAL_PT_bone_map(bpy.types.Panel):
    """Which bone of the armature is each body segment: detected from the bone names, editable"""

    bl_idname = "BODYCAL_PT_bone_map"
    bl_label = "Bone Map"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "BodyCal"
    bl_parent_id = "BODYCAL_PT_avatar"

    @classmethod
    def poll(cls, context):
        return context_armature(context) is not None

    def draw(self, context):
        layout = self.layout
        arm = context_armature(context)
        state = editor.editor_state(arm)
        _summary(layout, arm, state)
        if editor.rows_ready(arm):
            layout.template_list("BODYCAL_UL_bone_map", "", arm, "bodycal_bone_map_rows", arm,
                                 "bodycal_bone_map_index", rows=12)
            rows = arm.bodycal_bone_map_rows
            active = rows[arm.bodycal_bone_map_index] if arm.bodycal_bone_map_index < len(rows) else None
            bone = arm.data.bones.active
            if active is not None and active.kind == "SEGMENT" and bone is not None:
                op = layout.operator("bodycal.assign_bone", text=f"{active.name} -> {bone.name}", icon="EYEDROPPER")
                op.segment, op.bone = active.name, bone.name
        else:  # drawing may not write: the rows are made just after (or by the button)
            editor.request_rows(arm)
            layout.operator("bodycal.show_bone_map", icon="PRESET")
        row = layout.row(align=True)
        op = row.operator("bodycal.detect_bone_map", text="Reset to Detected", icon="LOOP_BACK")
        op.reset = True
        row.operator("bodycal.set_hinge_axis", icon="CON_ROTLIKE")
        # Presets: a naming scheme forced, or a saved map (FORMATS.md §5); the map stays on the armature.
        box = layout.box()
        row = box.row(align=True)
        row.prop(context.window_manager, "bodycal_bone_map_preset", text="")
        row.operator("bodycal.apply_bone_map_preset", text="Apply", icon="CHECKMARK")
        row = box.row(align=True)
        row.operator("bodycal.export_bone_map", text="Export Map", icon="EXPORT")
        row.operator("bodycal.import_bone_map", text="Import Map", icon="IMPORT")


CLASSES = (BODYCAL_UL_bone_map, BODYCAL_PT_bone_map)
