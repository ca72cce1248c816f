"""Checks of an avatar model against the procedural avatar's exact shapes (capsules, torso
ellipsoid, skull sphere, palm and sole boxes), shared by the Blender raycast tests and the engine's
analytic-caster tests. No bpy."""

from __future__ import annotations

import numpy as np

from bodycal_addon.body import skeleton as sk
from bodycal_addon.body import surface_layout as sl
from sample_rigs.procedural import torso_surface_distance

TOL = 0.002  # metres: "within 2 mm of the known truth"
CANON = {"forearm": "lowerarm", "shin": "calf"}


def proc_bone(canonical: str) -> str:
    """Procedural (Unreal-style) bone name of a canonical capsule bone."""
    parts = canonical.split("_")
    if parts[0] in sk.FINGERS:
        return f"{parts[0]}_{int(parts[1]):02d}_{parts[2]}"
    return f"{CANON.get(parts[0], parts[0])}_{parts[1]}"


def point_world(model, element_id, point):
    e = model.element(element_id)
    p = e.points[point]
    b = sk.BONE_BY_NAME[p.bone]
    h, t = model.joints[b.head].world, model.joints[b.tail].world
    return h + sl.bone_frame(h, t, model.bones[p.bone].right) @ p.local


def skull_world(model):
    e = model.element("sphere:skull")
    h, t = model.joints["skull_base"].world, model.joints["head"].world
    return h + sl.bone_frame(h, t, model.bones["head"].right) @ e.center, e.radius


def check_truth(model, spec, scale=1.0):
    truth = spec.truth
    # Capsules: every limb bone and phalanx. thumb_1's head half sits inside the palm box, so the
    # surface there is the box, not the capsule: only its tail radius is compared.
    for bone in sl.CAPSULE_BONES:
        r = truth["capsules"][proc_bone(bone)]["radius"] * scale
        info = model.bones[bone]
        assert abs(info.radius_tail - r) < TOL, (bone, info.radius_tail, r)
        if not bone.startswith("thumb_1"):
            assert abs(info.radius_head - r) < TOL, (bone, info.radius_head, r)
            # the procedural capsules are centred on their bones: no axis offset is measured
            assert np.abs(model.element(f"capsule:{bone}").axis_offsets()).max() < TOL, bone
    centre, radius = skull_world(model)
    assert np.linalg.norm(centre - truth["skull"]["center"]) < TOL
    assert abs(radius - truth["skull"]["radius"]) < TOL
    torso = np.array([point_world(model, "mesh:torso", p) for p in sl.TORSO_POINTS])
    d = torso_surface_distance(torso, truth["torso"]["center"], truth["torso"]["semi_axes"])
    assert d.max() < TOL, dict(zip(sl.TORSO_POINTS, d))
    for s in sk.SIDES:
        palm = truth["palms"][s]
        pts = np.array([point_world(model, f"mesh:palm_{s}", p) for p in model.element(f"mesh:palm_{s}").points])
        assert len(pts) >= 4
        depth = (pts - palm["origin"]) @ palm["normal_down"]
        assert np.all(np.abs(depth - palm["half_thickness"]) < TOL), depth
        sole = truth["soles"][s]
        pts = np.array([point_world(model, f"mesh:sole_{s}", p) for p in model.element(f"mesh:sole_{s}").points])
        assert len(pts) >= 4
        assert np.all(np.abs(pts[:, 2] - sole["z"]) < TOL)
        x0, x1 = sorted((sole["x"], sole["x2"]))
        assert np.all((pts[:, 0] > x0 - TOL) & (pts[:, 0] < x1 + TOL))
        assert np.all((pts[:, 1] > sole["y"][0] - TOL) & (pts[:, 1] < sole["y"][1] + TOL))
        # The sole outline spans the box: heel and toe ends and both sides are reached.
        assert np.ptp(pts[:, 1]) > (sole["y"][1] - sole["y"][0]) - 2 * TOL
        assert np.ptp(pts[:, 0]) > (x1 - x0) - 2 * TOL


def check_layout(model):
    assert sorted(e.id for e in model.surface) == sorted(sl.element_ids())
    for e in model.surface:
        for a, b, c in e.triangles:
            assert {a, b, c} <= set(e.points)
    torso = model.element("mesh:torso")
    assert set(torso.points) == set(sl.TORSO_POINTS)
    assert set(model.element("mesh:jaw").points) == set(sl.JAW_POINTS)
    for s in sk.SIDES:
        assert len(model.element(f"mesh:palm_{s}").points) >= 4
        assert len(model.element(f"mesh:sole_{s}").points) >= 4
