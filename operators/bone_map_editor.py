"""The bone map editor (the Avatar panel's Bone Map sub-panel, panels/bone_map_panel.py): every
canonical segment of the armature's map as a row of a list, its bone editable in place.

The rows kept on the armature object say only which segment each one is (they are the same for
every armature); a row's bone is read from, and written to, the map stored on the armature
(`avatar_rig`, custom property `bodycal_bone_map`): one storage, so the rows never go stale and
undo brings the map itself back. An edit is checked first (`avatar_rig.edit_segment`): a bone the
armature lacks, or a bone already serving another segment, changes nothing and leaves one line in
the panel; an edit that changes the map removes a stored avatar model made with the old one."""

import functools
from typing import NamedTuple

import bpy

from ..bodycal_addon.blender import BodyCalError, avatar_rig
from ..bodycal_addon.blender.avatar_rig import CHAIN_SEGMENTS, FINGERS, SIDES, BoneMap, required_segments, segment_value
from .avatar import context_armature, poll_armature
from .reporting import reports_errors


def _sided(s: str, side: str) -> tuple[tuple[str, str, tuple[str, ...], bool], ...]:
    fingers = tuple(p for f in FINGERS for p in (f"metacarpal_{f}_{s}", f"{f}_1_{s}", f"{f}_2_{s}", f"{f}_3_{s}"))
    return ((f"arm_{s}", f"{side} Arm", (f"clavicle_{s}", f"upperarm_{s}", f"forearm_{s}", f"hand_{s}"), True),
            (f"leg_{s}", f"{side} Leg", (f"thigh_{s}", f"shin_{s}", f"foot_{s}", f"toe_{s}"), True),
            (f"fingers_{s}", f"{side} Fingers", fingers, False))


# (id, title, segments, open by default): every canonical segment once; the essentials open first.
_L, _R = _sided("l", "Left"), _sided("r", "Right")
GROUPS: tuple[tuple[str, str, tuple[str, ...], bool], ...] = (
    ("trunk", "Trunk and Head", ("root", "pelvis", "spine", "neck", "head"), True),
    _L[0], _R[0], _L[1], _R[1], _L[2], _R[2],
    ("auxiliary", "Auxiliary (follow their parent)",
     tuple(f"{part}_{s}" for part in ("breast", "pelvis_side", "heel") for s in SIDES), False),
)
# (kind, group index, name): a group's header row (named by the group's id), then its segments.
ROWS: tuple[tuple[str, int, str], ...] = tuple(
    row for g, (gid, _title, segments, _open) in enumerate(GROUPS)
    for row in (("GROUP", g, gid), *(("CHAIN" if s in CHAIN_SEGMENTS else "SEGMENT", g, s) for s in segments)))
REQUIRED = frozenset(required_segments())


# --- the map as the editor shows it ----------------------------------------------------------------

class EditorState(NamedTuple):
    bm: BoneMap  # the map in use: detection and the stored overrides
    detected: BoneMap  # detection alone
    overrides: dict  # segment -> stored value: the segments set by hand (or by a preset)
    problem: str | None  # what is wrong with the stored map as it is, one line


_states: dict = {}
_notes: dict[str, tuple[str, str]] = {}  # armature -> (icon, line): the last edit's refusal or warning


def editor_state(arm) -> EditorState:
    """The armature's map for drawing, computed once per (bone names, stored map): the list's rows
    read it for every redraw."""
    key = (tuple(arm.data.bones.keys()), str(arm.get(avatar_rig.BONE_MAP_PROP, "")))
    state = _states.get(key)
    if state is None:
        detected = avatar_rig.detected_map(arm)
        try:
            state = EditorState(avatar_rig.bone_map_for(arm), detected, avatar_rig.load_overrides(arm),
                                avatar_rig.map_problem(arm))
        except BodyCalError as exc:  # unreadable stored map: shown as detected, with the reason
            state = EditorState(detected, detected, {}, exc.line())
        if len(_states) > 32:
            _states.clear()
        _states[key] = state
    return state


