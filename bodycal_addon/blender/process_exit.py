"""Ending a process that imported Blender as a module."""

from __future__ import annotations

import os
import shutil
import sys
from typing import NoReturn


def exit_now(code: int) -> NoReturn:
    """End the process without Blender's exit handlers (Blender 4.5 as a module can hang in them
    once classes were registered, BLENDER_NOTES.md "EXIT HANG"), after the two things they do that
    matter here: flush the output, and remove Blender's session temp folder (`bpy.app.tempdir`,
    `<temp>/blender_XXXXXX/`), which every process ended this way left behind (a batch farm ran
    one per job)."""
    sys.stdout.flush()
    sys.stderr.flush()
    bpy = sys.modules.get("bpy")
    temp = getattr(getattr(bpy, "app", None), "tempdir", "") or ""
    if os.path.basename(os.path.normpath(temp)).startswith("blender_"):
        shutil.rmtree(temp, ignore_errors=True)
    os._exit(code)
