"""Egocentric mapping invariants (Delahaye 2023, appendix C; DESIGN.md §5)."""

import numpy as np
import pytest
import retarget_bodies as rb

from bodycal_addon.core.errors import BodyCalError
from bodycal_addon.retarget import egocentric as eg
from bodycal_addon.retarget.egocentric import projection as egp

TARGETS = ["wrist_l", "wrist_r", "elbow_l", "elbow_r", "ankle_l", "ankle_r", "knee_l", "knee_r", "skull_base",
           "tip_thumb_l", "tip_index_l", "tip_middle_r", "tip_pinky_r"]


@pytest.fixture(scope="module")
def user():
    return rb.make_body_model()


def _posed(model, frames, seed, scale=1.0, noise=0.05):
    joints, rots = rb.pose_joints(model, frames, np.random.default_rng(seed), noise=noise)
    return joints, rots


def _targets(joints, seed, spread=0.06):
    rng = np.random.default_rng(seed + 100)
    pts = np.stack([joints[n] for n in TARGETS], axis=1)
    return pts + rng.normal(scale=spread, size=pts.shape)


# The mapping in float64, and in float32 (the pipeline's) to its precision: ~100 last bits of a
# coordinate of a metre or two.
PRECISION = [(np.float64, 1e-9), (np.float32, 2e-5)]


@pytest.mark.parametrize("dtype, atol", PRECISION)
@pytest.mark.parametrize("seed", [1, 2])
def test_avatar_equal_to_user_maps_every_target_onto_itself(user, seed, dtype, atol):
    joints, rots = _posed(user, 30, seed)
    us = eg.pose_surface(user, joints, rots)
    pts = _targets(joints, seed)
    out = eg.retarget_points(pts, TARGETS, us, us, chunk=7, dtype=dtype)
    assert out.dtype == dtype
    np.testing.assert_allclose(out, pts, atol=atol, rtol=0)
    out = eg.retarget_points(pts, TARGETS, us, us, turn_v=True, dtype=dtype)
    np.testing.assert_allclose(out, pts, atol=atol, rtol=0)


@pytest.mark.parametrize("dtype, atol", PRECISION)
@pytest.mark.parametrize("s, falloff, turn_v", [(1.35, 2.0, False), (0.62, 2.0, False), (1.2, 4.0, True)])
def test_uniformly_scaled_avatar_scales_every_target(user, s, falloff, turn_v, dtype, atol):
    joints, rots = _posed(user, 30, 3)
    avatar = rb.scale_model(user, s)
    us = eg.pose_surface(user, joints, rots)
    av = eg.pose_surface(avatar, {k: v * s for k, v in joints.items()}, rots)
    pts = _targets(joints, 3)
    out = eg.retarget_points(pts, TARGETS, us, av, falloff=falloff, turn_v=turn_v, dtype=dtype)
    np.testing.assert_allclose(out, s * pts, atol=atol, rtol=0)


def test_scaled_avatar_is_not_a_no_op(user):
    # Guard for the test above: the mapping must actually move the points.
    joints, rots = _posed(user, 5, 4)
    avatar = rb.scale_model(user, 1.5)
    us = eg.pose_surface(user, joints, rots)
    av = eg.pose_surface(avatar, {k: v * 1.5 for k, v in joints.items()}, rots)
    pts = _targets(joints, 4)
    assert np.abs(eg.retarget_points(pts, TARGETS, us, av) - pts).max() > 0.1


def _hand_on_belly(model, belly_point):
    """Standing pose with the right hand moved so its middle fingertip is at `belly_point`."""
    j = {k: v.world.copy() for k, v in model.joints.items()}
    shift = belly_point - j["tip_middle_r"]
    for k in list(j):
        if k.endswith("_r") and (k.startswith(("wrist", "mcp", "pip", "dip", "tip"))):
            j[k] = j[k] + shift
    j["elbow_r"] = 0.5 * (j["shoulder_r"] + j["wrist_r"]) + [-0.08, 0.0, -0.05]
    return j


