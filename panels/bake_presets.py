"""The bake presets button (operators/bake_presets.py) in the bake panels' headers."""

import bpy
from bl_ui.utils import PresetPanel

from ..operators.bake_presets import PRESET_PANEL, PRESET_SUBDIR


class BODYCAL_PT_bake_presets(PresetPanel, bpy.types.Panel):
    """Bake presets: apply saved bake settings, or save the current ones under a name"""

    bl_idname = PRESET_PANEL
    bl_label = "Bake Presets"
    preset_subdir = PRESET_SUBDIR
    preset_operator = "script.execute_preset"
    preset_add_operator = "bodycal.add_bake_preset"


def draw_presets_button(layout) -> None:
    BODYCAL_PT_bake_presets.draw_panel_header(layout)


CLASSES = (BODYCAL_PT_bake_presets,)
