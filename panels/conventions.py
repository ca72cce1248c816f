"""What every BodyCal panel does the same way (docs/SIDEBAR.md, "Conventions"): the panels'
order, long lines wrapped to the sidebar's width, the help button in the header."""

import textwrap

# The sidebar's panels in the order of the work. A panel's `bl_order` is its place here, set when
# it registers, whichever module defines it (Blender sorts a parent's sub-panels by it).
ORDER = ("BODYCAL_PT_recording", "BODYCAL_PT_calibration", "BODYCAL_PT_avatar", "BODYCAL_PT_retarget",
         "BODYCAL_PT_transfer", "BODYCAL_PT_live")


def apply_order(classes) -> None:
    """Each listed panel's `bl_order` from its place in ORDER (before it registers)."""
    for cls in classes:
        if getattr(cls, "bl_idname", None) in ORDER:
            cls.bl_order = ORDER.index(cls.bl_idname)


def text_width(context) -> int:
    """About how many characters of UI text fit across the region (60 without one: a script or
    background mode), from its width in pixels and the interface scale."""
    region = getattr(context, "region", None)
    if region is None:
        return 60
    scale = context.preferences.system.ui_scale or 1.0
    return max(20, int((region.width - 40 * scale) / (7 * scale)))


def wrapped_label(layout, context, text: str, icon: str = "NONE") -> None:
    """`text` as labels that fit the region's width, cut at spaces: a label does not wrap, it is
    cut with an ellipsis. The icon on the first line; the next lines indented alike."""
    col = layout.column(align=True)
    for k, line in enumerate(textwrap.wrap(text, text_width(context), break_on_hyphens=False) or [""]):
        col.label(text=line, icon=icon if k == 0 else ("BLANK1" if icon != "NONE" else "NONE"))


def draw_help(layout, section: str) -> None:
    """The header's help button: this panel's part of docs/SIDEBAR.md."""
    op = layout.operator("bodycal.open_docs", text="", icon="HELP", emboss=False)
    op.page = "SIDEBAR.md"
    op.section = section
