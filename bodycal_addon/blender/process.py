"""The process that runs Blender as a module: giving freed memory back, and ending it."""

from __future__ import annotations

import os
import shutil
import sys
from typing import NoReturn


def release_freed_memory() -> None:
    """Give the memory Python and numpy freed back to the system (glibc's `malloc_trim`; nothing
    elsewhere). The pipeline's chunks free hundreds of mid-sized arrays that glibc keeps in its
    heap: after a 10-minute retarget the process held ~400 MB it no longer used, on top of which
    the bake then made its keys."""
    if not sys.platform.startswith("linux"):
        return
    import ctypes

    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):  # not glibc (musl has no malloc_trim)
        pass


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
