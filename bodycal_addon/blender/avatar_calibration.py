"""Avatar surface calibration in Blender: `calibrate_avatar(arm)` measures the evaluated (deformed,
modifier-applied) mesh of every object skinned to the armature with `mathutils.bvhtree.BVHTree`,
in the rest pose (the armature is shown at rest while the meshes are read, whatever its pose) as
it stands in the scene (object transforms, scale and parenting included: rays are cast in world
space and moved into each mesh object's local space). The rays and the fits are
the engine's (`bodycal_addon/avatar/rays.py`, which documents every ray).

`prepare_survey` reads everything from Blender (the main thread's part); `measure` then casts the
rays on the BVH trees alone, so a worker thread may run it, with progress and Esc (the sidebar's
Calibrate Avatar); `calibrate_avatar` does both.
"""

from __future__ import annotations

import contextlib

import bpy
import numpy as np
from mathutils import Matrix, Vector
from mathutils.bvhtree import BVHTree

from ..avatar.armature import ArmatureReading
from ..avatar.estimate import estimate_surface
from ..avatar.rays import planned_rays, surface_from_rays
from ..body.bodymodel import BodyModel
from ..core.errors import BodyCalError, Cancelled
from ..retarget.placement import avatar_warnings, moved_to
from . import avatar_rig, avatar_storage


def avatar_meshes(arm) -> list:
    """Mesh objects deformed by the armature (modifier) or parented to it."""
    out = []
    for obj in arm.users_scene[0].objects if arm.users_scene else []:
        if obj.type != "MESH":
            continue
        skinned = any(m.type == "ARMATURE" and m.object == arm for m in obj.modifiers)
        if skinned or obj.parent == arm:
            out.append(obj)
    return out


class Caster:
    """First hits of world-space rays on the evaluated meshes (nearest over all meshes)."""

    def __init__(self, meshes, depsgraph):
        self._Vector = Vector
        self.trees = []
        for obj in meshes:
            try:
                m = np.array(obj.evaluated_get(depsgraph).matrix_world, dtype=float)
                tree = BVHTree.FromObject(obj, depsgraph)
            except (RuntimeError, ValueError):  # not in the view layer (excluded, other scene)
                continue
            inv = np.linalg.inv(m)
            self.trees.append((tree, m, inv, Matrix(m.tolist())))
        self.rays = 0
        self.planned = 0
        self.progress = self.cancel = None

    def watch(self, planned: int, progress=None, cancel=None) -> None:
        """Report progress(fraction of `planned` rays cast) and raise Cancelled once cancel() is true."""
        self.planned, self.progress, self.cancel = max(planned, 1), progress, cancel

    def cast(self, origin, direction, max_dist: float = 1e4):
        """(hit world, distance) of the first hit, or None."""
        if self.cancel is not None and self.cancel():
            raise Cancelled()
        best = None
        o4 = np.append(origin, 1.0)
        for tree, m, inv, _ in self.trees:
            ol = inv @ o4
            dl = inv[:3, :3] @ direction
            hit = tree.ray_cast(self._Vector(ol[:3]), self._Vector(dl), 1e6)
            if hit[0] is None:
                continue
            w = m[:3, :3] @ np.array(hit[0]) + m[:3, 3]
            d = float(np.linalg.norm(w - origin))
            if d <= max_dist and (best is None or d < best[1]):
                best = (w, d)
        self.rays += 1
        if self.progress is not None:
            self.progress(min(self.rays / self.planned, 1.0))
        return best

    def nearest(self, point):
        """(closest point world, distance) on the meshes."""
        best = None
        for tree, m, inv, _ in self.trees:
            pl = (inv @ np.append(point, 1.0))[:3]
            loc = tree.find_nearest(self._Vector(pl))[0]
            if loc is None:
                continue
            w = m[:3, :3] @ np.array(loc) + m[:3, 3]
            d = float(np.linalg.norm(w - point))
            if best is None or d < best[1]:
                best = (w, d)
        return best