def row_status(state: EditorState, segment: str) -> str:
    """"missing" (a required segment without a bone), "set" (by hand or a preset), "detected"
    (from the bone names), or "unmapped" (an optional segment without a bone)."""
    if not segment_value(state.bm, segment):
        return "missing" if segment in REQUIRED else "unmapped"
    return "set" if segment in state.overrides else "detected"


def note(arm) -> tuple[str, str] | None:
    """The last edit's line for this armature (a refusal, or a removed avatar model), if any."""
    return _notes.get(arm.name_full)


def edit(arm, segment: str, value: str | None) -> bool:
    """One edit as the list makes it (`avatar_rig.edit_segment`); a refusal is kept as the panel's
    line instead of raised: a property's setter has nobody to report to."""
    try:
        _bm, dropped = avatar_rig.edit_segment(arm, segment, value)
    except BodyCalError as exc:
        _notes[arm.name_full] = ("ERROR", exc.line())
        return False
    if dropped:
        _notes[arm.name_full] = ("INFO", f"{arm.name}: {avatar_rig.MODEL_DROPPED}")
    else:
        _notes.pop(arm.name_full, None)
    return True


# --- the rows ----------------------------------------------------------------------------------------

def _get_bone(self) -> str:
    if self.kind == "GROUP":
        return ""
    return segment_value(editor_state(self.id_data).bm, self.name)


def _set_bone(self, value: str) -> None:
    if self.kind == "GROUP":
        return
    current = _get_bone(self)
    if self.kind == "CHAIN":  # the same list however it is spaced: no edit
        same = _chain_list(value) == _chain_list(current)
    else:
        same = value == current
    if not same:  # picking the bone already there keeps it detected
        edit(self.id_data, self.name, value)


def _chain_list(text: str) -> list[str]:
    return [b.strip() for b in text.split(",") if b.strip()]


def _chain_candidates(self, _context, edit_text: str):
    """Completions of a chain's comma-separated list: the bones typed so far, then each bone of
    the armature whose name holds the last, unfinished one."""
    done, _comma, partial = edit_text.rpartition(",")
    head = _chain_list(done)
    prefix = "".join(f"{b}, " for b in head)
    partial = partial.strip().lower()
    return [prefix + n for n in self.id_data.data.bones.keys() if partial in n.lower() and n not in head]


class BODYCAL_PG_bone_map_row(bpy.types.PropertyGroup):
    """One row of the bone map editor: `name` is the segment (a group's id on its header row)."""

    kind: bpy.props.EnumProperty(items=[("GROUP", "Group", "A group's header"),
                                        ("SEGMENT", "Segment", "A segment mapped to one bone"),
                                        ("CHAIN", "Chain", "The spine or neck: bones bottom-up")],
                                 description="What the row shows")
    group: bpy.props.IntProperty(min=0, description="The row's group (operators/bone_map_editor.GROUPS)")
    bone: bpy.props.StringProperty(
        name="Bone", options=set(), get=_get_bone, set=_set_bone,
        description="The armature's bone for this segment (empty: unmapped); saved in the armature's bone map")
    bones: bpy.props.StringProperty(
        name="Bones", options=set(), get=_get_bone, set=_set_bone, search=_chain_candidates,
        description="The chain's bones, bottom-up, comma-separated; saved in the armature's bone map")


def rows_ready(arm) -> bool:
    rows = arm.bodycal_bone_map_rows
    return len(rows) == len(ROWS) and all(r.name == name for r, (_k, _g, name) in zip(rows, ROWS))


def can_edit(arm) -> bool:
    """A linked armature (not made local or overridden) keeps its library's map."""
    return bool(arm.is_editable)


def build_rows(arm) -> None:
    rows = arm.bodycal_bone_map_rows
    rows.clear()
    for kind, group, name in ROWS:
        row = rows.add()
        row.name, row.kind, row.group = name, kind, group


