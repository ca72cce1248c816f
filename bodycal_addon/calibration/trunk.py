"""Trunk (Delahaye 2023, appendix B, "Trunk Calibration"; DESIGN.md §3), from the `stand` step.

Sacrum: origin = midpoint of the hips (both hips symmetric about it), width = hip distance. The
spine root sits 0.10 m above the sacrum origin and 0.05 m behind it (sacrum height 10.9-11.4 cm,
LHS*20), stored in the pelvis (back) tracker's frame. Twelve vertebrae of equal length run from
the spine root to the skull base; the clavicles link the top of vertebra 5 to the shoulders.
Torso touches (palm centre) are stored in the nearest vertebra's frame; the four belly centre
points default to the bilinear interpolation of the belly corners.
"""

from __future__ import annotations

import numpy as np

from ..body import skeleton as sk
from ..body.surface_layout import BELLY_CENTRE, TORSO_POINTS, belly_centre_points
from ..core import transforms as tf
from . import touches as T
from .common import Session, State

SPINE_ROOT_UP = 0.10
SPINE_ROOT_BACK = 0.05
UP = np.array([0.0, 0.0, 1.0])


def sacrum(session: Session, state: State) -> None:
    """Pelvis joint and spine root in the pelvis tracker's frame (when the hips are known there)."""
    hl, hr = (state.local.get(f"hip_{s}", {}).get("pelvis") for s in sk.SIDES)
    if hl is None or hr is None:
        return
    origin = 0.5 * (hl + hr)
    state.set_local("pelvis", "pelvis", origin)
    width = float(np.linalg.norm(hl - hr))
    segs = session.rec.segments_of("stand")
    t = 0.5 * (segs[0].start + segs[0].end) if segs else session.reference_time
    p, q = session.pose_at("pelvis", t)
    world_l, world_r, world_o = (tf.transform_points(p, q, v) for v in (hl, hr, origin))
    left = world_l - world_r
    left[2] = 0.0
    left /= max(np.linalg.norm(left), 1e-9)
    forward = np.cross(left, UP)
    root = world_o + SPINE_ROOT_UP * UP - SPINE_ROOT_BACK * forward
    state.set_local("spine_root", "pelvis", tf.inverse_transform_points(p, q, root))
    state.extra["sacrum_width"] = width
    state.extra["sacrum_height_standing"] = float(world_o[2])
    session.use("stand" if segs else "sacrum", {"sacrum_width_mm": round(width * 1000, 1)})


def torso_touches(session: Session, state: State) -> None:
    """Torso points (touched with the palm centre) in the world at the reference time."""
    touches = T.collect(session, state, TORSO_POINTS)
    for k, t in touches.items():
        state.torso_world[k] = session.to_world(t.role, t.local)
    if touches:
        session.use("torso", {"points": len(touches), "spread_mm": round(max(t.spread_mm for t in touches.values()),
                                                                            2)})


def complete_torso(session: Session, state: State) -> None:
    w = state.torso_world
    corners = ("belly_ul", "belly_ur", "belly_ll", "belly_lr")
    if all(c in w for c in corners) and not all(c in w for c in BELLY_CENTRE):
        for k, v in belly_centre_points(*(w[c] for c in corners)).items():
            if k not in w:
                w[k] = v
                session.default(k, "bilinear interpolation of the four belly corners")


def spine(world: dict) -> None:
    """Vertebra joints of equal length from the spine root to the skull base; clavicle roots at
    the top of vertebra 5."""
    root, top = world["spine_root"], world["skull_base"]
    for k in range(1, sk.SPINE_COUNT + 1):
        world[sk.spine_joint(k)] = root + (k / sk.SPINE_COUNT) * (top - root)
    for s in sk.SIDES:
        world[f"clavicle_{s}"] = world[sk.spine_joint(sk.CLAVICLE_VERTEBRA)].copy()
