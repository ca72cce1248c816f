"""Avatar surface calibration by raycasting (DESIGN.md §4) against known truth: the procedural
avatar's exact shapes (capsules, torso ellipsoid, skull sphere, palm and sole boxes) and the
shared MakeHuman avatars."""

from __future__ import annotations

import math

import bpy
import numpy as np
import pytest
import truth_checks as tc
from mathutils import Matrix

from bodycal_addon.blender import avatar_calibration as ac
from bodycal_addon.body import skeleton as sk
from bodycal_addon.body import surface_layout as sl
from bodycal_addon.core.errors import BodyCalError
from sample_rigs import build_procedural_avatar, load_glb_avatar


@pytest.mark.parametrize("kwargs", [{}, {"arm_drop_deg": 40.0}, {"belly": 0.12}], ids=["tpose", "apose", "belly"])
def test_procedural_truth(kwargs):
    arm, _mesh, spec = build_procedural_avatar(**kwargs)
    model = ac.calibrate_avatar(arm)
    tc.check_layout(model)
    tc.check_truth(model, spec)
    assert model.extra["rig"]["rest_pose"] == ("A" if kwargs.get("arm_drop_deg") else "T")
    q = model.calibration["quality"]["capsule:forearm_l"]
    assert q["rays"] == q["hit"] and q["spread_mm"] < 1.0


def test_palm_sole_jaw_torso_winding_points_out_of_the_body():
    arm, _mesh, spec = build_procedural_avatar()
    model = ac.calibrate_avatar(arm)
    for s in sk.SIDES:
        for part, outward in (("palm", spec.truth["palms"][s]["normal_down"]), ("sole", np.array([0, 0, -1.0]))):
            e = model.element(f"mesh:{part}_{s}")
            for a, b, c in e.triangles:
                pa, pb, pc = (tc.point_world(model, e.id, n) for n in (a, b, c))
                assert np.dot(np.cross(pb - pa, pc - pa), outward) > 0, (e.id, a, b, c)
    e = model.element("mesh:jaw")
    for a, b, c in e.triangles:  # away from the skull base
        pa, pb, pc = (tc.point_world(model, e.id, n) for n in (a, b, c))
        assert np.dot(np.cross(pb - pa, pc - pa), (pa + pb + pc) / 3 - model.joints["skull_base"].world) > 0
    e = model.element("mesh:torso")
    for a, b, c in e.triangles[:-1]:  # front triangles face forward (-Y)
        pa, pb, pc = (tc.point_world(model, e.id, n) for n in (a, b, c))
        assert np.cross(pb - pa, pc - pa)[1] < 0, (a, b, c)
    pa, pb, pc = (tc.point_world(model, e.id, n) for n in e.triangles[-1])  # the back triangle faces back (+Y)
    assert np.cross(pb - pa, pc - pa)[1] > 0


def test_transformed_armature_transforms_the_results():
    """Rotated + scaled + translated armature (the mesh is its child): joints move with the
    object, radii scale, local coordinates of surface points scale, nothing else changes."""
    arm, _mesh, _spec = build_procedural_avatar()
    ref = ac.calibrate_avatar(arm)
    s = 1.3
    m = Matrix.Translation((0.4, -1.2, 0.3)) @ Matrix.Rotation(math.radians(35), 4, "Z") @ \
        Matrix.Rotation(math.radians(10), 4, "X") @ Matrix.Scale(s, 4)
    arm.matrix_world = m
    bpy.context.view_layer.update()
    moved = ac.calibrate_avatar(arm)
    mw = np.array(m)
    for j in ("pelvis", "skull_base", "wrist_l", "tip_index_r", "toe_l", "spine_07"):
        expect = (mw @ np.append(ref.joints[j].world, 1.0))[:3]
        assert np.allclose(moved.joints[j].world, expect, atol=1e-5), j
        assert np.allclose(moved.joints[j].local, ref.joints[j].local, atol=1e-6), j
    for b in ("upperarm_l", "thigh_r", "index_2_l"):
        assert moved.bones[b].radius_head == pytest.approx(ref.bones[b].radius_head * s, abs=2e-4)
        assert np.allclose(moved.bones[b].right, mw[:3, :3] @ ref.bones[b].right / s, atol=1e-5)
    for eid in ("mesh:torso", "mesh:jaw", "mesh:palm_l", "mesh:sole_r"):
        for name, p in ref.element(eid).points.items():
            assert np.allclose(moved.element(eid).points[name].local, p.local * s, atol=2e-4), (eid, name)
    assert moved.element("sphere:skull").radius == pytest.approx(ref.element("sphere:skull").radius * s, abs=2e-4)
    assert np.allclose(moved.extra["rig"]["matrix_world"], mw, atol=1e-6)
    # the rig is stored in armature space: unchanged by the object transform
    assert moved.extra["rig"]["bones"]["head"] == ref.extra["rig"]["bones"]["head"]


