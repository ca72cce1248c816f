"""Operators: thin UI over the engine (`bodycal_addon`) and its Blender glue."""

import bpy

from . import sample_avatars

_MODULES = (sample_avatars,)
CLASSES = tuple(cls for m in _MODULES for cls in m.CLASSES)

register, unregister = bpy.utils.register_classes_factory(CLASSES)
