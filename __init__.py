"""BodyCal Blender extension: registration only (the engine lives in `bodycal_addon/`)."""

import bpy

from . import operators, panels
from .bodycal_addon.app import cli_bridge

_cli_handle = None


def register():
    global _cli_handle
    operators.register()
    panels.register()
    if hasattr(bpy.utils, "register_cli_command"):
        _cli_handle = bpy.utils.register_cli_command("bodycal", cli_bridge.run)


def unregister():
    global _cli_handle
    if _cli_handle is not None:
        bpy.utils.unregister_cli_command(_cli_handle)
        _cli_handle = None
    panels.unregister()
    operators.unregister()
