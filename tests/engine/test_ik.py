"""Avatar IK (Delahaye 2023, appendix E; DESIGN.md §6)."""

import numpy as np
import pytest

from bodycal_addon.core import one_frame
from bodycal_addon.retarget import ik

# One frame in mathutils (float32) against numpy's float64 path: measured on these cases at most
# 9.3e-7 for two_bone (unit vectors, rotation entries; metres on limbs of 0.2-0.7 m), 5.1e-7 for the
# spine's rotations and 1.4e-7 m for its joints; checked at about twice that.
ONE_FRAME_ATOL = 2e-6


def _unit(v):
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def _perp(v, axis):
    return _unit(v - np.einsum("fi,fi->f", v, axis)[:, None] * axis)


def _check_frames(rot):
    np.testing.assert_allclose(rot @ np.swapaxes(rot, -1, -2), np.broadcast_to(np.eye(3), rot.shape), atol=1e-9)
    np.testing.assert_allclose(np.linalg.det(rot), 1.0, atol=1e-9)


def test_two_bone_reaches_every_reachable_target_and_keeps_the_swivel():
    rng = np.random.default_rng(0)
    n = 500
    l1, l2 = 0.30, 0.26
    root = rng.normal(size=(n, 3))
    direction = _unit(rng.normal(size=(n, 3)))
    dist = rng.uniform(abs(l1 - l2) + 1e-3, l1 + l2 - 1e-4, n)
    target = root + direction * dist[:, None]
    swivel = rng.normal(size=(n, 3))
    res = ik.two_bone(root, l1, l2, target, user_swivel_dir=swivel)
    assert np.linalg.norm(res.end - target, axis=-1).max() < 1e-4  # 0.1 mm
    np.testing.assert_allclose(np.linalg.norm(res.mid - root, axis=-1), l1, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(res.end - res.mid, axis=-1), l2, atol=1e-9)
    assert res.reached.all()
    # The mid joint lies in the half-plane of the requested swivel (pole None: t = 0, δ = γ).
    got = _perp(res.mid - root, direction)
    np.testing.assert_allclose(got, _perp(swivel, direction), atol=1e-9)
    # Flexion (eq. 5-6) and the hinge: both bones share +X, the second is the first turned about it.
    cos_alpha = (l1 * l1 + l2 * l2 - dist * dist) / (2 * l1 * l2)
    np.testing.assert_allclose(res.flexion, np.pi - np.arccos(cos_alpha), atol=1e-9)
    _check_frames(res.rot1)
    _check_frames(res.rot2)
    np.testing.assert_allclose(res.rot1[..., 0], res.rot2[..., 0], atol=1e-12)
    np.testing.assert_allclose(res.rot1[..., 1], _unit(res.mid - root), atol=1e-12)
    np.testing.assert_allclose(res.rot2[..., 1], _unit(res.end - res.mid), atol=1e-12)
    # Positive flexion about +X: rot2 = rot1 Rx(α).
    c, s = np.cos(res.flexion), np.sin(res.flexion)
    y2 = c[:, None] * res.rot1[..., 1] + s[:, None] * res.rot1[..., 2]
    np.testing.assert_allclose(res.rot2[..., 1], y2, atol=1e-9)


def test_swivel_follows_the_pole_target_with_the_blend_of_eq_7():
    n = 7
    root = np.zeros((n, 3))
    target = np.tile([0.0, 0.0, -0.45], (n, 1))
    r = np.array([0.0, 0.03, 0.05, 0.08, 0.10, 0.15, 0.4])
    # Pole at 90° from the user's swivel, at distance r from the axis.
    pole = np.stack([np.zeros(n), r, np.full(n, -0.2)], -1)
    user = np.tile([1.0, 0.0, 0.0], (n, 1))
    res = ik.two_bone(root, 0.3, 0.26, target, pole_target=pole, user_swivel_dir=user)
    t = np.clip((r - 0.05) * 10, 0, 1)
    np.testing.assert_allclose(res.blend, t, atol=1e-12)
    np.testing.assert_allclose(ik.swivel_blend(r), t)
    angle = np.arctan2(res.swivel_dir[:, 1], res.swivel_dir[:, 0])
    np.testing.assert_allclose(angle, t * np.pi / 2, atol=1e-9)  # δ = t β + (1 - t) γ, β = 90°, γ = 0
    np.testing.assert_allclose(np.linalg.norm(res.end - target, axis=-1), 0, atol=1e-9)


