"""Wrists and ankles from the recording's own motion (beyond Delahaye 2023, whose wrists and ankles come
from touches only): with a tracker on the forearm (shin) and the hand device (foot tracker), the
wrist (ankle) is the point fixed in both frames over every frame the two are tracked together,
the performance included (`geometry.fit_rigid_point`). The touches, when recorded, win.

The ankle turns mostly about one axis and a wrist may too: when the data leave the point free
along that axis (geometry.fit_rigid_point), it is put where the knee (elbow) is along it, the shin
(forearm) running from one joint to the other square to the distal joint's axis. A point the
motion determines is kept in the limb tracker's frame too, for `limbs.straighten`. Without the
limb tracker, or with too little motion at the joint, nothing is measured and the defaults apply
(defaults.py), reported as usual.
"""

from __future__ import annotations

from ..body import skeleton as sk
from ..core import transforms as tf
from ..core.errors import BodyCalError
from ..core.geometry import fit_rigid_point
from .common import Session, State

MAX_FRAMES = 4000  # a long take is thinned to this many frames (the fit is over a few seconds of motion)
EFFECTORS = {"wrist": ("forearm", "hand", "elbow"), "ankle": ("shin", "foot", "knee")}


def effectors(session: Session, state: State) -> None:
    for s in sk.SIDES:
        for joint, (limb, device, hinge) in EFFECTORS.items():
            name = f"{joint}_{s}"
            limb_role, dev_role = f"{limb}_{s}", f"{device}_{s}"
            if name in state.local or not (session.has(limb_role) and session.has(dev_role)):
                continue
            lp, lq, lv = session.pose(limb_role)
            dp, dq, dv = session.pose(dev_role)
            idx = (lv & dv).nonzero()[0]
            idx = idx[::max(1, len(idx) // MAX_FRAMES)]
            above = state.local.get(f"{hinge}_{s}", {}).get(limb_role)
            try:
                fit = fit_rigid_point(tf.quat_to_matrix(lq[idx]), lp[idx], tf.quat_to_matrix(dq[idx]), dp[idx],
                                      name=f"{name} from the motion", robust=session.robust, along_axis_as=above)
            except BodyCalError:
                continue  # not enough motion at the joint: the default stands
            state.set_local(name, dev_role, fit.local_b)
            if not fit.weak_axis:  # limbs.straighten places the hinge above with it
                state.extra.setdefault("effector_in_limb", {})[name] = (limb_role, fit.local_a)
            q = {"rms_mm": round(fit.rms * 1000, 3), "kept": fit.kept, "of": fit.of,
                 "range_deg": round(fit.range_deg, 1), "frames": f"{dev_role} and {limb_role}"}
            if fit.weak_axis:
                q["along_axis"] = f"{hinge}_{s}"
            session.use(f"{name} from the motion", q)
