"""Operators: thin UI over the engine (`bodycal_addon`) and its Blender glue."""

from . import (
    avatar,
    bake_presets,
    bake_settings,
    bone_map_editor,
    bone_maps,
    calibration,
    devices,
    docs,
    live,
    preferences,
    preview,
    recording,
    retarget,
    review,
    sample_avatars,
    transfer,
)
from .registration import register_classes_factory

_MODULES = (preferences, sample_avatars, recording, devices, calibration, avatar, bone_maps, review, bake_settings,
            bake_presets, retarget, transfer, preview, bone_map_editor, docs, live)
CLASSES = tuple(cls for m in _MODULES for cls in m.CLASSES)

_register_classes, _unregister_classes = register_classes_factory(CLASSES)


def register():
    _register_classes()
    for m in _MODULES:  # scene properties, after their PropertyGroup classes
        if hasattr(m, "register_properties"):
            m.register_properties()
    for m in _MODULES:  # menu entries (e.g. File > Import), after the classes they show
        if hasattr(m, "register_menus"):
            m.register_menus()
    for m in _MODULES:  # app handlers (the timeline preview's frame changes)
        if hasattr(m, "register_handlers"):
            m.register_handlers()


def unregister():
    for m in reversed(_MODULES):
        if hasattr(m, "unregister_handlers"):
            m.unregister_handlers()
    for m in reversed(_MODULES):
        if hasattr(m, "unregister_menus"):
            m.unregister_menus()
    for m in reversed(_MODULES):
        if hasattr(m, "unregister_properties"):
            m.unregister_properties()
    _unregister_classes()