def test_degenerate_targets_never_give_nan():
    l1, l2 = 0.3, 0.25
    root = np.zeros((6, 3))
    target = np.array([[0, 0, 0], [0, 0, -2.0], [0, 0, -0.01], [0, 0, -0.55], [0, 0, 1e-15], [0, 0, -0.3]], float)
    pole = np.array([[0, 0, -0.2]] * 5 + [[0, 0, -0.1]], float)  # on the root-effector axis
    for kw in ({}, {"pole_target": pole}, {"user_swivel_dir": np.tile([0, 0, 1.0], (6, 1))},
               {"user_swivel_dir": np.zeros((6, 3)), "flex_axis_hint": np.tile([1.0, 0, 0], (6, 1))}):
        res = ik.two_bone(root, l1, l2, target, **kw)
        for arr in (res.mid, res.end, res.rot1, res.rot2, res.flexion, res.blend):
            assert np.all(np.isfinite(arr)), kw
        _check_frames(res.rot1)
        _check_frames(res.rot2)
        np.testing.assert_allclose(np.linalg.norm(res.mid - root, axis=-1), l1, atol=1e-9)
        np.testing.assert_allclose(np.linalg.norm(res.end - res.mid, axis=-1), l2, atol=1e-9)
    res = ik.two_bone(root, l1, l2, target, user_swivel_dir=np.tile([1.0, 0, 0], (6, 1)))
    # Unreachable: fully extended toward the target.
    np.testing.assert_allclose(res.end[1], [0, 0, -(l1 + l2)], atol=1e-12)
    assert res.flexion[1] == pytest.approx(0.0, abs=1e-7)
    assert not res.reached[1] and not res.reached[2] and res.reached[5]
    # Too close: folded as far as the bones allow, toward the target.
    np.testing.assert_allclose(res.end[2], [0, 0, -(l1 - l2)], atol=1e-12)


def test_flex_axis_hint_sets_the_swivel_of_a_straight_user_limb():
    n = 3
    root = np.zeros((n, 3))
    target = np.tile([0.0, 0.0, -0.4], (n, 1))
    hint = np.tile([1.0, 0.0, 0.0], (n, 1))  # the user's hinge axis
    res = ik.two_bone(root, 0.3, 0.26, target, user_swivel_dir=np.tile([0, 0, -1.0], (n, 1)), flex_axis_hint=hint)
    np.testing.assert_allclose(res.rot1[..., 0], hint, atol=1e-12)  # the avatar's hinge = the user's


def test_spine_arc_reaches_the_skull_base_with_equal_angles():
    n = 5
    rng = np.random.default_rng(1)
    lengths = np.full(12, 0.05)
    pelvis = np.zeros((n, 3))
    rot = np.broadcast_to(np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]]), (n, 3, 3)).copy()  # +Y = world +Z
    skull = np.stack([np.zeros(n), rng.uniform(-0.15, 0.15, n), rng.uniform(0.4, 0.5, n)], -1) + [0, 0, 0.1]
    kink = {}
    for two_pass in (False, True):
        res = ik.spine(pelvis, rot, 0.1, lengths, skull, two_pass=two_pass)
        first = _unit(res.joints[:, 1] - res.joints[:, 0])
        kink[two_pass] = np.arccos(np.clip(np.einsum("fi,fi->f", first, res.sacrum_rot[..., 1]), -1, 1))
        np.testing.assert_allclose(res.joints[:, -1], skull, atol=1e-6)
        seg = np.diff(res.joints, axis=1)
        np.testing.assert_allclose(np.linalg.norm(seg, axis=-1), 0.05, atol=1e-12)
        u = seg / 0.05
        turn = np.arccos(np.clip(np.einsum("fki,fki->fk", u[:, 1:], u[:, :-1]), -1, 1))
        np.testing.assert_allclose(turn, np.broadcast_to(turn[:, :1], turn.shape), atol=1e-6)
        _check_frames(res.rotations)
        _check_frames(res.sacrum_rot)
    # Second pass: turning the sacrum toward the first vertebra shrinks the sacrum-vertebra kink
    # (it does not cancel it: the moved spine root changes the chord and the arc is solved again).
    assert np.all(kink[True] < kink[False] - 0.05)
    np.testing.assert_allclose(res.sacrum_rot[..., 0], rot[..., 0], atol=1e-12)  # about the hip axis


