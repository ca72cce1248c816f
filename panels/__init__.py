"""Sidebar panels (View3D > Sidebar > BodyCal): thin UI over the operators."""

import bpy

from . import (
           avatar_panel,
           bone_map_panel,
           calibration_panel,
           main_panel,
           recording_panel,
           retarget_panel,
           transfer_panel,
)

CLASSES = (main_panel.CLASSES + recording_panel.CLASSES + calibration_panel.CLASSES + avatar_panel.CLASSES
           + bone_map_panel.CLASSES + retarget_panel.CLASSES + transfer_panel.CLASSES)

register, unregister = bpy.utils.register_classes_factory(CLASSES)
