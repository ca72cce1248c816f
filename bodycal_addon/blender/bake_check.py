"""Every bake is checked in Blender before it is kept (DESIGN.md §1, "Verified bakes"): the
armature is evaluated at a handful of the new action's frames (its constraints and drivers
included) and the bones that deform the mesh must put the body's main joints where the engine's
animation says. Keys that drive nothing (a Rigify rig's FK controls once a game engine's round
trip has dropped its constraints, a rig whose deforming bones follow other, unkeyed bones) are
one BodyCalError instead of an action whose mesh stands still, and the bake puts everything back.

`plan(anim, avatar)` picks the frames and keeps the engine's joints there (a few numbers: taken
before a long take's arrays are let go); `verify(check, obj, frames)` evaluates and compares.
"""

from __future__ import annotations

from dataclasses import dataclass

import bpy
import numpy as np

from ..body.animation import AvatarAnimation
from ..body.bodymodel import BodyModel
from ..core.errors import BodyCalError

CHECK_JOINTS = ("pelvis", "skull_base", *(f"{j}_{s}" for s in ("l", "r")
                                          for j in ("shoulder", "elbow", "wrist", "hip", "knee", "ankle")))
CHECK_FRAMES = 5
# A joint further than this from the engine's, as a fraction of the avatar's height, is a bake that
# does not play the animation. A faithful bake's joints land within a few mm (keys reduced within
# 0.1 degree, float32, a Rigify rig's FK controls within 1 mm of its DEF- pose), one that drives
# nothing is off by tens of centimetres wherever the body moves.
TOLERANCE = 0.02


class VerificationFailed(BodyCalError):
    """The baked keys do not play the animation on the evaluated rig (one line, as any BodyCalError;
    its own type so a review lists it first, output/review.py)."""


@dataclass
class BakeCheck:
    samples: np.ndarray  # (K,) indices into the animation's frames
    joints: dict[str, np.ndarray]  # canonical joint -> (K, 3) world, where the engine put it
    bones: dict[str, tuple[str, np.ndarray]]  # canonical joint -> (avatar bone it rides on, offset in its rest frame)
    tolerance: float  # m


def plan(anim: AvatarAnimation, avatar: BodyModel) -> BakeCheck | None:
    """The frames to check (in each of CHECK_FRAMES stretches of the take, the one where the
    joints are furthest from the first frame's, relative to the pelvis: a pose that moved is one
    a silent bake would show) and the engine's joints there; None when the animation carries no
    joints to compare with."""
    names = [j for j in CHECK_JOINTS if j in anim.joints_world and j in avatar.joints
             and avatar.joints[j].frame is not None and avatar.joints[j].local is not None]
    if not names or "pelvis" not in names or anim.frame_count == 0:
        return None
    pts = np.stack([np.asarray(anim.joints_world[j], float) for j in names], axis=1)  # (F, J, 3)
    rel = pts - pts[:, names.index("pelvis")][:, None]
    moved = np.nan_to_num(np.linalg.norm(rel - rel[:1], axis=-1).max(axis=1), nan=-1.0)
    edges = np.linspace(0, anim.frame_count, min(CHECK_FRAMES, anim.frame_count) + 1).astype(int)
    samples = np.array([a + int(np.argmax(moved[a:b])) for a, b in zip(edges[:-1], edges[1:]) if b > a])
    world = {j: np.asarray(avatar.joints[j].world, float) for j in avatar.joints}
    height = float(np.linalg.norm(world["skull_base"] - world["pelvis"])
                   + np.linalg.norm(world["pelvis"] - world.get("ankle_l", world["pelvis"])))
    return BakeCheck(samples, {j: pts[samples, k] for k, j in enumerate(names)},
                     {j: (avatar.joints[j].frame, np.asarray(avatar.joints[j].local, float)) for j in names},
                     TOLERANCE * max(height, 0.1))