def test_spine_twist_is_uniform_and_reaches_the_top_right():
    n = 2
    lengths = np.full(12, 0.05)
    rot = np.broadcast_to(np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]]), (n, 3, 3)).copy()
    skull = np.tile([0.0, 0.0, 0.1 + 0.6], (n, 1))  # straight: the twist alone turns the frames
    top = np.tile([np.cos(0.6), np.sin(0.6), 0.0], (n, 1))
    res = ik.spine(np.zeros((n, 3)), rot, 0.1, lengths, skull, top_right=top)
    x = res.rotations[..., 0]
    ang = np.arctan2(x[..., 1], x[..., 0])
    np.testing.assert_allclose(ang, np.broadcast_to(0.6 * np.arange(1, 13) / 12, ang.shape), atol=1e-9)


def test_spine_out_of_reach_is_straight_and_finite():
    n = 2
    rot = np.broadcast_to(np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]]), (n, 3, 3)).copy()
    skull = np.array([[0.0, 0.0, 3.0], [0.0, 0.0, 0.1]])  # too far; on the spine root
    res = ik.spine(np.zeros((n, 3)), rot, 0.1, np.full(12, 0.05), skull)
    assert np.all(np.isfinite(res.joints)) and np.all(np.isfinite(res.rotations))
    np.testing.assert_allclose(res.joints[0, -1], [0, 0, 0.1 + 0.6], atol=1e-6)


def test_spine_straight_above_but_too_close_bends_in_the_sagittal_plane():
    n = 1
    rot = np.broadcast_to(np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]]), (n, 3, 3)).copy()  # Z = -Y world
    skull = np.array([[0.0, 0.0, 0.1 + 0.5]])  # straight above the spine root, chain 0.6 m long
    res = ik.spine(np.zeros((n, 3)), rot, 0.1, np.full(12, 0.05), skull, two_pass=False)
    np.testing.assert_allclose(res.joints[:, -1], skull, atol=1e-6)
    np.testing.assert_allclose(res.joints[..., 0], 0.0, atol=1e-9)  # no lateral bend
    assert res.joints[0, 1, 1] > 0  # the first vertebra leans toward the sacrum's -Z (world +Y)


def test_hinge_hint_takes_over_when_the_user_limb_is_straight():
    rng = np.random.default_rng(4)
    n = 50
    root = np.zeros((n, 3))
    target = np.tile([0.0, 0.0, -0.45], (n, 1))
    hint = np.tile([1.0, 0.0, 0.0], (n, 1))
    expected = np.cross(_unit(target - root), hint)  # swivel = axis x hint
    # A straight user arm: its elbow sits on the axis up to 0.1 mm of noise.
    straight = np.tile([0.0, 0.0, -0.3], (n, 1)) + rng.normal(scale=1e-4, size=(n, 3))
    res = ik.two_bone(root, 0.3, 0.26, target, user_swivel_dir=straight, flex_axis_hint=hint)
    assert np.degrees(np.arccos(np.clip(np.einsum("fi,fi->f", res.swivel_dir, expected), -1, 1))).max() < 1.5
    # A bent user arm agreeing with its hinge keeps exactly that swivel.
    bent = np.tile([0.0, 0.0, -0.2], (n, 1)) + 0.1 * expected
    res = ik.two_bone(root, 0.3, 0.26, target, user_swivel_dir=bent, flex_axis_hint=hint)
    np.testing.assert_allclose(res.swivel_dir, expected, atol=1e-12)


def _bent_chain(rest_segments, delta):
    """The rest chain (sacrum frame = world) with segment k turned by (k + 1) δ about +X."""
    k = np.arange(1, len(rest_segments) + 1)
    c, s = np.cos(delta * k), np.sin(delta * k)
    rx = np.stack([np.stack([np.ones_like(c), 0 * c, 0 * c], -1), np.stack([0 * c, c, -s], -1),
                   np.stack([0 * c, s, c], -1)], -2)
    seg = np.einsum("kij,kj->ki", rx, rest_segments)
    return np.concatenate([np.zeros((1, 3)), np.cumsum(seg, axis=0)])