def test_a_posed_armature_is_calibrated_at_rest():
    """A rig opened posed (an imported take at its current frame, a character being animated) is
    calibrated as at rest: the same model, and the armature shown posed again afterwards. Read
    posed, the rays from the raised arm's bones missed its mesh."""
    arm, _mesh, _spec = build_procedural_avatar()
    ref = ac.calibrate_avatar(arm).to_dict()
    for bone, euler in (("upperarm_l", (0.0, 0.0, math.radians(50))), ("thigh_r", (math.radians(40), 0.0, 0.0)),
                        ("spine_02", (0.3, 0.2, -0.1))):
        pb = arm.pose.bones[bone]
        pb.rotation_mode = "XYZ"
        pb.rotation_euler = euler
    bpy.context.view_layer.update()
    assert ac.calibrate_avatar(arm).to_dict() == ref
    assert arm.data.pose_position == "POSE"
    assert tuple(arm.pose.bones["upperarm_l"].rotation_euler) == pytest.approx((0.0, 0.0, math.radians(50)))


def test_parented_mesh_with_its_own_transform():
    """The mesh unparented and moved by its own object transform (mesh data moved back): the
    evaluated surface is unchanged, so the measurement is too."""
    arm, mesh, spec = build_procedural_avatar()
    ref = ac.calibrate_avatar(arm)
    mesh.parent = None
    off = Matrix.Translation((0.0, 0.5, 0.0)) @ Matrix.Rotation(math.radians(90), 4, "Z") @ Matrix.Scale(2.0, 4)
    mesh.data.transform(off.inverted())
    mesh.matrix_world = off
    bpy.context.view_layer.update()
    model = ac.calibrate_avatar(arm)
    tc.check_truth(model, spec)
    assert model.bones["thigh_l"].radius_head == pytest.approx(ref.bones["thigh_l"].radius_head, abs=1e-4)


