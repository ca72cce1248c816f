"""T-pose (AvatarGo §3.2-3.3): device roles from the T-pose when the recording leaves
them unset, eye height = HMD height, and the exact offsets v0(TJ) = p0(J) - p0(T), R0(T), R0(J)
for every tracker / joint pair at the reference time (eq. 2-3 use them to animate)."""

from __future__ import annotations

import numpy as np

from ..body.bodymodel import Offset
from ..core import transforms as tf
from ..recording.roles import apply_roles
from .common import Session


def identify_roles(session: Session) -> None:
    rec = session.rec
    if not any(d.role is None for d in rec.devices) or not rec.segments_of("tpose"):
        return
    before = {d.name: d.role for d in rec.devices}
    apply_roles(rec)
    found = {d.name: d.role for d in rec.devices if before.get(d.name) is None and d.role}
    if found:
        session.use("tpose", None)
        session.quality.setdefault("roles", {}).update(found)


def device_poses(session: Session) -> dict[str, list[float]]:
    """{role: [px, py, pz, qw, qx, qy, qz]} at the reference time."""
    out = {}
    roles = [d.role for d in session.rec.devices if d.role]
    for role in dict.fromkeys(roles + [r for r in ("hand_l", "hand_r") if session.has(r)] + list(session.estimated)):
        try:
            p, q = session.ref_pose(role)
        except Exception:  # never tracked: not in the T-pose
            continue
        out[role] = [round(float(v), 7) for v in np.concatenate([p, q])]
    return out


def offsets(session: Session, joints: dict, bone_quats: dict[str, np.ndarray], joint_bone: dict[str, str]
            ) -> dict[str, Offset]:
    """AvatarGo §3.3: per joint with a tracker, v0 = p0(J) - p0(T), R0(T), R0(J)."""
    out = {}
    for name, j in joints.items():
        if j.frame is None or name not in joint_bone:
            continue
        p, q = session.ref_pose(j.frame)
        out[name] = Offset(j.frame, np.asarray(j.world) - p, tf.quat_normalize(q),
                           tf.quat_normalize(bone_quats[joint_bone[name]]))
    return out