def test_spine_from_the_rest_shape_gives_the_rest_shape_back_at_the_rest_chord():
    ang = np.linspace(0.1, -0.25, 12)  # a curved rest spine (lordosis then kyphosis), in the y-z plane
    rest = np.stack([np.zeros(12), 0.045 * np.cos(ang), 0.045 * np.sin(ang)], -1) * np.linspace(1.2, 0.8, 12)[:, None]
    joints0 = np.concatenate([np.zeros((1, 3)), np.cumsum(rest, axis=0)])
    rot = np.broadcast_to(np.eye(3), (1, 3, 3)).copy()
    res = ik.spine(np.zeros((1, 3)) - [0, 0.1, 0], rot, 0.1, None, joints0[-1][None], rest_segments=rest)
    np.testing.assert_allclose(res.joints[0], joints0, atol=1e-9)
    assert abs(res.bend[0]) < 1e-9


def test_spine_from_a_straight_rest_recovers_a_uniform_bend_exactly():
    rest = np.tile([0.0, 0.045, 0.0], (12, 1))
    deltas = np.array([0.0, 0.01, -0.03, 0.08])
    truth = np.stack([_bent_chain(rest, d) for d in deltas])
    rot = np.broadcast_to(np.eye(3), (len(deltas), 3, 3)).copy()
    res = ik.spine(np.zeros((len(deltas), 3)) - [0, 0.1, 0], rot, 0.1, None, truth[:, -1], rest_segments=rest)
    np.testing.assert_allclose(res.joints, truth, atol=1e-9)
    np.testing.assert_allclose(res.bend, np.abs(deltas), atol=1e-9)  # the axis carries the sign
    _check_frames(res.rotations)


def test_spine_from_the_rest_shape_shrugs_off_skull_base_noise_the_chord_length_cannot():
    # A near-straight spine bent 6° in all: 3 mm of noise on the skull base moves its middle by a
    # few mm; the chord-length arc reads the same noise as a bend of tens of degrees.
    rng = np.random.default_rng(7)
    ang = np.linspace(0.05, -0.05, 12)
    rest = np.stack([np.zeros(12), 0.045 * np.cos(ang), 0.045 * np.sin(ang)], -1)
    n = 200
    truth = np.stack([_bent_chain(rest, d) for d in np.full(n, np.radians(0.5))])
    noisy = truth[:, -1] + rng.normal(0, 0.003, (n, 3))
    rot = np.broadcast_to(np.eye(3), (n, 3, 3)).copy()
    start = np.zeros((n, 3)) - [0, 0.1, 0]
    new = ik.spine(start, rot, 0.1, None, noisy, rest_segments=rest)
    arc = ik.spine(start, rot, 0.1, np.linalg.norm(rest, axis=-1), noisy, two_pass=False)
    mid_new = np.linalg.norm(new.joints[:, 6] - truth[:, 6], axis=-1)
    mid_arc = np.linalg.norm(arc.joints[:, 6] - truth[:, 6], axis=-1)
    assert np.percentile(mid_new, 95) < 0.004, np.percentile(mid_new, 95)
    assert np.percentile(mid_arc, 95) > 3 * np.percentile(mid_new, 95)
    np.testing.assert_allclose(new.joints[:, -1], noisy, atol=1e-9)  # the top still lands on the target


def test_spine_from_the_rest_shape_is_finite_on_the_root_and_short_out_of_reach():
    rest = np.tile([0.0, 0.045, 0.0], (12, 1))
    rot = np.broadcast_to(np.eye(3), (3, 3, 3)).copy()
    start = np.zeros((3, 3))
    skull = np.array([[0.0, 0.0, 0.0], [0.0, 3.0, 0.0], [0.0, -0.54, 0.0]])  # on the root; too far; behind
    res = ik.spine(start - [0, 0.1, 0], rot, 0.1, None, skull, rest_segments=rest)
    assert np.all(np.isfinite(res.joints)) and np.all(np.isfinite(res.rotations))
    np.testing.assert_allclose(res.joints[1, -1], [0, 0.54 * ik.MAX_SPINE_STRETCH, 0], atol=1e-9)
    flat = ik.spine(start - [0, 0.1, 0], rot, 0.1, None, skull, rest_segments=np.zeros((12, 3)))  # no spine
    assert np.all(np.isfinite(flat.joints)) and np.all(np.isfinite(flat.rotations))
    np.testing.assert_allclose(np.linalg.norm(np.diff(res.joints, axis=1), axis=-1)[0], 0.045 * ik.MIN_SPINE_STRETCH)