def test_fingertip_on_the_belly_lands_on_a_much_bigger_belly(user):
    big = rb.make_body_model(belly=0.15)
    rest = {k: v.world[None] for k, v in user.joints.items()}
    rights = {b: i.right[None] for b, i in user.bones.items()}
    us0 = eg.pose_surface(user, rest, rb.bone_frames(rest, rights))
    tri = us0.tri[0, us0.mesh_slices[0][0] + 3]  # belly_ul, belly_c2, belly_c1
    target = tri.mean(axis=0)
    j = {k: v[None] for k, v in _hand_on_belly(user, target).items()}
    rots = rb.bone_frames(j, rights)
    us = eg.pose_surface(user, j, rots)
    av = eg.pose_surface(big, j, rots)  # same skeleton, the avatar's belly 15 cm further forward
    names = ["tip_middle_r", "wrist_r"]
    pts = np.stack([j[n] for n in names], axis=1)
    out = eg.retarget_points(pts, names, us, av)
    before = eg.project(pts[:, :1], av)
    after = eg.project(out[:, :1], av)
    torso = av.element_ids.index("mesh:torso")
    assert before.dist[0, 0, torso] > 0.1  # without the mapping the fingertip would be deep inside
    assert after.dist[0, 0, torso] < 1e-3


def test_floor_height_target_keeps_its_horizontal_position(user):
    joints, rots = _posed(user, 4, 5, noise=0.0)
    s = 1.25
    avatar = rb.scale_model(user, s)
    us = eg.pose_surface(user, joints, rots)
    av = eg.pose_surface(avatar, {k: v * s for k, v in joints.items()}, rots)
    pts = np.stack([joints["ankle_l"], joints["tip_index_r"]], axis=1)
    pts[:, 0, 2] = 0.0  # exactly on the floor: the floor's weight is at its cap
    out = eg.retarget_points(pts, ["ankle_l", "tip_index_r"], us, av)
    assert np.all(np.isfinite(out))
    np.testing.assert_allclose(out[:, 0, :2], s * pts[:, 0, :2], atol=1e-9)
    np.testing.assert_allclose(out[:, 0, 2], 0.0, atol=1e-9)
    assert np.all(np.linalg.norm(out[:, 0, :2], axis=-1) > 0.05)  # not sent to the origin


def test_degenerate_targets_give_finite_results(user):
    joints, rots = _posed(user, 3, 6, noise=0.0)
    us = eg.pose_surface(user, joints, rots)
    av = eg.pose_surface(rb.make_body_model(belly=0.05), joints, rots)
    on_axis = 0.5 * (joints["thigh_l" and "hip_r"] + joints["knee_r"])  # on the right thigh's axis
    on_surface = us.tri[:, 2].mean(axis=1)  # a torso triangle's centroid
    pts = np.stack([np.zeros_like(on_axis), on_axis, on_surface, joints["pelvis"]], axis=1)
    names = ["wrist_l", "wrist_r", "tip_index_l", "skull_base"]
    out = eg.retarget_points(pts, names, us, av)
    assert np.all(np.isfinite(out))
    proj = eg.project(pts, us)
    assert np.all(np.isfinite(proj.x)) and np.all(np.isfinite(proj.factor))


def test_own_chain_elements_get_no_weight(user):
    joints, rots = _posed(user, 2, 7)
    us = eg.pose_surface(user, joints, rots)
    pts = _targets(joints, 7)
    d = {}
    eg.retarget_points(pts, TARGETS, us, us, details=d)
    ids = us.element_ids
    w = TARGETS.index("wrist_l")
    assert d["lam"][:, w, ids.index("capsule:forearm_l")].max() == 0.0
    assert d["lam"][:, w, ids.index("capsule:index_2_l")].max() == 0.0
    assert d["lam"][:, w, ids.index("capsule:forearm_r")].min() > 0.0
    t = TARGETS.index("tip_index_l")
    assert d["lam"][:, t, ids.index("capsule:index_3_l")].max() == 0.0
    assert d["lam"][:, t, ids.index("capsule:thumb_3_l")].max() == 0.0  # the same hand: its shape, not a contact
    assert d["lam"][:, t, ids.index("capsule:thumb_3_r")].min() > 0.0
    np.testing.assert_allclose(d["lam"].sum(-1), 1.0)
    np.testing.assert_allclose(d["lam_g"].sum(-1) + d["lam_g_floor"], 1.0)


