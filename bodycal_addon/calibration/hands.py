"""Hands and fingers (Delahaye 2023, appendix B, "Hands and Fingers calibration"; DESIGN.md §3).

- `palms_together`: each palm plane = plane through the midpoints of opposite LEDs (the three
  back-of-hand LEDs and the five fingertip LEDs of one hand with their mirror on the other hand),
  stored in each hand's frame, normal out of the palm; finger radius = half the distance from the
  fingertip LED to the palm plane; extended fingertips (on the finger axis, one radius from the
  plane) stored in the hand frame.
- wrist = mean of the `wrist_top` / `wrist_bottom` touches; wrist radius = half their distance.
- finger base (MCP) = touched point projected on the palm plane, moved one finger radius toward
  the back of the hand; PIP / DIP on the base-to-tip line at anthropometric fractions (reported).
- palm surface = `palm_*` touches projected on the palm plane.
"""

from __future__ import annotations

import numpy as np

from ..body import skeleton as sk
from ..core import transforms as tf
from ..core.geometry import fit_plane, robust_mean
from . import touches as T
from .common import Session, State

# Fractions of the MCP -> extended tip distance at which PIP and DIP sit (phalanx lengths of
# Buchholz et al. 1992, proximal : middle : distal ≈ 0.46 : 0.29 : 0.25 of the finger).
PHALANX_FRACTIONS = {"thumb": (0.50, 0.78), "index": (0.46, 0.75), "middle": (0.46, 0.75),
                     "ring": (0.46, 0.75), "pinky": (0.44, 0.72)}


def palms_together(session: Session, state: State) -> None:
    segs = session.rec.segments_of("palms_together")
    if not segs:
        return
    rec = session.rec
    idx = session.frames(segs)
    names = [f"hand_led{k}" for k in (1, 2, 3)] + [f"{f}_tip" for f in sk.FINGERS]
    pairs = [n for n in names if f"{n}_l" in rec.marker_names and f"{n}_r" in rec.marker_names]
    if len(pairs) < 3 or not (session.has("hand_l") and session.has("hand_r")):
        session.missing.append("palms_together (needs both gloves' LED markers)")
        return
    mids, ok = [], []
    for n in pairs:
        pl, vl = rec.marker(f"{n}_l")
        pr, vr = rec.marker(f"{n}_r")
        mids.append(0.5 * (pl[idx] + pr[idx]))
        ok.append(vl[idx] & vr[idx])
    mids = np.stack(mids, axis=1)  # (N, K, 3)
    ok = np.stack(ok, axis=1)
    quality = {}
    for s in sk.SIDES:
        hp, hq, hv = session.pose(f"hand_{s}")
        local = tf.inverse_transform_points(hp[idx, None], hq[idx, None], mids)  # (N, K, 3)
        use = ok & hv[idx, None]
        pts = local[use]
        plane = fit_plane(pts, name=f"palms_together ({s} palm plane)")
        d = np.abs(plane.distance(pts))
        keep = d <= max(2.0 * d.std() + d.mean(), 1e-6)  # 2-sigma pass on the distance to the plane
        if session.robust and keep.sum() >= 3 and not keep.all():
            plane = fit_plane(pts[keep], name=f"palms_together ({s} palm plane)")
        normal = plane.normal if plane.distance(np.zeros(3)) < 0 else -plane.normal  # out of the palm
        # the hand frame's origin projected on the plane: the palm centre (`by: palm_<s>` touches)
        point = (plane.point @ normal) * normal
        state.palm_planes[f"hand_{s}"] = (point, normal)
        state.extra.setdefault("palm_centre", {})[s] = point
        quality[s] = {"rms_mm": round(plane.rms * 1000, 3), "kept": int(keep.sum()), "of": int(len(pts))}
        for f in sk.FINGERS:
            name = f"{f}_tip_{s}"
            if name not in rec.marker_names:
                continue
            mp, mv = rec.marker(name)
            sel = idx[mv[idx] & hv[idx]]
            if len(sel) == 0:
                continue
            led = robust_mean(tf.inverse_transform_points(hp[sel], hq[sel], mp[sel]), name=name)[0]
            dist = float((point - led) @ normal)  # LED is on the back of the finger, behind the plane
            r = 0.5 * abs(dist)
            state.radii[f"finger_{f}_{s}"] = r
            state.set_local(f"tip_{f}_{s}", f"hand_{s}", led + normal * (abs(dist) - r))
    session.use("palms_together", {"rms_mm": max(q["rms_mm"] for q in quality.values()),
                                   "kept": sum(q["kept"] for q in quality.values()),
                                   "of": sum(q["of"] for q in quality.values()), "per_hand": quality})


def hand_touches(session: Session, state: State) -> None:
    """Wrist, finger bases and palm outline from touches, per side."""
    touches = T.collect(session, state, ("wrist_", "mcp_", "palm_"))
    for s in sk.SIDES:
        role = f"hand_{s}"
        plane = state.palm_planes.get(role)
        top, bottom = touches.get(f"wrist_top_{s}"), touches.get(f"wrist_bottom_{s}")
        if top and bottom:
            state.set_local(f"wrist_{s}", role, 0.5 * (top.local + bottom.local))
            state.radii[f"wrist_{s}"] = 0.5 * float(np.linalg.norm(top.local - bottom.local))
            session.use(f"wrist_{s}", {"spread_mm": round(max(top.spread_mm, bottom.spread_mm), 2),
                                       "radius_mm": round(state.radii[f"wrist_{s}"] * 1000, 1)})
        for f in sk.FINGERS:
            t = touches.get(f"mcp_{f}_{s}")
            if t is None:
                continue
            p = t.local
            if plane is not None:
                point, normal = plane
                r = state.radii.get(f"finger_{f}_{s}", 0.0)
                p = p - ((p - point) @ normal) * normal - r * normal  # onto the palm, one radius to the back
            state.set_local(f"mcp_{f}_{s}", role, p)
            session.use(f"mcp_{s}")
        palm = sorted((k for k in touches if k.startswith("palm_") and k.endswith(f"_{s}")),
                      key=lambda k: int(k.split("_")[1]))
        if len(palm) >= 3:
            pts = {k: touches[k].local for k in palm}
            if plane is not None:
                point, normal = plane
                pts = {k: v - ((v - point) @ normal) * normal for k, v in pts.items()}
            state.palm_points[s] = pts
            session.use(f"palm_{s}")


def digits(session: Session, state: State) -> None:
    """PIP / DIP on the line from the finger base to the extended tip (capsule digits)."""
    for s in sk.SIDES:
        role = f"hand_{s}"
        for f in sk.FINGERS:
            mcp = state.local.get(f"mcp_{f}_{s}", {}).get(role)
            tip = state.local.get(f"tip_{f}_{s}", {}).get(role)
            if mcp is None or tip is None:
                continue
            a, b = PHALANX_FRACTIONS[f]
            state.set_local(f"pip_{f}_{s}", role, mcp + a * (tip - mcp))
            state.set_local(f"dip_{f}_{s}", role, mcp + b * (tip - mcp))
        if any(f"pip_{f}_{s}" in state.local for f in sk.FINGERS):
            session.default(f"pip_dip_{s}", "on the base-to-tip line at phalanx fractions (Buchholz 1992)")
