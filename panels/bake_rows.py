"""The sidebar rows of the bake settings Retarget and Bake and Transfer Animation share
(operators/bake_settings.py)."""


def draw_rig_output(col, settings) -> None:
    col.prop(settings, "root_motion")
    col.prop(settings, "rigify_target")


def draw_keys(col, settings) -> None:
    row = col.row(align=True)
    row.prop(settings, "replace", toggle=True)
    row.prop(settings, "push_to_nla", toggle=True)
    sub = col.column(align=True)
    sub.prop(settings, "output_fps")
    sub.prop(settings, "tolerance")
    sub.prop(settings, "location_tolerance")


def draw_last_result(layout, settings) -> None:
    if settings.last_result:
        box = layout.box()
        for part in settings.last_result.split("; "):
            box.label(text=part)
