"""Rest frames of the canonical skeleton (DESIGN.md §2): one rule that fixes every bone's frame
from joint positions and hinge axes, used for the user at the reference time and for the avatar at
rest, so that copying a frame copies a pose; and the completion of a body model's joints to the
whole canonical skeleton.

Canonical bone frames follow `surface_layout.bone_frame`: origin at the head joint, +Y along the
bone, +X the bone's right.
"""

from __future__ import annotations

import numpy as np

from ..core.errors import BodyCalError
from ..core.transforms import frame_from_axes, normalize
from . import skeleton as sk
from .bodymodel import BodyModel


def _hinge_right(bones: dict, name: str):
    b = bones.get(name)
    return None if b is None or b.right is None else np.asarray(b.right, float)


def canonical_rest_frames(pos: dict, rights: dict) -> dict[str, np.ndarray]:
    """Canonical frames (..., 3, 3) of every bone from joint positions `pos` {joint: (..., 3)} and
    hinge rights {hinge bone: (..., 3)} (forearm, shin, finger phalanges 2-3). One rule for the
    user and the avatar: the twist of a non-hinge bone is fixed by its child hinge (upper limb
    bones), the palm's lateral line (hand, metacarpals), the hip line (trunk, head) or the trunk's
    forward direction (clavicles, hip shortcuts)."""
    lat = normalize(pos["hip_l"] - pos["hip_r"])
    up = normalize(pos["skull_base"] - pos["pelvis"])
    fwd = normalize(np.cross(lat, up))  # +Z of a trunk frame whose X is the performer's left
    out = {}

    def put(name, head, tail, hint):
        out[name] = frame_from_axes(pos[tail] - pos[head], hint)

    for b in sk.BONES:
        if b.name == "sacrum" or b.name.startswith(("spine_", "shortcut_")) or b.name == "head":
            put(b.name, b.head, b.tail, lat)
        elif b.name.startswith("clavicle_") or b.name.startswith("hip_"):
            put(b.name, b.head, b.tail, fwd)
    for s in sk.SIDES:
        for limb, hinge in (("upperarm", "forearm"), ("thigh", "shin")):
            r = rights.get(f"{hinge}_{s}")
            if r is None:  # T-pose fallback: left arm flexes about -up, right arm about +up; legs about +left
                r = (-up if s == "l" else up) if limb == "upperarm" else lat
            bb = sk.BONE_BY_NAME[f"{limb}_{s}"]
            put(bb.name, bb.head, bb.tail, r)
            hb = sk.BONE_BY_NAME[f"{hinge}_{s}"]
            put(hb.name, hb.head, hb.tail, r)
        put(f"foot_{s}", f"ankle_{s}", f"toe_{s}", rights.get(f"shin_{s}", lat))
        palm_x = normalize(pos[f"mcp_index_{s}"] - pos[f"mcp_pinky_{s}"])
        palm_x = np.where(np.linalg.norm(palm_x, axis=-1, keepdims=True) > 0.5, palm_x,
                          rights.get(f"forearm_{s}", lat))
        put(f"hand_{s}", f"wrist_{s}", f"mcp_middle_{s}", palm_x)
        for f in sk.FINGERS:
            put(f"metacarpal_{f}_{s}", f"wrist_{s}", f"mcp_{f}_{s}", palm_x)
            r2 = rights.get(f"{f}_2_{s}", palm_x)
            r3 = rights.get(f"{f}_3_{s}", r2)
            put(f"{f}_1_{s}", f"mcp_{f}_{s}", f"pip_{f}_{s}", r2)
            put(f"{f}_2_{s}", f"pip_{f}_{s}", f"dip_{f}_{s}", r2)
            put(f"{f}_3_{s}", f"dip_{f}_{s}", f"tip_{f}_{s}", r3)
    return out


def model_rest_frames(model: BodyModel, pos: dict | None = None) -> np.ndarray:
    """(B, 3, 3) canonical frames of a (complete) body model at its reference time / rest pose."""
    pos = pos or {j: model.joints[j].world for j in sk.JOINTS}
    rights = {b: r for b in sk.HINGE_BONES if (r := _hinge_right(model.bones, b)) is not None}
    frames = canonical_rest_frames(pos, rights)
    return np.stack([frames[b.name] for b in sk.BONES])


def complete_joints(model: BodyModel, extra_points: dict | None = None) -> dict[str, np.ndarray]:
    """World position of every canonical joint: the model's own, then what the skeleton implies
    (a vertebra missing -> resampled between spine_root and skull_base; clavicle joint = spine_05;
    finger joints missing -> along the hand). Raises BodyCalError naming the first missing
    required joint."""
    pos = {j: np.asarray(v.world, float) for j, v in model.joints.items() if j in sk.JOINT_INDEX}
    pos.update(extra_points or {})
    for j in sk.REQUIRED_JOINTS:
        if j not in pos:
            raise BodyCalError(f"joint '{j}' is missing", source=model.name, field=f"joints.{j}",
                               hint="recalibrate the body model")
    if any(j not in pos for j in sk.SPINE_JOINTS[1:-1]):
        curve = np.stack([pos["spine_root"], pos["skull_base"]])
        res = sk.resample_polyline(curve, sk.SPINE_COUNT)
        for k, j in enumerate(sk.SPINE_JOINTS):
            pos.setdefault(j, res[k])
    pos.setdefault("spine_12", pos["skull_base"])
    for s in sk.SIDES:
        pos.setdefault(f"clavicle_{s}", pos[sk.spine_joint(sk.CLAVICLE_VERTEBRA)])
        if f"toe_{s}" not in pos:
            ankle = pos[f"ankle_{s}"]
            fwd = normalize(np.cross(pos["hip_l"] - pos["hip_r"], pos["skull_base"] - pos["pelvis"]))
            pos[f"toe_{s}"] = np.array([*(ankle[:2] + 0.15 * fwd[:2]), 0.02])
        w, e = pos[f"wrist_{s}"], pos[f"elbow_{s}"]
        along = normalize(w - e)
        side = normalize(np.cross(along, pos["skull_base"] - pos["pelvis"]))
        for i, f in enumerate(sk.FINGERS):
            off = (i - 2) * 0.02 * side
            for k, jn in enumerate(sk.FINGER_JOINTS):
                pos.setdefault(f"{jn}_{f}_{s}", w + (0.09 + 0.025 * k) * along + off)
    return pos