@contextlib.contextmanager
def in_rest_position(arm):
    """The armature shown in its rest position while its meshes are read (the Armature panel's
    Rest Position), then as it was. The bones are read at rest; a rig opened posed (an imported
    take at its current frame, a character mid-animation) would deform its meshes away from them,
    and the rays from a posed arm's bones missed it."""
    data = arm.data
    before = data.pose_position
    if before != "REST":
        data.pose_position = "REST"
        bpy.context.view_layer.update()
    try:
        yield
    finally:
        if data.pose_position != before:
            data.pose_position = before
            bpy.context.view_layer.update()


def calibrate_avatar(arm, meshes=None, name: str | None = None, depsgraph=None) -> BodyModel:
    """Surface-calibrate the avatar of armature object `arm` (rest pose as it stands)."""
    rig, caster = prepare_survey(arm, meshes, depsgraph)
    return measure(rig, caster, name or arm.name)


def measure(rig: ArmatureReading, caster: Caster, name: str, progress=None, cancel=None) -> BodyModel:
    """The surface calibration's rays and fits on what `prepare_survey` read; reads no Blender
    data. progress(f), f in [0, 1], as the rays are cast; raises Cancelled once cancel() is true."""
    caster.watch(planned_rays(rig), progress, cancel)
    return surface_from_rays(rig, caster, name)


def calibration_report(arm_name: str, model: BodyModel) -> tuple[str, list[str]]:
    """(summary line, warnings) of an avatar calibration: what the sidebar reports."""
    q = model.calibration["quality"]
    rejected = sum(v["rejected"] for v in q.values())
    note = f"; missing: {', '.join(model.calibration['missing'])}" if model.calibration["missing"] else ""
    summary = (f"{arm_name}: {len(model.surface)} surface elements, {sum(v['hit'] for v in q.values())} ray hits "
               f"({rejected} rejected), {model.extra['rig']['rest_pose']}-pose rest{note}")
    return summary, list(avatar_warnings(model))


def prepare_survey(arm, meshes=None, depsgraph=None) -> tuple[ArmatureReading, Caster]:
    """What the surface calibration of armature object `arm` reads from Blender: its rig, and the
    BVH trees of its meshes as they stand in the rest position."""
    rig = avatar_rig.read_rig(arm)
    meshes = list(meshes) if meshes is not None else avatar_meshes(arm)
    if not meshes:
        raise BodyCalError("no mesh is skinned to this armature, nothing to raycast", source=arm.name,
                           hint="add an Armature modifier pointing at it to the avatar's mesh; retarget and "
                                "transfer estimate a bare skeleton's body from its bone lengths")
    with in_rest_position(arm):
        caster = Caster(meshes, depsgraph or bpy.context.evaluated_depsgraph_get())
    if not caster.trees:
        raise BodyCalError(f"none of the meshes skinned to it ({', '.join(o.name for o in meshes)}) is in the "
                           "view layer", source=arm.name, hint="include the avatar's collection in the view layer")
    return rig, caster


def avatar_model_for(arm) -> tuple[BodyModel, bool]:
    """The armature's stored avatar model, brought to where its object stands now (moved, turned
    or scaled since it was calibrated), or a fresh surface calibration (True: not stored yet; the
    bake stores it with the action it makes), or for a bare skeleton (no mesh skinned to it: a game
    skeleton, a BVH) its body estimated from its bone lengths (avatar/estimate.py, DESIGN.md §8;
    False: cheap to make again, and not stored, so that a mesh added later is measured)."""
    if avatar_storage.has_model(arm):
        stored = avatar_storage.load_model(arm)
        return moved_to(stored, np.array(arm.matrix_world, dtype=float)), False
    if not avatar_meshes(arm):
        return estimate_surface(avatar_rig.read_rig(arm), arm.name), False
    return calibrate_avatar(arm), True