def test_kinematic_paths_use_the_shortcut_bones():
    path = [eg.GRAPH_BONES[i] for i in eg.kinematic_path("shoulder_r", "wrist_l")]
    assert path == ["clavicle_r", "clavicle_l", "upperarm_l", "forearm_l"]
    path = [eg.GRAPH_BONES[i] for i in eg.kinematic_path("knee_l", "skull_base")]
    assert path == ["thigh_l", "hip_l", "shortcut_sacrum_clavicles", "shortcut_clavicles_head"]


def test_mismatched_surfaces_are_a_clear_error(user):
    joints, rots = _posed(user, 2, 8)
    us = eg.pose_surface(user, joints, rots)
    part = eg.pose_surface(user, joints, rots, element_ids=us.element_ids[:-1])
    with pytest.raises(BodyCalError, match="different elements"):
        eg.retarget_points(np.zeros((2, 1, 3)), ["wrist_l"], us, part)


def test_mesh_with_other_triangles_falls_back_to_its_bone_frame(user):
    # The avatar's left palm has five outline points instead of four: no triangle pairs up, the
    # projection is carried in the hand bone's frame scaled by the bone length ratio.
    from bodycal_addon.body.bodymodel import SurfacePoint

    s = 1.2
    avatar = rb.scale_model(user, s)
    palm = avatar.element("mesh:palm_l")
    names = list(palm.points)
    a, b = palm.points[names[0]].local, palm.points[names[1]].local
    palm.points["palm_5_l"] = SurfacePoint("hand_l", 0.5 * (a + b))
    palm.triangles = [(names[0], "palm_5_l", names[1]), (names[0], names[1], names[2]), (names[0], names[2], names[3])]
    joints, rots = _posed(user, 6, 9)
    us = eg.pose_surface(user, joints, rots)
    av = eg.pose_surface(avatar, {k: v * s for k, v in joints.items()}, rots)
    m = us.element_ids.index("mesh:palm_l") - sum(us.counts[:2])
    assert us.mesh_slices[m][1] - us.mesh_slices[m][0] != av.mesh_slices[m][1] - av.mesh_slices[m][0]
    pts = np.stack([joints["wrist_r"], joints["tip_index_r"]], axis=1)
    out = eg.retarget_points(pts, ["wrist_r", "tip_index_r"], us, av)
    np.testing.assert_allclose(out, s * pts, atol=1e-9)


def test_public_projection_coordinates_re_pose_exactly(user):
    # project -> repose through the public (F, P, E, 3) API: on the same body the projections come
    # back unchanged, and every projection lies on its element (|v| = distance to the surface).
    joints, rots = _posed(user, 4, 10)
    us = eg.pose_surface(user, joints, rots)
    pts = _targets(joints, 10)
    proj = eg.project(pts, us)
    np.testing.assert_allclose(eg.repose(proj, us, us), proj.x, atol=1e-12)
    np.testing.assert_allclose(proj.x + proj.v, np.broadcast_to(pts[:, :, None], proj.x.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(proj.cap_dir, axis=-1), 1.0, atol=1e-12)
    np.testing.assert_allclose(proj.tri_bary.sum(-1), 1.0, atol=1e-12)
    assert proj.tri_bary.min() >= -1e-12


def test_triangle_weight_survives_a_shallow_penetration():
    # max(0, cos(v, n)) would drop a target 3 mm inside the crude mesh to zero weight; the plane is
    # shifted by the penetration tolerance (1 cm) first.
    n = np.array([0.0, -1.0, 0.0])[:, None]
    inside = egp._triangle_factor(np.array([0.0, 0.003, 0.0])[:, None], n, eg.PENETRATION_TOLERANCE)
    deep = egp._triangle_factor(np.array([0.0, 0.02, 0.0])[:, None], n, eg.PENETRATION_TOLERANCE)
    plain = egp._triangle_factor(np.array([0.0, 0.003, 0.0])[:, None], n, 0.0)
    assert inside[0] == pytest.approx(1.0) and deep[0] == 0.0 and plain[0] == 0.0


def _reach_forward(joints, k):
    """The right arm straight forward, upper arm and forearm scaled by k, the hand carried along."""
    j = {n: v.copy() for n, v in joints.items()}
    sh = j["shoulder_r"]
    ua, fa = np.linalg.norm(j["elbow_r"] - sh), np.linalg.norm(j["wrist_r"] - j["elbow_r"])
    fwd = np.array([0.0, -1.0, 0.0])
    elbow, wrist = sh + fwd * ua * k, sh + fwd * (ua + fa) * k
    turn = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])  # arm-down hand offsets -> pointing forward
    for n in list(j):
        if n.endswith("_r") and n.split("_")[0] in ("mcp", "pip", "dip", "tip"):
            j[n] = wrist + turn @ (j[n] - j["wrist_r"])
    j["elbow_r"], j["wrist_r"] = elbow, wrist
    return j


