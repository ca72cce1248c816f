"""The process that runs Blender as a module: where Blender's output goes, giving freed memory
back, and ending it. Nothing here imports `bpy`: the command line uses it before Blender loads."""

from __future__ import annotations

import contextlib
import ctypes
import io
import os
import shutil
import sys
import warnings
from typing import NoReturn


@contextlib.contextmanager
def stderr_to_stdout(*, python_stderr: bool = True):
    """What Blender's C code prints to the process's stderr (file descriptor 2) goes to stdout for
    the block: a scripted driver it refuses to run, an importer's complaints.

    `python_stderr`: Python's `sys.stderr` goes to stdout too (Blender's importers print their
    chatter from Python). False (the command line): Python's stderr keeps the process's real
    stderr, which then carries BodyCal's own lines only (one per error or warning), while Python's
    warnings (numpy's) go to stdout with Blender's log; when `sys.stderr` is not the process's (a
    test capturing it in Python), nothing changes."""
    if not python_stderr:
        try:
            is_process_stderr = sys.stderr.fileno() == 2
        except (AttributeError, ValueError, io.UnsupportedOperation):
            is_process_stderr = False
        if not is_process_stderr:
            yield
            return
    sys.stdout.flush()
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        os.dup2(1, 2)
        if python_stderr:
            with contextlib.redirect_stderr(sys.stdout):
                yield
        else:
            own = open(saved, "w", buffering=1, encoding=sys.stderr.encoding, errors="backslashreplace",
                       closefd=False)
            previous, show = sys.stderr, warnings.showwarning

            def to_stdout(message, category, filename, lineno, file=None, line=None):
                show(message, category, filename, lineno, file=sys.stdout, line=line)

            sys.stderr, warnings.showwarning = own, to_stdout
            try:
                yield
            finally:
                own.flush()
                sys.stderr, warnings.showwarning = previous, show
    finally:
        sys.stdout.flush()
        os.dup2(saved, 2)
        os.close(saved)


def release_freed_memory() -> None:
    """Give the memory Python and numpy freed back to the system (glibc's `malloc_trim`; nothing
    elsewhere). The pipeline's chunks free hundreds of mid-sized arrays that glibc keeps in its
    heap: after a 10-minute retarget the process held ~400 MB it no longer used, on top of which
    the bake then made its keys."""
    if not sys.platform.startswith("linux"):
        return
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
