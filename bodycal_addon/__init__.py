"""BodyCal engine: tracker recordings -> body models -> egocentric retargeting (numpy only).

Everything that touches Blender lives in `bodycal_addon.blender`; this package and its other
modules import numpy only, so they run and test without Blender.

Its packages are layers, lowest first, each importing only its own and those below (DESIGN.md
"Modules"): `core`, `body`, `recording`, `calibration` and `avatar`, `retarget`, `output`, `live`,
`blender`, `app`. `python -m bodycal_addon` is `app.cli.main`.
"""

__version__ = "0.1.0"