def test_kinematic_normalisation_stretches_a_reach_with_longer_arms():
    # Delahaye 2023, Figure 14: an avatar with 1.5x longer arms reaching forward like the user
    # should reach further; with τ'/τ = 1 the wrist would stay at the user's reach from the chest.
    base = rb.standing_joints()
    user, avatar = rb.make_body_model(_reach_forward(base, 1.0)), rb.make_body_model(_reach_forward(base, 1.5))

    def posed(m):
        j = {k: v.world[None] for k, v in m.joints.items()}
        return eg.pose_surface(m, j, rb.bone_frames(j, {b: i.right[None] for b, i in m.bones.items()})), j

    (us, uj), (av, aj) = posed(user), posed(avatar)
    pts = uj["wrist_r"][:, None]
    out = eg.retarget_points(pts, ["wrist_r"], us, av)
    reach_user = np.linalg.norm(uj["wrist_r"] - uj["shoulder_r"])
    reach_avatar = np.linalg.norm(aj["wrist_r"] - aj["shoulder_r"])
    got = np.linalg.norm(out[0, 0] - aj["shoulder_r"][0])
    d = {}
    eg.retarget_points(pts, ["wrist_r"], us, av, details=d)
    torso = us.element_ids.index("mesh:torso")
    assert d["ratio"][0, 0, torso] > 1.2  # the arm's share of the chain grew by 1.5
    assert reach_avatar > got > 1.15 * reach_user


def test_turned_contribution_keeps_its_angle_to_a_tilted_surface(user):
    # A target 3 cm straight out of a torso triangle: on an avatar whose belly is pushed forward
    # (triangles tilted), turn_v carries v along the avatar triangle's normal, so the mapped point
    # stays 3 cm out of it along its normal; the world v of eq. 1 keeps the user's direction.
    big = rb.make_body_model(belly=0.15)
    rest = {k: v.world[None] for k, v in user.joints.items()}
    rights = {b: i.right[None] for b, i in user.bones.items()}
    rots = rb.bone_frames(rest, rights)
    us, av = eg.pose_surface(user, rest, rots), eg.pose_surface(big, rest, rots)
    t = us.mesh_slices[0][0] + 4
    target = us.tri[:, t].mean(axis=1) + 0.03 * us.tri_normal[:, t]
    pr = egp.project_components(target[:, None], us, 0.0)
    x, v = egp.repose_components(pr, us, av, turn_v=True)
    torso = us.element_ids.index("mesh:torso")
    np.testing.assert_allclose(v[:, 0, 0, torso], 0.03 * av.tri_normal[0, t], atol=1e-12)
    _, v_world = egp.repose_components(pr, us, av)
    np.testing.assert_allclose(v_world[:, 0, 0, torso], 0.03 * us.tri_normal[0, t], atol=1e-12)
    assert np.dot(us.tri_normal[0, t], av.tri_normal[0, t]) < 0.999  # the triangle did tilt


