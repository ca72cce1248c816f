"""The sidebar rows of the bake settings Retarget and Bake and Transfer Animation share
(`scene.bodycal_bake`, operators/bake_settings.py), laid out for `use_property_split`."""

import math

from .conventions import wrapped_label


def draw_placement(col, bake) -> None:
    """Where the performance plays and what carries it: placement, root motion, Rigify, feet."""
    col.prop(bake, "placement")
    col.prop(bake, "root_motion")
    col.prop(bake, "rigify_target")
    col.prop(bake, "plant_feet")


def draw_keys(col, bake) -> None:
    sub = col.column(heading="Action")
    sub.prop(bake, "replace")
    sub.prop(bake, "push_to_nla")
    sub = col.column(align=True)
    sub.prop(bake, "frame_range")
    if bake.frame_range == "custom":
        sub.prop(bake, "frame_first")
        sub.prop(bake, "frame_last")
    sub.prop(bake, "set_scene_range")
    sub = col.column(align=True)
    sub.prop(bake, "output_fps")
    sub.prop(bake, "interpolation")
    sub.prop(bake, "tolerance")
    sub.prop(bake, "location_tolerance")


def draw_last_result(layout, settings, context) -> None:
    """The last bake's figures, one avatar's line at a time, wrapped to the sidebar's width; then
    its review (docs/SIDEBAR.md, "Review")."""
    if settings.last_result:
        box = layout.box()
        for part in settings.last_result.split("; "):
            wrapped_label(box, context, part)
    draw_review(layout, getattr(settings, "review_flags", ()), context)


def draw_review(layout, flags, context) -> None:
    """The last bake's review: per avatar, each figure against its limit (red past it, worst first)
    with a button that jumps the timeline to its frame."""
    if not len(flags):
        return
    box = layout.box()
    shown = None
    for flag in flags:
        if flag.armature != shown:
            shown = flag.armature
            box.label(text=f"Review: {shown}", icon="VIEWZOOM")
        row = box.row()
        row.alert = flag.over
        if math.isfinite(flag.frame):
            op = row.operator("bodycal.jump_to_flag", text=f"{flag.frame:g}", icon="TIME")
            op.frame = flag.frame
        wrapped_label(row, context, flag.text, icon="ERROR" if flag.over else "CHECKMARK")