def test_glb_avatars_every_element_found(avatar_files):
    for path in avatar_files:
        bpy.ops.wm.read_homefile(use_empty=True)
        arm, mesh = load_glb_avatar(path)
        model = ac.calibrate_avatar(arm)
        tc.check_layout(model)
        assert model.extra["rig"]["rest_pose"] == "A", path.name
        caster = ac.Caster([mesh], bpy.context.evaluated_depsgraph_get())
        # every mesh point lies on the skin (they are ray hits, transformed through the frames)
        for e in model.surface:
            for name in e.points:
                w = tc.point_world(model, e.id, name)
                if e.id.startswith("mesh:sole"):
                    continue  # projected onto the floor plane
                assert caster.nearest(w)[1] < 1e-4, (path.name, e.id, name)
        for b in sl.CAPSULE_BONES:
            info = model.bones[b]
            assert 0.003 < info.radius_head < 0.12 and 0.003 < info.radius_tail < 0.12, (path.name, b)
        # limbs are thicker than fingers, thighs than shins (taper measured, not assumed)
        assert model.bones["thigh_l"].radius_head > model.bones["shin_l"].radius_head > model.bones[
            "index_1_l"].radius_head
        centre, radius = tc.skull_world(model)
        assert 0.06 < radius < 0.13, path.name
        # The capsule's surface follows the skin all around, front included, though the femur
        # runs behind the middle of the thigh: median within 6 mm (bone-centred capsules: 10-17 mm,
        # 30 mm under the thigh's front); the worst point, where a calf or thigh is more oval than
        # round, within 18 mm.
        for b in ("thigh_l", "thigh_r", "upperarm_l", "forearm_r", "shin_l"):
            _capsule_hugs_the_skin(model, caster, b, path.name)
        for side in sk.SIDES:
            # the palm is on the side the (slightly curled) rest fingers bend to
            J = {k: v.world for k, v in model.joints.items()}
            w, mcp, tip = J[f"wrist_{side}"], J[f"mcp_middle_{side}"], J[f"tip_middle_{side}"]
            d = (mcp - w) / np.linalg.norm(mcp - w)
            curl = (tip - mcp) - np.dot(tip - mcp, d) * d
            palm = f"mesh:palm_{side}"
            pc = np.mean([tc.point_world(model, palm, n) for n in model.element(palm).points], axis=0)
            off = (pc - w) - np.dot(pc - w, d) * d
            assert np.dot(curl, off) / np.linalg.norm(curl) / np.linalg.norm(off) > 0.8, (path.name, side)
        q = model.calibration["quality"]
        assert set(q) == set(sl.element_ids())


def test_a_thighs_front_is_skin_not_an_outlier(avatar_files):
    """A thigh's front (the quadriceps) stands 5-8 mm beyond the circle through the rest of its
    ring; the rings' outlier rule dropped it (3-17 hits a thigh on the shared avatars, 17 on the
    child), its capsule sat ~8 mm under the skin there and a palm on the thigh sank that deep. Every
    hit of the legs' rings is their skin; the circle is fitted through all of them."""
    for path in avatar_files:
        bpy.ops.wm.read_homefile(use_empty=True)
        arm, _mesh = load_glb_avatar(path)
        q = ac.calibrate_avatar(arm).calibration["quality"]
        for b in ("thigh_l", "thigh_r", "shin_l", "shin_r"):
            assert q[f"capsule:{b}"]["rejected"] == 0 and q[f"capsule:{b}"]["hit"] == q[f"capsule:{b}"]["rays"], (
                path.name, b, q[f"capsule:{b}"])


def _capsule_hugs_the_skin(model, caster, bone, label, median_tol=0.006, worst_tol=0.018):
    info = model.bones[bone]
    h, t = model.joints[info.head].world, model.joints[info.tail].world
    rot = sl.bone_frame(h, t, info.right)
    off = model.element(f"capsule:{bone}").axis_offsets()
    gaps = []
    for st in (0.4, 0.5, 0.6):
        centre = h + st * (t - h) + rot @ (off[0] + st * (off[1] - off[0]))
        r = info.radius_head + st * (info.radius_tail - info.radius_head)
        for a in np.linspace(0, 2 * np.pi, 8, endpoint=False):
            gaps.append(caster.nearest(centre + r * (np.cos(a) * rot[:, 0] + np.sin(a) * rot[:, 2]))[1])
    assert np.median(gaps) < median_tol and max(gaps) < worst_tol, (label, bone, np.median(gaps), max(gaps))


