"""Animation transfer between characters (DESIGN.md §8): any animated humanoid
is the performer, any avatar the target, through the same pipeline as a tracker recording
(`pipeline.run_source` with a `pose_source.AnimationSource`).

The source character is measured like an avatar (its BodyModel from the avatar surface
calibration, or `avatar/estimate.estimate_surface` for a bare skeleton) and posed by its own action
(pose-bone values, Blender's FK). Placement: the source's motion is taken relative to where its
armature object stands and faces at rest (its play area, placement.py's `object` rule applied to
the source), and played relative to the target's object (`object`) or in the source's world
coordinates on the target's floor (`performer`).
"""

from __future__ import annotations

import copy
from collections.abc import Callable

import numpy as np

from ..avatar.estimate import sole_depth
from ..body.animation import AvatarAnimation
from ..body.bodymodel import BodyModel
from .avatar_pose import AvatarRig
from .methods import check_method
from .pipeline import PreparedTake, run_source
from .placement import check_placement, play_area_to_world, rig_matrix, transformed_avatar
from .pose_source import AnimationSource


def source_in_play_area(source: BodyModel, placement: str = "object") -> tuple[BodyModel, np.ndarray]:
    """The source model moved into its play area, and the (4, 4) that moved it."""
    check_placement(placement)
    if placement == "performer":
        return source, np.eye(4)
    to_area = np.linalg.inv(play_area_to_world(source, "object"))
    if np.allclose(to_area, np.eye(4), atol=1e-12):
        return source, to_area
    return transformed_avatar(source, to_area), to_area


def transfer(source: BodyModel, basis: np.ndarray, locations: np.ndarray, time: np.ndarray, avatar: BodyModel,
             method: str = "egocentric", *, chunk_frames: int = 2000, progress: Callable[[float], None] | None = None,
             cancel: Callable[[], bool] | None = None, plant_feet: bool = True, placement: str = "object",
             name: str | None = None) -> AvatarAnimation:
    """The source character's animation (`basis` (F, N, 4) pose-bone quaternions in the order of
    its rig's bone names, `locations` (F, N, 3) or the pelvis bone's (F, 3), `time` (F,) s) on
    `avatar`, by `method` (egocentric or rotations). Bad inputs raise one BodyCalError."""
    check_method(method, "animation")
    moved, _ = source_in_play_area(source, placement)
    src = AnimationSource(moved, basis, locations, time, name or source.name)
    anim = run_source(src, avatar, method, chunk_frames=chunk_frames, progress=progress, cancel=cancel,
                      plant_feet=plant_feet, placement=placement)
    if source.calibration.get("method") == "estimated":
        anim.notes.append(f"{source.name}: body surface estimated from its bone lengths (no mesh)")
    return anim


def prepare_transfer(source: BodyModel, basis: np.ndarray, locations: np.ndarray, time: np.ndarray,
                     avatar: BodyModel, method: str = "egocentric", *, plant_feet: bool = True,
                     placement: str = "object", name: str | None = None) -> PreparedTake:
    """`transfer`'s take prepared once, to be solved a few frames at a time (PreparedTake)."""
    check_method(method, "animation")
    moved, _ = source_in_play_area(source, placement)
    return PreparedTake(AnimationSource(moved, basis, locations, time, name or source.name), avatar, method,
                        plant_feet=plant_feet, placement=placement)


FLOOR_PERCENTILE = 5.0  # of the clip's lowest sole height per frame: where a bare skeleton's floor is


def stand_on_floor(model: BodyModel, locations: np.ndarray, basis: np.ndarray, time: np.ndarray
                   ) -> tuple[BodyModel, np.ndarray, float, float]:
    """A bare skeleton stood on its floor (a BVH says nothing of where its floor is: its rest pose
    hangs from the hips at the origin, and its motion's height is the capture's):
    - the rest pose is lifted so its lowest sole point is at the armature object's origin height
      (the floor of its play area; the sole from the estimated body);
    - the motion is moved up or down so that the lowest sole point of each frame is on that floor
      in the clip's lower FLOOR_PERCENTILE (its feet touch the floor, whatever the capture's zero),
      through the parentless bones' pose locations (F, N, 3).
    Returns (model, locations, the rest's lift, the motion's lift) in metres."""

    world = rig_matrix(model)
    depth = {s: sole_depth(model, s) for s in ("l", "r")}
    sole = min(float(model.joints[f"ankle_{s}"].world[2]) - depth[s] for s in ("l", "r"))
    lift = float(world[2, 3] - sole)
    out = copy.deepcopy(model)
    for j in out.joints.values():
        j.world = np.asarray(j.world, float) + [0.0, 0.0, lift]
    step = np.linalg.solve(world[:3, :3], [0.0, 0.0, lift])  # armature units
    for b in out.extra["rig"]["bones"].values():
        b["head"] = (np.asarray(b["head"], float) + step).tolist()
        b["tail"] = (np.asarray(b["tail"], float) + step).tolist()
    rig = AvatarRig.from_model(out)
    roots = np.flatnonzero(rig.parent < 0)
    locations = np.array(locations, float, copy=True)
    for i in roots:
        locations[:, i] -= rig.rest[i].T @ step
    # The motion: the rest lift kept every posed bone in place; now the clip's floor.
    src = AnimationSource(out, basis, locations, time)
    low = np.min([src.ankle(s)[:, 2] - depth[s] for s in ("l", "r")], axis=0)
    motion = float(world[2, 3] - np.percentile(low, FLOOR_PERCENTILE))
    step = np.linalg.solve(world[:3, :3], [0.0, 0.0, motion])
    for i in roots:
        locations[:, i] += rig.rest[i].T @ step
    return out, locations, lift, motion