def test_empty_inputs_and_unknown_targets(user):
    joints, rots = _posed(user, 3, 11)
    us = eg.pose_surface(user, joints, rots)
    assert eg.retarget_points(np.zeros((3, 0, 3)), [], us, us).shape == (3, 0, 3)
    none = eg.pose_surface(user, {k: v[:0] for k, v in joints.items()}, {k: v[:0] for k, v in rots.items()})
    assert eg.retarget_points(np.zeros((0, 2, 3)), ["wrist_l", "knee_r"], none, none).shape == (0, 2, 3)
    with pytest.raises(BodyCalError, match="not on the kinematic tree"):
        eg.retarget_points(np.zeros((3, 1, 3)), ["spine_07"], us, us)
    with pytest.raises(BodyCalError, match="targets must be"):
        eg.retarget_points(np.zeros((3, 2, 3)), ["wrist_l"], us, us)


def test_capsule_axis_offsets_move_the_posed_capsule_in_its_bone_frame(user):
    import copy

    joints, rots = _posed(user, 4, 5)
    cap = next(e for e in user.surface if e.type == "capsule")
    shifted = copy.deepcopy(user)
    shifted.element(cap.id).set_axis_offsets([0.01, 0.0, -0.02], [0.0, 0.0, 0.03])
    a = eg.pose_surface(user, joints, rots, [cap.id])
    b = eg.pose_surface(shifted, joints, rots, [cap.id])
    np.testing.assert_allclose(b.caps_head - a.caps_head, a.caps_rot @ np.array([0.01, 0.0, -0.02]), atol=1e-12)
    np.testing.assert_allclose(b.caps_tail - a.caps_tail, a.caps_rot @ np.array([0.0, 0.0, 0.03]), atol=1e-12)
    # a target on the shifted capsule's surface maps to the same surface point of an identical avatar
    p = (b.caps_head + b.caps_tail)[:, :, None] / 2 + (b.caps_rot[..., 0] * 0.2)[:, :, None]
    out = eg.retarget_points(p[:, 0], ["skull_base"], b, b)
    np.testing.assert_allclose(out, p[:, 0], atol=1e-9)


def _rest(model):
    joints = {k: v.world[None] for k, v in model.joints.items()}
    return joints, rb.bone_frames(joints, {b: i.right[None] for b, i in model.bones.items()})


def test_a_target_off_a_mesh_edge_keeps_its_weight_whichever_triangle_is_named(user):
    # Outside a convex edge, both triangles' closest point is the edge point: their distances tie
    # and rounding picks one. Their normals differ, so the angular factor must not depend on the
    # pick (it did: a 1e-12 nudge moved the weights by several percent, the targets by mm).
    joints, rots = _rest(user)
    us = eg.pose_surface(user, joints, rots)
    n = 40
    us_n = eg.pose_surface(user, {k: np.repeat(v, n, 0) for k, v in joints.items()},
                           {k: np.repeat(v, n, 0) for k, v in rots.items()})
    first_mesh = us.counts[0] + us.counts[1]
    tested = 0
    for e, (s, t) in enumerate(us.mesh_slices, start=first_mesh):
        tri, nrm = us.tri[0, s:t], us.tri_normal[0, s:t]
        for a in range(len(tri)):
            for b in range(a + 1, len(tri)):
                shared = [p for p in tri[a] if np.isclose(p, tri[b]).all(-1).any()]
                if len(shared) != 2 or nrm[a] @ nrm[b] > 0.95:
                    continue
                edge_mid = 0.5 * (shared[0] + shared[1])
                out = edge_mid + 0.03 * (0.7 * nrm[a] + 0.3 * nrm[b]) / np.linalg.norm(0.7 * nrm[a] + 0.3 * nrm[b])
                pts = out + np.random.default_rng(a).normal(scale=1e-12, size=(n, 1, 3))
                proj = eg.project(pts, us_n)
                if not np.allclose(proj.x[:, 0, e], edge_mid, atol=1e-9):
                    continue  # a concave edge, or another part of the mesh is closer
                own = [max(0.0, (out - edge_mid) @ m / np.linalg.norm(out - edge_mid)) for m in (nrm[a], nrm[b])]
                assert abs(own[0] - own[1]) > 0.01  # the two triangles' factors differ: the pick would matter
                assert np.ptp(proj.factor[:, 0, e]) < 1e-9, us.element_ids[e]
                d = {}
                eg.retarget_points(pts, ["wrist_l"], us_n, us_n, details=d)
                assert np.ptp(d["lam"][:, 0, e]) < 1e-9, us.element_ids[e]
                # float32: nudges of a few last bits; the weight moves by as little
                pts32 = out + np.random.default_rng(a).normal(scale=3e-7, size=(n, 1, 3))
                eg.retarget_points(pts32, ["wrist_l"], us_n, us_n, details=d, dtype=np.float32)
                assert np.ptp(d["lam"][:, 0, e]) < 1e-4 * d["lam"][:, 0, e].mean(), us.element_ids[e]
                tested += 1
    assert tested


