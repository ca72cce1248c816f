"""Per-avatar configuration authoring (DESIGN.md §4; Delahaye 2023, appendix C: "these points remain
calibrated manually once for the targeted avatars"): the stored avatar model shown as editable
helper empties, and read back.

`edit_surface(arm)` puts one empty per surface point (torso, jaw, palms, soles), one per capsule
end (a sphere whose size is the radius: scale it to change the radius; its location is the end
of the capsule's axis, at or near the joint: move it to shift the axis) and one for the skull
sphere (move it, scale it) into the collection "BodyCal Surface <armature>". The helpers are
children of the armature with a parent inverse that cancels the armature's transform at
calibration time, so they follow the armature if it is moved later. `apply_surface_edits(arm)`
reads them back into the model stored on the armature.
"""

from __future__ import annotations

import bpy
import numpy as np
from mathutils import Matrix

from ..body import skeleton as sk
from ..body import surface_layout as sl
from ..body.bodymodel import BodyModel
from ..core.errors import BodyCalError
from . import avatar_storage

ELEMENT_PROP = "bodycal_element"
POINT_PROP = "bodycal_point"  # mesh point name, "head" / "tail" (capsule end) or "center" (sphere)
ARMATURE_PROP = "bodycal_armature"
POINT_SIZE = 0.012  # metres: display size of a point helper


def collection_name(arm) -> str:
    return f"BodyCal Surface {arm.name}"


def helper_collection(arm):
    return bpy.data.collections.get(collection_name(arm))


def _frames(model: BodyModel) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Canonical bone frames (origin, rotation) at calibration time, world."""
    out = {}
    for name, b in model.bones.items():
        if b.head in model.joints and b.tail in model.joints and b.right is not None:
            h, t = model.joints[b.head].world, model.joints[b.tail].world
            out[name] = (h, sl.bone_frame(h, t, b.right))
    return out


def _cal_matrix(model: BodyModel) -> np.ndarray:
    return np.asarray(model.extra.get("rig", {}).get("matrix_world", np.eye(4)), float).reshape(4, 4)


def edit_surface(arm, context=None) -> object:
    """Create (or re-create) the helper empties of the avatar model stored on `arm`."""
    model = avatar_storage.load_model(arm)
    remove_helpers(arm)
    coll = bpy.data.collections.new(collection_name(arm))
    coll[ARMATURE_PROP] = arm.name
    scene = (context or bpy.context).scene
    scene.collection.children.link(coll)
    frames = _frames(model)
    parent_inv = Matrix(np.linalg.inv(_cal_matrix(model)).tolist())
    scale = float(np.linalg.norm(model.joints["skull_base"].world - model.joints["pelvis"].world)) / 0.62

    def add(name, element_id, point, world, size, display="SPHERE"):
        obj = bpy.data.objects.new(f"{arm.name}:{name}", None)
        obj.empty_display_type = display
        obj.empty_display_size = size
        obj[ELEMENT_PROP] = element_id
        obj[POINT_PROP] = point
        obj[ARMATURE_PROP] = arm.name
        coll.objects.link(obj)
        obj.parent = arm
        obj.matrix_parent_inverse = parent_inv
        obj.matrix_basis = Matrix.Translation(tuple(world))
        return obj

    for e in model.surface:
        if e.type == "capsule":
            b = model.bones[e.bone]
            rot = frames[e.bone][1] if e.bone in frames else np.eye(3)
            for (end, joint, r), off in zip((("head", b.head, b.radius_head), ("tail", b.tail, b.radius_tail)),
                                            e.axis_offsets()):
                add(f"{e.id}:{end}", e.id, end, model.joints[joint].world + rot @ off, float(r or POINT_SIZE))
        elif e.type == "sphere":
            h, rot = frames[e.bone]
            add(e.id, e.id, "center", h + rot @ e.center, float(e.radius))
        else:
            for pname, p in e.points.items():
                h, rot = frames[p.bone]
                add(f"{e.id}:{pname}", e.id, pname, h + rot @ p.local, POINT_SIZE * scale, "PLAIN_AXES")
    return coll


def remove_helpers(arm) -> None:
    coll = helper_collection(arm)
    if coll is None:
        return
    for obj in list(coll.objects):
        bpy.data.objects.remove(obj)
    bpy.data.collections.remove(coll)


def apply_surface_edits(arm, remove: bool = False) -> list[str]:
    """Read the helpers back into the model stored on `arm`; returns the ids of the elements
    that changed. Helpers the user deleted leave their point as it was."""
    model = avatar_storage.load_model(arm)
    coll = helper_collection(arm)
    if coll is None or not coll.objects:
        raise BodyCalError("there are no surface helpers to read back", source=arm.name,
                           hint="press Edit Surface first")
    frames = _frames(model)
    cal = _cal_matrix(model)
    to_cal = cal @ np.linalg.inv(np.array(arm.matrix_world, dtype=float))
    changed: set[str] = set()
    by_id = {e.id: e for e in model.surface}
    for obj in coll.objects:
        eid, point = obj.get(ELEMENT_PROP), obj.get(POINT_PROP)
        e = by_id.get(eid)
        if e is None:
            continue
        world = (_helper_cal_matrix(obj, arm, cal, to_cal) @ np.array([0.0, 0.0, 0.0, 1.0]))[:3]
        size = float(obj.empty_display_size) * float(np.mean(np.abs(obj.scale)))
        if e.type == "capsule":
            b = model.bones[e.bone]
            attr = "radius_head" if point == "head" else "radius_tail"
            if not np.isclose(getattr(b, attr) or 0.0, size, atol=1e-7):
                setattr(b, attr, size)
                changed.add(eid)
            if e.bone in frames:
                end = 0 if point == "head" else 1
                offsets = e.axis_offsets()
                off = frames[e.bone][1].T @ (world - model.joints[b.head if end == 0 else b.tail].world)
                if not np.allclose(off, offsets[end], atol=1e-6):
                    offsets[end] = off
                    e.set_axis_offsets(*offsets)
                    changed.add(eid)
        elif e.type == "sphere":
            h, rot = frames[e.bone]
            c = rot.T @ (world - h)
            if not (np.allclose(c, e.center, atol=1e-7) and np.isclose(e.radius, size, atol=1e-7)):
                e.center, e.radius = c, size
                changed.add(eid)
        elif point in e.points:
            p = e.points[point]
            if e.id == "mesh:torso":  # a moved torso point may now be nearest another vertebra
                spine = np.array([model.joints[sk.spine_joint(k)].world for k in range(sk.SPINE_COUNT + 1)])
                p.bone = sl.nearest_vertebra(world, spine)
            h, rot = frames[p.bone]
            local = rot.T @ (world - h)
            if not np.allclose(local, p.local, atol=1e-7):
                p.local = local
                changed.add(eid)
    if changed:
        edited = set(model.calibration.get("edited", [])) | changed
        model.calibration["edited"] = sorted(edited)
        avatar_storage.store_model(arm, model)
    if remove:
        remove_helpers(arm)
    return sorted(changed)


def _helper_cal_matrix(obj, arm, cal: np.ndarray, to_cal: np.ndarray) -> np.ndarray:
    """The helper's matrix in calibration-time world space, from its own (always current)
    matrices rather than matrix_world, which waits for a depsgraph update."""
    basis = np.array(obj.matrix_basis, dtype=float)
    if obj.parent == arm:
        return cal @ np.array(obj.matrix_parent_inverse, dtype=float) @ basis
    if obj.parent is None:
        return to_cal @ basis
    return to_cal @ np.array(obj.matrix_world, dtype=float)
