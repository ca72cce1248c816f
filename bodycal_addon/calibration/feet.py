"""Feet (Delahaye 2023, appendix B, "Feet calibration", Figure 7): sole points = the touches projected
to the floor (z = 0) and stored in the foot tracker's frame; ankle = mean of the `ankle_in` /
`ankle_out` touches; ankle radius = half their distance."""

from __future__ import annotations

import numpy as np

from ..body import skeleton as sk
from ..core import transforms as tf
from ..core.geometry import robust_mean
from . import touches as T
from .common import Session, State


def feet(session: Session, state: State) -> None:
    touches = T.collect(session, state, ("sole_", "ankle_"))
    for s in sk.SIDES:
        role = f"foot_{s}"
        a_in, a_out = touches.get(f"ankle_in_{s}"), touches.get(f"ankle_out_{s}")
        if a_in and a_out:
            state.set_local(f"ankle_{s}", role, 0.5 * (a_in.local + a_out.local))
            state.radii[f"ankle_{s}"] = 0.5 * float(np.linalg.norm(a_in.local - a_out.local))
            session.use(f"ankle_{s}", {"spread_mm": round(max(a_in.spread_mm, a_out.spread_mm), 2),
                                       "radius_mm": round(state.radii[f"ankle_{s}"] * 1000, 1)})
        soles = sorted((k for k in touches if k.startswith("sole_") and k.endswith(f"_{s}")),
                       key=lambda k: int(k.split("_")[1]))
        if len(soles) < 3:
            continue
        fp, fq, _ = session.pose(role)
        pts = {}
        for k in soles:
            t = touches[k]
            floor = session.rec.marker(t.by)[0][t.frames] if t.by in session.rec.marker_names else None
            if floor is None:
                floor = np.repeat(t.world[None], len(t.frames), axis=0)
            floor = floor * np.array([1.0, 1.0, 0.0])  # projected to the floor (Figure 7, orange arrows)
            pts[k] = robust_mean(tf.inverse_transform_points(fp[t.frames], fq[t.frames], floor), name=k)[0]
        state.sole_points[s] = pts
        session.use(f"sole_{s}")
