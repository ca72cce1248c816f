"""The engine lane: plain pytest, no Blender. The engine is numpy, and mathutils for one frame (PyPI's
build here, core/one_frame.py); importing bpy or bmesh from here fails the test that tries (a test
that needs Blender belongs in tests/blender).
The block applies when only this lane is asked for (`make test-fast`, or paths under tests/engine);
a run that also collects tests/blender (both lanes, or no path: the ini's testpaths) loads Blender
and leaves it alone, whichever lane is collected first."""

import sys

_lanes = [a for a in sys.argv[1:] if not a.startswith("-") and ("engine" in a or "blender" in a)]
if _lanes and not any("blender" in a for a in _lanes) and "bpy" not in sys.modules:
    for name in ("bpy", "bmesh", "addon_utils"):
        sys.modules[name] = None  # `import bpy` now raises ImportError