def test_both_feet_down_the_floor_term_does_not_flip_between_them(user):
    # Standing on both feet, which ankle is lower is noise. With the user's left knee bent and an
    # avatar with longer legs, the two feet's tau'/tau differ, and picking the lower ankle flipped
    # every target's height between them. Nudging the ankles by a micrometre must move nothing.
    aj = rb.standing_joints()
    for k in aj:
        if not k.startswith(("knee_", "ankle_", "toe_")):
            aj[k] = aj[k] + [0.0, 0.0, 0.12]
        elif k.startswith("knee_"):
            aj[k] = aj[k] + [0.0, 0.0, 0.06]
    avatar = rb.make_body_model(aj, kind="avatar")
    av = eg.pose_surface(avatar, *_rest(avatar))
    joints, _ = _rest(user)
    joints["knee_l"] = joints["knee_l"] + [0.0, -0.15, 0.0]
    names = ["wrist_l", "skull_base", "knee_r"]
    outs = []
    for dz in (1e-6, -1e-6, 0.05, -0.05):
        j = {k: v.copy() for k, v in joints.items()}
        j["ankle_l"][:, 2] += dz
        rots = rb.bone_frames(j, {b: i.right[None] for b, i in user.bones.items()})
        outs.append(eg.retarget_points(np.stack([j[n] for n in names], axis=1), names,
                                       eg.pose_surface(user, j, rots), av))
    assert np.abs(outs[0] - outs[1]).max() < 1e-5
    assert np.abs(outs[2] - outs[3]).max() > 1e-3  # guard: which foot supports does matter here


