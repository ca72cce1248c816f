"""BodyCal engine: tracker recordings -> body models -> egocentric retargeting (numpy only).

Everything that touches Blender lives in `bodycal_addon.blender`; this package and its other
modules import numpy only, so they run and test without Blender.
"""

__version__ = "0.1.0"
