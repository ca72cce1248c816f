"""Sidebar panels (View3D > Sidebar > BodyCal): thin UI over the operators."""

from ..operators.registration import register_classes_factory
from . import (
    avatar_panel,
    bake_presets,
    bone_map_panel,
    calibration_panel,
    conventions,
    live_panel,
    main_panel,
    recording_panel,
    retarget_panel,
    transfer_panel,
)

CLASSES = (main_panel.CLASSES + recording_panel.CLASSES + calibration_panel.CLASSES + avatar_panel.CLASSES
           + bone_map_panel.CLASSES + retarget_panel.CLASSES + transfer_panel.CLASSES + bake_presets.CLASSES
           + live_panel.CLASSES)

conventions.apply_order(CLASSES)
register, unregister = register_classes_factory(CLASSES)