def test_heavy_belly_centre_points_on_the_belly(data_dir):
    arm, mesh = load_glb_avatar(data_dir / "avatars" / "mpfb2_variants" / "heavy_belly_male.glb")
    model = ac.calibrate_avatar(arm)
    caster = ac.Caster([mesh], bpy.context.evaluated_depsgraph_get())
    corners = {p: tc.point_world(model, "mesh:torso", p) for p in ("belly_ul", "belly_ur", "belly_ll", "belly_lr")}
    chord = sl.belly_centre_points(**{k.split("_")[1]: v for k, v in corners.items()})
    for p in sl.BELLY_CENTRE:
        w = tc.point_world(model, "mesh:torso", p)
        assert caster.nearest(w)[1] < 0.005, p
        # and they are NOT the chord: the belly bulges out in front of the corners' plane
        assert np.linalg.norm(w - chord[p]) > 0.005, p


def test_mesh_less_armature_is_one_clear_message():
    arm, mesh, _spec = build_procedural_avatar()
    bpy.data.objects.remove(mesh)
    with pytest.raises(BodyCalError, match="no mesh is skinned"):
        ac.calibrate_avatar(arm)


def test_ray_that_misses_names_the_point_and_bone():
    """Delete the left palm (the hand bone's box): its rays miss, and the message says which."""
    arm, mesh, spec = build_procedural_avatar()
    me = mesh.data
    vg = mesh.vertex_groups["hand_l"].index
    import bmesh

    bm = bmesh.new()
    bm.from_mesh(me)
    deform = bm.verts.layers.deform.active
    bmesh.ops.delete(bm, geom=[v for v in bm.verts if vg in v[deform]], context="VERTS")
    bm.to_mesh(me)
    bm.free()
    with pytest.raises(BodyCalError) as exc:
        ac.calibrate_avatar(arm)
    msg = str(exc.value)
    assert "palm_1_l" in msg and "hand_l" in msg and "\n" not in msg


def test_fbx_style_y_up_armature_under_a_rotated_object():
    """Bones stored Y-up in armature space under an object rotated +90 degrees about X (how FBX
    rigs arrive): the avatar stands exactly where it stood, so the measurement is the same."""
    arm, mesh, spec = build_procedural_avatar()
    ref = ac.calibrate_avatar(arm)
    rx = Matrix.Rotation(math.radians(90), 4, "X")
    arm.data.transform(rx.inverted())
    arm.matrix_world = rx
    mesh.matrix_parent_inverse = rx.inverted()
    bpy.context.view_layer.update()
    model = ac.calibrate_avatar(arm)
    tc.check_truth(model, spec)
    for j in ("pelvis", "skull_base", "wrist_l", "toe_r"):
        assert np.allclose(model.joints[j].world, ref.joints[j].world, atol=1e-5), j
    for eid in ("mesh:torso", "mesh:sole_l", "mesh:jaw"):
        for name in ref.element(eid).points:
            assert np.allclose(tc.point_world(model, eid, name), tc.point_world(ref, eid, name), atol=1e-4), (eid, name)


def test_rig_without_fingers_and_toes_is_calibrated_with_a_report():
    """Fingers and toes are optional: the model says what it lacks and what it defaulted."""
    arm, _mesh, _spec = build_procedural_avatar()
    bpy.context.view_layer.objects.active = arm
    bpy.ops.object.mode_set(mode="EDIT")
    for eb in list(arm.data.edit_bones):
        if eb.name.split("_")[0] in sk.FINGERS or eb.name.startswith("ball_"):
            arm.data.edit_bones.remove(eb)
    bpy.ops.object.mode_set(mode="OBJECT")
    model = ac.calibrate_avatar(arm)
    cal = model.calibration
    assert "toe_l" in cal["defaulted"] and "toe_r" in cal["defaulted"]
    assert any("index_l" in m for m in cal["missing"]) and any("mesh:palm_r" in m for m in cal["missing"])
    assert np.allclose(model.joints["toe_l"].world, np.array(arm.data.bones["foot_l"].tail_local), atol=1e-6)
    ids = {e.id for e in model.surface}
    assert "capsule:index_1_l" not in ids and "mesh:palm_l" not in ids
    assert {"capsule:forearm_l", "mesh:torso", "mesh:sole_r", "sphere:skull", "mesh:jaw"} <= ids