def test_a_nearly_straight_limb_keeps_its_bend_plane_under_joint_noise():
    """A standing leg's knee sits 1-2 cm off the hip-ankle line and the trackers move it by
    millimetres; the measured hinge axis, not that noise, must set the swivel (it turned by tens of
    degrees a frame and the avatar's knee jumped by centimetres)."""
    rng = np.random.default_rng(7)
    n = 300
    root = np.zeros((n, 3))
    target = np.tile([0.0, 0.0, -0.825], (n, 1))
    hint = np.tile([1.0, 0.0, 0.0], (n, 1))
    expected = np.cross(_unit(target - root), hint)
    knee = np.tile([0.0, 0.0, -0.4], (n, 1)) + 0.015 * expected + rng.normal(scale=0.002, size=(n, 3))
    res = ik.two_bone(root, 0.41, 0.42, target, user_swivel_dir=knee, flex_axis_hint=hint)
    turn = np.degrees(np.arccos(np.clip(np.einsum("fi,fi->f", res.swivel_dir, expected), -1, 1)))
    assert turn.max() < 8.0, turn.max()
    assert np.linalg.norm(np.diff(res.mid, axis=0), axis=1).max() < 0.008  # at a 1 cm weight: 13°, 14 mm


def test_a_few_limbs_in_python_floats_are_numpy_s_two_bone_to_float64(monkeypatch):
    # A live frame's limbs (ik.FEW_LIMBS items or fewer) are solved in Python floats (float64,
    # ik._two_bone_one): numpy's two_bone to its sums' rounding (1e-12, where the mathutils kernel
    # it replaced held float32's 2e-6), degenerate limbs included (target on the root, pole and
    # user swivel on the axis, hint along the axis, out of reach).
    rng = np.random.default_rng(7)
    n = 400
    root = rng.normal(size=(n, 3))
    target = root + rng.normal(size=(n, 3)) * rng.uniform(0.0, 0.4, (n, 1))
    pole = root + rng.normal(size=(n, 3)) * 0.2
    user = rng.normal(size=(n, 3))
    hint = rng.normal(size=(n, 3))
    axis = target - root
    target[:8] = root[:8]  # on the root
    pole[8:16] = root[8:16] + 0.5 * axis[8:16]  # on the root-effector axis
    user[16:24] = axis[16:24]
    hint[24:32] = axis[24:32]
    user[32:40] = 0.0
    target[40:48] = root[40:48] + [0.0, 0.0, -2.0]  # out of reach
    l1, l2 = rng.uniform(0.2, 0.35, n), rng.uniform(0.2, 0.35, n)
    assert one_frame.ENABLED
    for kw in ({"pole_target": pole, "user_swivel_dir": user, "flex_axis_hint": hint}, {"user_swivel_dir": user},
               {"pole_target": pole, "flex_axis_hint": hint}, {}):
        monkeypatch.setattr(ik, "FEW_LIMBS", 0)
        whole = ik.two_bone(root, l1, l2, target, size_ratio=1.3, **kw)
        monkeypatch.setattr(ik, "FEW_LIMBS", 4)
        # where a degenerate case turns on a vector of rounding noise (pole, user swivel or hint
        # exactly on the axis) the swivel is arbitrary either way, and a target within a few mm of
        # the root has an axis that float32 positions of metres give to 1e-4: those items are
        # checked for sound frames and the effector
        exact = np.linalg.norm(target - root, axis=1) > 0.02
        exact[8:32] = False
        for k in range(0, n, 2):
            few = ik.two_bone(root[k:k + 2], l1[k:k + 2], l2[k:k + 2], target[k:k + 2], size_ratio=1.3,
                              **{a: v[k:k + 2] for a, v in kw.items()})
            for rot in (few.rot1, few.rot2):
                np.testing.assert_allclose(rot @ rot.swapaxes(-1, -2), np.broadcast_to(np.eye(3), rot.shape),
                                           atol=ONE_FRAME_ATOL)
            np.testing.assert_allclose(few.end, whole.end[k:k + 2], rtol=0, atol=1e-12)
            np.testing.assert_array_equal(few.reached, whole.reached[k:k + 2])
            keep = exact[k:k + 2]
            for got, want in ((few.mid, whole.mid), (few.rot1, whole.rot1), (few.rot2, whole.rot2),
                              (few.blend, whole.blend), (few.swivel_dir, whole.swivel_dir),
                              (few.flexion, whole.flexion)):
                np.testing.assert_allclose(got[keep], want[k:k + 2][keep], rtol=0, atol=1e-12)