def test_one_prepared_user_side_maps_onto_several_avatars(user):
    # The pipeline prepares the user's side once and maps it onto several avatar poses; a
    # prepared mapping must give each avatar its own answer (no state carried from the last one).
    joints, rots = _posed(user, 12, 6)
    us = eg.pose_surface(user, joints, rots)
    pts = _targets(joints, 6)
    prepared = eg.prepare_targets(pts, TARGETS, us)
    for s in (1.35, 0.62, 1.35):
        av = eg.pose_surface(rb.scale_model(user, s), {k: v * s for k, v in joints.items()}, rots)
        np.testing.assert_allclose(prepared.map(av), s * pts, atol=1e-9, rtol=0)
        np.testing.assert_allclose(prepared.map(av), eg.retarget_points(pts, TARGETS, us, av), atol=1e-12, rtol=0)


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
@pytest.mark.parametrize("frames", [1, 3])
def test_a_few_frames_map_as_the_groups_apart_do(user, monkeypatch, dtype, frames):
    # A few frames take the speed paths (every target projected and re-posed on every element at
    # once, each exclusion group taking its pairs; τ summed over the padded path slots at once;
    # the rotated vectors three rows at a time): the same values, bit for bit, as each group
    # projected on its own elements with the slot by slot sums, weights included.
    from bodycal_addon.retarget.egocentric import mapping as egm

    avatar = rb.scale_model(user, 1.2)
    joints, rots = _posed(user, frames, 5)
    us = eg.pose_surface(user, joints, rots)
    av = eg.pose_surface(avatar, {k: v * 1.2 + 0.01 for k, v in joints.items()}, rots)
    pts = _targets(joints, 5, spread=0.1)
    fast, fast_details = [], {}
    for turn_v in (False, True):
        fast.append(eg.retarget_points(pts, TARGETS, us, av, turn_v=turn_v, dtype=dtype, details=fast_details))
    assert egm.MERGED_PAIRS >= frames * len(TARGETS) * len(us.element_ids)  # the fast paths were taken
    monkeypatch.setattr(egm, "MERGED_PAIRS", 0)
    monkeypatch.setattr(egp, "SMALL_ROWS", 0)
    apart_details = {}
    for k, turn_v in enumerate((False, True)):
        apart = eg.retarget_points(pts, TARGETS, us, av, turn_v=turn_v, dtype=dtype, details=apart_details)
        np.testing.assert_array_equal(fast[k], apart)
    for name in apart_details:
        np.testing.assert_array_equal(fast_details[name], apart_details[name], err_msg=name)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_a_few_frames_mapped_side_by_side_are_each_group_s_own_values_to_the_bit(user, dtype):
    # A few frames (a live frame) project every target on every element at once and map the
    # exclusion groups side by side, padding the narrow ones with pairs of no weight
    # (mapping._fused_groups); a bake's chunks map each group on its own elements. Each target's
    # sums still run over its own elements in their order, so the two give the same bits, also
    # with targets kept off some elements (`exclude`) and mapped a subset at a time (`targets`).
    from bodycal_addon.retarget.egocentric import mapping

    joints, rots = _posed(user, 24, 11)
    avatar = rb.scale_model(user, 1.2)
    us = eg.pose_surface(user, joints, rots)
    av = eg.pose_surface(avatar, {k: v * 1.2 for k, v in joints.items()}, rots)
    pts = _targets(joints, 11)
    arms = {e for e in us.element_ids if e.startswith(("capsule:upperarm_", "capsule:forearm_", "mesh:palm_"))}
    exclude = {n: arms for n in ("skull_base", "ankle_l", "knee_r")}
    groups = mapping._fused_groups(tuple(TARGETS), tuple(us.element_ids), tuple(us.element_roots),
                                   tuple(frozenset(exclude.get(n, ())) for n in TARGETS))
    assert any(len(set(np.diff(c, axis=1).ravel().tolist())) > 1 or len(g) > 1 for _, g, _, c, _ in groups)
    assert len(groups) < len(mapping._grouping(tuple(TARGETS), tuple(us.element_ids), tuple(us.element_roots),
                                               tuple(frozenset(exclude.get(n, ())) for n in TARGETS)))
    grouped = eg.prepare_targets(pts, TARGETS, us, exclude=exclude, chunk=24, dtype=dtype).map(av)
    lower = ["skull_base", "ankle_l", "knee_r"]
    for f in range(0, 24, 3):
        few = eg.prepare_targets(pts[f:f + 1], TARGETS, us.take(f, f + 1), exclude=exclude, dtype=dtype)
        assert few.whole is not None  # the side-by-side path
        np.testing.assert_array_equal(few.map(av.take(f, f + 1)), grouped[f:f + 1])
        np.testing.assert_array_equal(few.map(av.take(f, f + 1), targets=lower),
                                      grouped[f:f + 1, [TARGETS.index(n) for n in lower]])


def test_a_block_mapped_by_group_takes_an_avatar_surface_of_the_elements_its_targets_use(user):
    # A bake's trunk stage maps its targets group by group on an avatar surface posed with the
    # elements they use only (the body without the arms): the values of the whole surface's map.
    joints, rots = _posed(user, 40, 12)
    avatar = rb.scale_model(user, 1.1)
    us = eg.pose_surface(user, joints, rots)
    pts = _targets(joints, 12)
    arms = {e for e in us.element_ids if e.startswith(("capsule:upperarm_", "capsule:forearm_", "mesh:palm_"))}
    lower = ["skull_base", "ankle_l", "knee_r"]
    prepared = eg.prepare_targets(pts, TARGETS, us, exclude={n: arms for n in lower}, chunk=40)
    av_joints = {k: v * 1.1 for k, v in joints.items()}
    whole = prepared.map(eg.pose_surface(avatar, av_joints, rots), targets=lower)
    trunk = [e for e in us.element_ids if e not in arms]
    np.testing.assert_array_equal(prepared.map(eg.pose_surface(avatar, av_joints, rots, trunk), targets=lower), whole)
    with pytest.raises(BodyCalError, match="lacks elements"):
        prepared.map(eg.pose_surface(avatar, av_joints, rots, trunk), targets=["wrist_l"])


