"""Head (Delahaye 2023, appendix B, "Head Calibration", Figure 9), all in the HMD frame (`head`):
jaw crude mesh from the six jaw touches; skull-back sphere through the four skull touches (with
exactly four points the sphere is exact); skull base = mean of the two skull-base touches."""

from __future__ import annotations

import numpy as np

from ..body.surface_layout import JAW_POINTS, SKULL_POINTS
from ..core.geometry import fit_sphere
from . import touches as T
from .common import Session, State


def head(session: Session, state: State) -> None:
    touches = T.collect(session, state, ("ear_", "upper_lip", "chin", "jaw_", "skull_"))
    jaw = {k: touches[k].local for k in JAW_POINTS if k in touches}
    if len(jaw) == len(JAW_POINTS):
        state.jaw = jaw
        session.use("jaw", {"spread_mm": round(max(touches[k].spread_mm for k in JAW_POINTS), 2)})
    elif jaw:
        session.missing.append(f"jaw mesh: only {len(jaw)} of the 6 jaw touches ({', '.join(sorted(jaw))})")
    skull = [touches[k].local for k in SKULL_POINTS if k in touches]
    if len(skull) >= 4:
        fit = fit_sphere(np.array(skull), name="skull sphere (skull_top, skull_left, skull_right, skull_back)")
        state.skull = (fit.center, float(fit.radius))
        session.use("skull", {"rms_mm": round(fit.rms * 1000, 3), "kept": fit.kept, "of": fit.of,
                              "radius_mm": round(fit.radius * 1000, 1)})
    elif skull:
        session.missing.append(f"skull sphere: only {len(skull)} of the 4 skull touches")
    bl, br = touches.get("skull_base_l"), touches.get("skull_base_r")
    if bl and br:
        state.set_local("skull_base", "head", 0.5 * (bl.local + br.local))
        session.use("skull_base", {"spread_mm": round(max(bl.spread_mm, br.spread_mm), 2)})
