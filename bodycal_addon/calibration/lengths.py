"""Limb lengths from the knee and elbow touches of a six-device user (DESIGN.md §3, "Touches with
six devices"), beyond Delahaye 2023, whose knee and elbow touches are taken in the shin / forearm
tracker's frame.

Without a shin (forearm) tracker the knee (elbow) is fixed in no tracked frame: the foot (hand)
device turns at the ankle (wrist). But its two ends are: the hip in the pelvis tracker's frame
(its swing) and the ankle in the foot tracker's (its touches, else the default); the shoulder in
the trunk's and the wrist in the controller's. A touch on the knee's inner or outer side is a
point one knee radius r from the knee along its axis, so its squared distance from the hip at
that moment is L1^2 + r^2 +- 2 r (axis . thigh); the mean over the inner and outer touches
cancels the last term (an axis a few degrees off square to the bone): L1 = sqrt(mean d^2 - r^2),
and the same with the ankle gives the shin. r is the default radius: 10 mm off changes L by about
a millimetre. The two touches may come at different moments, the leg moving between them (the
knee is not fixed in the foot's frame, so the touches' distance is not its breadth).

What the lengths give (`defaults.py` uses them):
- the knee at the reference pose, between the hip and the ankle in the measured thigh : shin
  ratio, bent `defaults.R["reference_bend_deg"]` (its place across the leg is not observed);
- **Decision**: the hips' height. The foot's swing fixes a hip across the leg well and along it
  barely (a 40° cap trades its centre with its radius: 10-40 mm along the leg on real clips, the
  mean of both legs 5-16 mm); the thigh touch is taken with the thigh raised, square to that
  direction, so the hip's error there hardly changes L1. Standing in the reference pose on both
  feet, each hip is then the two bones' reach above its ankle (the knee bent the default 5°: 0-6°
  changes the reach by 2 mm), and both at the mean of the two heights (`limbs.level_hips`'s
  reason). With the thigh measured from the hip moved, again, until it settles.
- the elbow between the shoulder and the wrist: the forearm from the elbow touches and the wrist;
  the upper arm is what closes the T-pose's reach (the shoulder's place in the trunk's frame is
  the T-pose's, where the arm raised to the side lifts the shoulder girdle: with the arm hanging,
  as it is touched, the shoulder sits a centimetre or two elsewhere).
"""

from __future__ import annotations

import numpy as np

from ..core import transforms as tf
from . import touches as T
from .common import Session, State

SETTLE_PASSES = 4  # hips moved and thighs measured again this many times (it settles in two or three)


def touch_pair(session: Session, state: State, joint: str, side: str, role: str):
    """The inner and outer touches of `joint`_<side> (knee / elbow) taken in `role`'s frame (the
    foot / hand device: the joint not rigid there), or None when one is missing."""
    found = T.collect(session, state, (f"{joint}_in_{side}", f"{joint}_out_{side}"))
    pair = [found.get(f"{joint}_{k}_{side}") for k in ("in", "out")]
    if any(t is None or t.role != role for t in pair):
        return None
    return pair


def _at(session: Session, role: str, local: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """A point fixed in `role`'s frame, in the world, averaged over `frames`."""
    p, q, _ = session.pose(role)
    return tf.transform_points(p[frames], q[frames], local).mean(axis=0)


def length_to(session: Session, pair, role: str, local: np.ndarray, radius: float) -> float | None:
    """The distance from the touched joint's centre to a point fixed in `role`'s frame (`local`):
    sqrt(mean d^2 - r^2) over the pair of touches (module docstring)."""
    d2 = [float(np.sum((t.world - _at(session, role, local, t.frames)) ** 2)) for t in pair]
    v = float(np.mean(d2)) - radius * radius
    return float(np.sqrt(v)) if v > 0 else None


def two_bone_reach(l1: float, l2: float, bend_deg: float) -> float:
    """The distance between the ends of two bones meeting at a joint bent `bend_deg` from straight."""
    b = np.radians(bend_deg)
    return float(np.sqrt(l1 * l1 + l2 * l2 + 2.0 * l1 * l2 * np.cos(b)))


def upper_closing_reach(l2: float, reach: float, bend_deg: float) -> float | None:
    """The upper bone that, with lower bone `l2` and the joint bent `bend_deg`, spans `reach`."""
    b = np.radians(bend_deg)
    disc = reach * reach - (l2 * np.sin(b)) ** 2
    if disc <= 0.0:
        return None
    l1 = float(-l2 * np.cos(b) + np.sqrt(disc))
    return l1 if l1 > 0.5 * l2 else None
