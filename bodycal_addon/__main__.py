"""`python -m bodycal_addon <command> ...` (Blender as a Python module)."""

import os
import sys

from bodycal_addon.cli import main

if __name__ == "__main__":
    code = main(sys.argv[1:])
    sys.stdout.flush()
    sys.stderr.flush()
    if "bpy" in sys.modules:
        # Blender 4.5 as a module can hang at interpreter exit once classes were registered
        # (BLENDER_NOTES.md, "EXIT HANG"): leave without running its atexit handlers.
        os._exit(code)
    sys.exit(code)