def test_chain_roots_broadcast_over_a_group_equal_the_gathered_roots():
    """A group's plan (every target on the same elements) takes the chains' roots by element and
    broadcasts them over its targets (`_Plan.root_cols`): the same x - r, bit for bit, as the roots
    gathered per chain; a plan whose targets have other elements has no such columns."""
    from bodycal_addon.retarget.egocentric import mapping as egm
    ids = ("capsule:upperarm_l", "capsule:thigh_r", "sphere:head")
    roots = ("shoulder_l", "hip_r", "skull_base")
    plan = egm._plan(("wrist_r", "ankle_l", "tip_index_r"), ids, roots)
    assert plan.root_cols is not None and plan.dense
    rng = np.random.default_rng(3)
    x = rng.standard_normal((3, 5, 3, len(ids))).astype(np.float32)
    nodes = rng.standard_normal((3, 5, len(eg.GRAPH_NODES))).astype(np.float32)
    gathered = egm._chains(x, plan) - nodes.take(plan.chain_root, axis=2)
    assert np.array_equal(egm._from_roots(x, nodes, plan), gathered)
    rows = egm._row_plan(("wrist_r", "ankle_l"), (ids, ids[::-1]), (roots, roots[::-1]), (frozenset(),) * 2)
    assert rows.root_cols is None


@pytest.mark.parametrize("dtype", [np.float64, np.float32])
def test_distances_are_the_projection_s_own_to_the_bit(user, dtype):
    """`distances` (the palm weights' nearest distance) skips the factors and surface coordinates
    but gives project's dist bit for bit, on every element type and inside the body too."""
    joints, rots = _posed(user, 9, 11)
    us = eg.pose_surface(user, joints, rots).astype(dtype)
    pts = _targets(joints, 11, spread=0.15).astype(dtype)
    pts[:, 0] = joints["pelvis"]  # inside the torso
    got = eg.distances(pts, us)
    assert got.dtype == dtype and got.shape == pts.shape[:2] + (len(us.element_ids),)
    assert np.array_equal(got, eg.project(pts, us).dist)
    assert us.counts[2] and np.all(np.isfinite(got))


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_blocks_of_any_size_map_to_the_bit(user, monkeypatch, dtype):
    # The bake maps its frames in blocks of BLOCK_PAIRS frames x targets x elements (a speed
    # choice, docs/PERFORMANCE.md "Bake"): every operation is per pair or per target row, so the
    # block size must change no value, weights and ratios included.
    from bodycal_addon.retarget.egocentric import mapping as egm

    frames = 150
    avatar = rb.scale_model(user, 1.2)
    joints, rots = _posed(user, frames, 7)
    us = eg.pose_surface(user, joints, rots)
    av = eg.pose_surface(avatar, {k: v * 1.2 + 0.01 for k, v in joints.items()}, rots)
    pts = _targets(joints, 7, spread=0.1)
    pairs = frames * len(TARGETS) * len(us.element_ids)
    results = []
    for block_pairs in (2_000, pairs // 3, 10 * pairs):  # blocks of the 32-frame minimum, three, one
        monkeypatch.setattr(egm, "BLOCK_PAIRS", block_pairs)
        for turn_v in (False, True):
            details = {}
            out = eg.retarget_points(pts, TARGETS, us, av, turn_v=turn_v, dtype=dtype, details=details)
            results.append((block_pairs, turn_v, out, details))
    for block_pairs, turn_v, out, details in results[2:]:
        ref = results[int(turn_v)]
        np.testing.assert_array_equal(out, ref[2], err_msg=f"{block_pairs} {turn_v}")
        for name in details:
            np.testing.assert_array_equal(details[name], ref[3][name], err_msg=f"{name} {block_pairs}")
