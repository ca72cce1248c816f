"""Bake setting presets, with Blender's own preset system (`bl_operators.presets.AddPresetBase`):
a preset is a small Python file in the user's `scripts/presets/bodycal/bake/`, listed by the
presets button in the Retarget and Bake and Transfer Animation panels' headers
(panels/bake_presets.py) and applied by Blender's `script.execute_preset`."""

import bpy
from bl_operators.presets import AddPresetBase

PRESET_SUBDIR = "bodycal/bake"
PRESET_PANEL = "BODYCAL_PT_bake_presets"

# What a preset keeps: how to bake and the device smoothing, not what (the avatar, the method, a
# custom range's frames: they belong to a scene's take).
BAKE_VALUES = ("placement", "root_motion", "rigify_target", "plant_feet", "replace", "push_to_nla", "frame_range",
               "set_scene_range", "output_fps", "tolerance", "location_tolerance")
SMOOTHING_VALUES = ("use_filter", "filter_min_cutoff", "filter_beta", "filter_rot_min_cutoff", "filter_rot_beta")


class BODYCAL_OT_add_bake_preset(AddPresetBase, bpy.types.Operator):
    """Save the bake settings and the device smoothing as a preset, or remove the chosen preset"""

    bl_idname = "bodycal.add_bake_preset"
    bl_label = "Add Bake Preset"
    preset_menu = PRESET_PANEL
    preset_subdir = PRESET_SUBDIR
    preset_defines = ["bake = bpy.context.scene.bodycal_bake", "retarget = bpy.context.scene.bodycal_retarget"]
    preset_values = [f"bake.{name}" for name in BAKE_VALUES] + [f"retarget.{name}" for name in SMOOTHING_VALUES]


CLASSES = (BODYCAL_OT_add_bake_preset,)