def deforming_bones(obj) -> set[str] | None:
    """The bones that deform a mesh skinned to `obj` (a vertex group of theirs on a mesh whose
    Armature modifier uses `obj`, and Deform on); None when no mesh is skinned to it."""
    groups, skinned = set(), False
    for mesh in bpy.data.objects:
        if mesh.type != "MESH":
            continue
        if any(m.type == "ARMATURE" and m.object == obj and m.use_vertex_groups for m in mesh.modifiers):
            skinned = True
            groups |= {g.name for g in mesh.vertex_groups}
    if not skinned:
        return None
    return {b.name for b in obj.data.bones if b.use_deform and b.name in groups}


def _twin(obj, bone: str, deforming: set[str]) -> str | None:
    """A deforming bone that stands where `bone` does at rest (same head, same direction): the
    deform twin of a control bone, as Rigify's DEF- bones are of its ORG- bones."""
    b = obj.data.bones[bone]
    head, axis = np.array(b.head_local), np.array(b.matrix_local)[:3, 1]
    tol = 1e-3 * max(b.length, 1e-6)
    for name in sorted(deforming):
        d = obj.data.bones[name]
        same_axis = np.dot(np.array(d.matrix_local)[:3, 1], axis) > 0.999
        if np.linalg.norm(np.array(d.head_local) - head) <= tol and same_axis:
            return name
    return None


def _riders(check: BakeCheck, obj) -> list[tuple[str, str, np.ndarray]]:
    """(joint, bone, offset in the bone's rest frame) to read: each joint's own bone, and, when
    that bone deforms nothing, its deforming twin too (the mesh follows the twin, not the bone)."""
    deforming = deforming_bones(obj)
    out = []
    for joint, (bone, local) in check.bones.items():
        if bone not in obj.data.bones:
            continue
        out.append((joint, bone, local))
        if deforming is not None and bone not in deforming:
            twin = _twin(obj, bone, deforming)
            if twin is not None:
                b, t = obj.data.bones[bone], obj.data.bones[twin]
                rb, rt = np.array(b.matrix_local)[:3, :3], np.array(t.matrix_local)[:3, :3]
                arm_point = np.array(b.head_local) + rb @ local
                out.append((joint, twin, rt.T @ (arm_point - np.array(t.head_local))))
    return out


def verify(check: BakeCheck | None, obj, frames: np.ndarray, in_place: bool = False) -> None:
    """Evaluate `obj` at the scene frames of the check's samples (`frames`: the scene frame of
    every animation frame) and raise one BodyCalError when a joint of a bone that deforms the
    mesh is further than the tolerance from the engine's. `in_place`: the bake took the travel out
    (root motion `in-place`), so the joints are compared about the pelvis. The scene's frame is
    put back."""
    if check is None:
        return
    scene = bpy.context.scene
    was = scene.frame_current, scene.frame_subframe
    riders = _riders(check, obj)
    worst = (0.0, None, None)
    try:
        for k, i in enumerate(check.samples):
            f = float(frames[i])
            scene.frame_set(int(np.floor(f)), subframe=f - np.floor(f))
            mw = np.array(obj.matrix_world)
            got = {}
            for joint, bone, local in riders:
                pm = np.array(obj.pose.bones[bone].matrix)
                point = (mw @ np.append(pm[:3, :3] @ local + pm[:3, 3], 1.0))[:3]
                got.setdefault(joint, []).append((bone, point))
            shift = np.zeros(3)
            if in_place and "pelvis" in got:  # the travel on the floor is gone; the pelvis's height is kept
                shift[:2] = (got["pelvis"][0][1] - check.joints["pelvis"][k])[:2]
            for joint, seen in got.items():
                for bone, point in seen:
                    err = float(np.linalg.norm(point - shift - check.joints[joint][k]))
                    if err > worst[0]:
                        worst = (err, f"{joint} (bone {bone})", f)
    finally:
        scene.frame_set(was[0], subframe=was[1])
    err, what, frame = worst
    if err > check.tolerance:
        raise VerificationFailed(
            f"the baked keys do not move the bones that deform the mesh: at frame {frame:g} the {what} is "
            f"{err * 1000:.0f} mm from the retargeted pose (allowed {check.tolerance * 1000:.0f} mm); nothing was kept",
            source=obj.name,
            hint="constraints or drivers make the deforming bones follow bones the bake does not key: key the "
                 "deforming bones (a Rigify rig: Rigify Target DEF Bones, --rigify-target def) or remove those "
                 "constraints")
