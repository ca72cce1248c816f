"""`python -m bodycal_addon <command> ...` (Blender as a Python module)."""

import sys

from bodycal_addon.app.cli import main

if __name__ == "__main__":
    code = main(sys.argv[1:])
    sys.stdout.flush()
    sys.stderr.flush()
    if "bpy" in sys.modules:
        from bodycal_addon.blender.process import exit_now

        exit_now(code)
    sys.exit(code)
