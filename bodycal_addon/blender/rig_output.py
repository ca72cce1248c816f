"""What the bake keys on the armature besides the engine's own pose bones (issue 14): where the
travel goes (root motion, `retarget/root_motion.py`) read off the armature object's rest pose.
"""

from __future__ import annotations

import numpy as np

from ..animation import AvatarAnimation
from ..retarget.root_motion import RootRest, apply_root_motion, check_root_motion
from . import avatar_rig


def _rest(obj, name: str) -> tuple[np.ndarray, np.ndarray]:
    b = obj.data.bones[name]
    return np.array([b.matrix_local[i][:3] for i in range(3)], float), np.array(b.head_local[:], float)


def root_bone_of(obj, pelvis: str) -> str | None:
    """The bone map's `root` bone when it is an ancestor of `pelvis` (it carries the travel)."""
    root = avatar_rig.bone_map_for(obj).bones.get("root")
    if not root or root == pelvis or root not in obj.data.bones or pelvis not in obj.data.bones:
        return None
    parent = obj.data.bones[pelvis].parent
    while parent is not None:
        if parent.name == root:
            return root
        parent = parent.parent
    return None


def root_rest(obj, anim: AvatarAnimation) -> RootRest:
    bm = avatar_rig.bone_map_for(obj)
    lin = np.array(obj.matrix_world, float)[:3, :3]
    up = np.linalg.solve(lin, np.array([0.0, 0.0, 1.0]))
    lateral = np.zeros(3)
    if bm.bones.get("thigh_l") in obj.data.bones and bm.bones.get("thigh_r") in obj.data.bones:
        lateral = _rest(obj, bm.bones["thigh_l"])[1] - _rest(obj, bm.bones["thigh_r"])[1]
    root = root_bone_of(obj, anim.root_bone)
    rm, rh = _rest(obj, root) if root else (None, None)
    pm, ph = _rest(obj, anim.root_bone)
    return RootRest(root, rm, rh, pm, ph, up / np.linalg.norm(up), lateral, lin)


def with_root_motion(anim: AvatarAnimation, obj, mode: str) -> AvatarAnimation:
    check_root_motion(mode)
    if mode == "pelvis":
        return anim
    return apply_root_motion(anim, root_rest(obj, anim), mode)