def _rotations(rng, n):
    q = rng.normal(size=(n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    w, x, y, z = q.T
    return np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
                     np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
                     np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)


def _spine_case(rng, n, strided=False):
    """(a rest spine's 12 segments, pelvis (n, 3), sacrum frames (n, 3, 3), the spine's start and
    the skull-base aims (n, 3) each): random frames, the first six aims on the rest chord, the next
    four on the spine's start; the sacrum frames a strided view (as a pose's frames give it) when
    asked."""
    rest = np.cumsum(np.tile([0.0, 0.045, 0.0], (12, 1)) + rng.normal(scale=0.004, size=(12, 3)), axis=0)
    rest_segments = np.diff(np.concatenate([np.zeros((1, 3)), rest]), axis=0)
    pelvis = rng.normal(size=(n, 3))
    sac = _rotations(rng, n)
    if strided:
        held = np.zeros((n, 4, 3, 3))
        held[:, 2] = sac
        sac = held[:, 2]
    start = pelvis + 0.1 * sac[..., 1]
    aim = start + np.einsum("fij,j->fi", sac, rest_segments.sum(0)) + rng.normal(scale=0.08, size=(n, 3))
    aim[:6] = start[:6] + 0.5 * np.einsum("fij,j->fi", sac[:6], rest_segments.sum(0))  # on the rest chord
    aim[6:10] = start[6:10]  # on the spine's start
    return rest_segments, pelvis, sac, start, aim


def test_one_frame_s_spine_in_mathutils_is_numpy_s_to_float32(monkeypatch):
    # A live frame's spine is computed in mathutils (float32, core/one_frame.py): numpy's path to
    # float32's rounding, degenerate frames included (the skull base on the rest chord, on the
    # spine's start, a top right along the chord), on a sacrum frame that is a strided view too.
    rng = np.random.default_rng(11)
    n = 120
    for strided in (False, True):
        rest_segments, pelvis, sac, start, aim = _spine_case(rng, n, strided)
        right = rng.normal(size=(n, 3))
        right[10:14] = aim[10:14] - start[10:14]  # along the chord
        for top in (right, None):
            for f in range(n):
                args = (pelvis[f:f + 1], sac[f:f + 1], 0.1, None, aim[f:f + 1])
                kw = {"top_right": None if top is None else top[f:f + 1] / np.linalg.norm(top[f]),
                      "two_pass": False, "rest_segments": rest_segments}
                monkeypatch.setattr(one_frame, "ENABLED", False)
                want = ik.spine(*args, **kw)
                monkeypatch.setattr(one_frame, "ENABLED", True)
                got = ik.spine(*args, **kw)
                np.testing.assert_array_equal(got.sacrum_rot, want.sacrum_rot)
                np.testing.assert_allclose(got.joints, want.joints, rtol=0, atol=ONE_FRAME_ATOL)
                np.testing.assert_allclose(got.bend, want.bend, rtol=0, atol=ONE_FRAME_ATOL)
                if top is not None and 10 <= f < 14:
                    continue  # a top right along the chord: the twist is float32 noise's either way
                np.testing.assert_allclose(got.rotations, want.rotations, rtol=0, atol=ONE_FRAME_ATOL)


def test_a_spine_with_a_vanishing_vertebra_keeps_sound_frames():
    # A vertebra of zero length takes the chord as its +Y, a right along it any perpendicular:
    # the frames stay rotations, never NaN (the bake's components-first path and one frame's).
    rng = np.random.default_rng(12)
    n = 20
    rest_segments, pelvis, sac, _, aim = _spine_case(rng, n)
    rest_segments[4] = 0.0
    right = rng.normal(size=(n, 3))
    kw = {"top_right": right / np.linalg.norm(right, axis=1, keepdims=True), "two_pass": False,
          "rest_segments": rest_segments}
    for res in [ik.spine(pelvis, sac, 0.1, None, aim, **kw)] + [
            ik.spine(pelvis[f:f + 1], sac[f:f + 1], 0.1, None, aim[f:f + 1], top_right=kw["top_right"][f:f + 1],
                     two_pass=False, rest_segments=rest_segments) for f in range(3)]:
        rot = res.rotations
        assert np.isfinite(rot).all() and np.isfinite(res.joints).all()
        np.testing.assert_allclose(rot @ rot.swapaxes(-1, -2), np.broadcast_to(np.eye(3), rot.shape),
                                   atol=ONE_FRAME_ATOL)