_pending: set[str] = set()


def request_rows(arm) -> None:
    """From a panel's draw, which may not write data: build the armature's rows just after it
    (a timer), once; the Show Bone Map button does the same by hand."""
    name = arm.name
    if name in _pending or not can_edit(arm) or bpy.app.background:  # no window draws in background
        return
    _pending.add(name)
    bpy.app.timers.register(functools.partial(_build_later, name), first_interval=0.0)


def _build_later(name: str) -> None:
    try:
        arm = bpy.data.objects.get(name)
        if arm is not None and arm.type == "ARMATURE" and can_edit(arm) and not rows_ready(arm):
            build_rows(arm)
            for window in bpy.context.window_manager.windows:
                for area in window.screen.areas:
                    if area.type == "VIEW_3D":
                        area.tag_redraw()
    finally:
        _pending.discard(name)


# --- operators ---------------------------------------------------------------------------------------

def _poll_editable(cls, context) -> bool:
    if not poll_armature(cls, context, object_mode=False):
        return False
    if not can_edit(context_armature(context)):
        cls.poll_message_set("A linked armature: make it local (or add a library override) to edit its bone map")
        return False
    return True


class BODYCAL_OT_show_bone_map(bpy.types.Operator):
    """List every body segment of the armature's bone map, to review and edit it in place"""

    bl_idname = "bodycal.show_bone_map"
    bl_label = "Show Bone Map"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return _poll_editable(cls, context)

    @reports_errors
    def execute(self, context):
        arm = context_armature(context)
        if not rows_ready(arm):
            build_rows(arm)
        return {"FINISHED"}


class _SegmentEdit:
    segment: bpy.props.StringProperty(name="Segment", options={"SKIP_SAVE"}, description="The body segment to edit")

    @classmethod
    def poll(cls, context):
        return _poll_editable(cls, context)

    def _edit(self, context, value):
        arm = context_armature(context)
        _bm, dropped = avatar_rig.edit_segment(arm, self.segment, value)
        _notes.pop(arm.name_full, None)
        if dropped:
            self.report({"WARNING"}, f"{arm.name}: {avatar_rig.MODEL_DROPPED}")
        return {"FINISHED"}


class BODYCAL_OT_clear_bone_map_entry(_SegmentEdit, bpy.types.Operator):
    """Leave this segment unmapped (its bone then follows its parent); saved with the armature"""

    bl_idname = "bodycal.clear_bone_map_entry"
    bl_label = "Clear Bone Map Entry"
    bl_options = {"REGISTER", "UNDO"}

    @reports_errors
    def execute(self, context):
        return self._edit(context, "")


class BODYCAL_OT_revert_bone_map_entry(_SegmentEdit, bpy.types.Operator):
    """Give this segment back to detection: the bone its name says (forgets what was set by hand
    or by a preset for it)"""

    bl_idname = "bodycal.revert_bone_map_entry"
    bl_label = "Revert Bone Map Entry to Detected"
    bl_options = {"REGISTER", "UNDO"}

    @reports_errors
    def execute(self, context):
        return self._edit(context, None)


CLASSES = (BODYCAL_PG_bone_map_row, BODYCAL_OT_show_bone_map, BODYCAL_OT_clear_bone_map_entry,
           BODYCAL_OT_revert_bone_map_entry)


def register_properties():
    bpy.types.Object.bodycal_bone_map_rows = bpy.props.CollectionProperty(
        type=BODYCAL_PG_bone_map_row, options={"HIDDEN"},
        description="The rows of BodyCal's bone map editor (the map itself is the bodycal_bone_map property)")
    bpy.types.Object.bodycal_bone_map_index = bpy.props.IntProperty(
        name="Active Segment", options={"HIDDEN"}, default=0, min=0,
        description="The bone map editor's active row")


def unregister_properties():
    del bpy.types.Object.bodycal_bone_map_index
    del bpy.types.Object.bodycal_bone_map_rows
