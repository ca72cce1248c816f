"""Sample avatars: the shared glb files load as armature + skinned mesh, and the procedural
avatar's mesh has exactly the surface its spec says."""

import json

import bpy
import numpy as np
from mathutils import Vector
from mathutils.bvhtree import BVHTree

from bodycal_addon.core import paths
from sample_rigs import procedural

rigs = paths.sample_rigs()


def test_glb_avatars_load_as_named_armature_and_skinned_mesh(avatar_files):
    for path in avatar_files:
        name = path.stem
        arm, mesh = rigs.load_glb_avatar(path)
        assert arm.name == name and mesh.name == f"{name}_mesh"
        assert bpy.data.collections[name].objects[:] == [arm, mesh] or \
            set(bpy.data.collections[name].objects) == {arm, mesh}
        assert any(m.type == "ARMATURE" and m.object == arm for m in mesh.modifiers)
        assert len(arm.data.bones) == 53
    assert {o.type for o in bpy.data.objects} == {"ARMATURE", "MESH"}  # the stray icosphere is gone
    assert len(bpy.data.objects) == 10


def test_glb_bone_heads_match_the_published_skeleton(data_dir, avatar_files):
    path = avatar_files[0]
    arm, _ = rigs.load_glb_avatar(path)
    ref = json.loads(path.with_suffix("").with_suffix(".skeleton.json").read_text())["bones"]
    for name, b in ref.items():
        head = arm.matrix_world @ arm.data.bones[name].head_local
        assert (head - Vector(b["head"])).length < 1e-3, name


def test_procedural_capsule_vertices_lie_on_the_true_radius():
    spec = procedural.build_spec(scale=1.1)
    for part in spec.parts:
        if not part.name.startswith("capsule_"):
            continue
        truth = spec.truth["capsules"][part.bone]
        a, b, r = truth["head"], truth["tail"], truth["radius"]
        ab = b - a
        t = np.clip(((part.vertices - a) @ ab) / (ab @ ab), 0, 1)
        d = np.linalg.norm(part.vertices - (a + t[:, None] * ab), axis=1)
        np.testing.assert_allclose(d, r, atol=1e-9)


def test_procedural_avatar_in_blender_raycasts_to_the_known_radius():
    arm, mesh, spec = rigs.build_procedural_avatar(scale=1.0)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    bvh = BVHTree.FromObject(mesh.evaluated_get(depsgraph), depsgraph)
    truth = spec.truth["capsules"]["upperarm_l"]
    mid = (truth["head"] + truth["tail"]) / 2
    # Straight forward (-Y) from the middle of the upper arm: the hit is one radius away (facets of
    # a 48-gon sit at most r(1 - cos(pi/48)) = 0.1 mm inside the true circle).
    hit, _normal, _index, dist = bvh.ray_cast(Vector(mid), Vector((0, -1, 0)))
    assert hit is not None
    assert abs(dist - truth["radius"]) < 2e-4
    # The torso ellipsoid's front at the centre height.
    torso = spec.truth["torso"]
    hit, _n, _i, dist = bvh.ray_cast(Vector(torso["center"]), Vector((0, -1, 0)))
    assert abs(dist - torso["semi_axes"][1]) < 1e-3
    # Bone local +X is the flexion axis: the left forearm flexes its tail forward (-Y).
    bone = arm.data.bones["lowerarm_l"]
    assert bone.matrix_local.col[2].to_3d().dot(Vector((0, -1, 0))) > 0.99
    knee = arm.data.bones["calf_l"]
    assert knee.matrix_local.col[2].to_3d().dot(Vector((0, 1, 0))) > 0.99


def test_a_pose_lowers_the_arms():
    spec = procedural.build_spec(arm_drop_deg=45)
    b = spec.bones["lowerarm_l"]
    d = (b.tail - b.head) / np.linalg.norm(b.tail - b.head)
    np.testing.assert_allclose(d, [np.cos(np.pi / 4), 0, -np.sin(np.pi / 4)], atol=1e-9)


def test_procedural_scale_scales_every_bone_and_surface():
    one, half = procedural.build_spec(scale=1.0), procedural.build_spec(scale=0.5)
    for name, b in one.bones.items():
        np.testing.assert_allclose(half.bones[name].head, 0.5 * b.head, atol=1e-12, err_msg=name)
        np.testing.assert_allclose(half.bones[name].tail, 0.5 * b.tail, atol=1e-12, err_msg=name)
    for p1, p2 in zip(one.parts, half.parts):
        np.testing.assert_allclose(p2.vertices, 0.5 * p1.vertices, atol=1e-12, err_msg=p1.name)
