"""The engine lane: plain pytest, no Blender. The engine is numpy only; importing bpy, mathutils or
bmesh from here fails the test that tries (a test that needs Blender belongs in tests/blender).
Run alone (`make test-fast`); when one process collects both lanes, Blender is already loaded by
the Blender lane and is left alone."""

import sys

if "bpy" not in sys.modules:
    for name in ("bpy", "mathutils", "bmesh", "addon_utils"):
        sys.modules[name] = None  # `import bpy` now raises ImportError
