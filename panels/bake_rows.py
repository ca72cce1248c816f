"""The sidebar rows of the bake settings Retarget and Bake and Transfer Animation share
(`scene.bodycal_bake`, operators/bake_settings.py), laid out for `use_property_split`."""

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
    """The last bake's figures, one avatar's line at a time, wrapped to the sidebar's width."""
    if settings.last_result:
        box = layout.box()
        for part in settings.last_result.split("; "):
            wrapped_label(box, context, part)
