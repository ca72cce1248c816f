"""Finger flexion and realignment (Delahaye 2023, appendix D, eq. 3-4)."""

import numpy as np
import pytest
from retarget_bodies import random_rotations

from bodycal_addon.retarget import fingers as fg

LENGTHS = [(0.045, 0.025, 0.02), (0.05, 0.03, 0.022), (0.04, 0.03, 0.025), (0.03, 0.03, 0.03)]


@pytest.mark.parametrize("lengths", LENGTHS)
def test_flexion_round_trips_through_the_tip_distance(lengths):
    alpha = np.deg2rad(np.linspace(0.0, 90.0, 181))
    d = fg.tip_distance(*lengths, alpha)
    back = fg.flexion_from_distance(*lengths, d)
    # x is clamped to ±0.9999 (eq. 4): below ~0.8° of flexion the result saturates at acos(0.9999).
    small = alpha < np.arccos(fg.X_CLAMP) + 1e-9
    np.testing.assert_allclose(back[~small], alpha[~small], atol=1e-9)
    assert np.all(back[small] <= np.arccos(fg.X_CLAMP) + 1e-9)


def test_tip_distance_matches_the_chain_it_describes():
    l1, l2, l3 = LENGTHS[0]
    a = np.deg2rad(37.0)
    tip = (np.array([0, l1, 0]) + l2 * np.array([0, np.cos(a), np.sin(a)])
           + l3 * np.array([0, np.cos(2 * a), np.sin(2 * a)]))
    assert fg.tip_distance(l1, l2, l3, a) == pytest.approx(np.linalg.norm(tip), abs=1e-12)


def test_flexion_is_capped_and_never_nan():
    l1, l2, l3 = LENGTHS[1]
    d = np.array([0.0, 0.001, 0.02, 0.2, np.inf])
    a = fg.flexion_from_distance(l1, l2, l3, d[:-1])
    assert np.all(np.isfinite(a))
    assert np.all(a <= np.pi / 2 + 1e-12) and np.all(a >= 0)
    assert a[0] == pytest.approx(np.pi / 2)  # a closed fist: capped at 90°
    assert a[-1] < 0.02  # farther than the finger reaches: straight


@pytest.mark.parametrize("thumb", [False, True])
def test_pose_finger_reaches_targets_within_the_limits(thumb):
    rng = np.random.default_rng(3)
    n = 200
    l1, l2, l3 = LENGTHS[0]
    (ylo, yhi), (plo, phi) = fg.LIMITS["thumb" if thumb else "finger"]
    alpha = np.deg2rad(rng.uniform(5, 85, n))
    yaw = np.deg2rad(rng.uniform(ylo, yhi, n))
    # Tip pitch of the flexed finger plus a realignment that stays within the pitch limits.
    tip_local = fg.tip_distance(l1, l2, l3, alpha)
    pitch = np.deg2rad(rng.uniform(plo, phi, n))
    direction = np.stack([np.sin(yaw), np.cos(yaw) * np.cos(pitch), -np.cos(yaw) * np.sin(pitch)], -1)
    ref = random_rotations(rng, n)
    mcp = rng.normal(size=(n, 3))
    roll = fg.THUMB_ROLL if thumb else 0.0
    rolled = ref @ fg._ry(np.full(n, roll))
    target = mcp + np.einsum("fij,fj->fi", rolled, direction * tip_local[:, None])
    pose = fg.pose_finger(mcp, ref, l1, l2, l3, target, thumb=thumb)
    np.testing.assert_allclose(pose.joints[:, -1], target, atol=1e-9)
    np.testing.assert_allclose(pose.flexion, alpha, atol=1e-9)
    np.testing.assert_allclose(pose.yaw, yaw, atol=1e-9)
    # Bone frames: orthonormal, +Y along each phalanx, hinges flex about +X only.
    rots = pose.rotations
    np.testing.assert_allclose(rots @ np.swapaxes(rots, -1, -2), np.broadcast_to(np.eye(3), rots.shape), atol=1e-9)
    seg = pose.joints[:, 1:] - pose.joints[:, :-1]
    np.testing.assert_allclose(seg, rots[..., :, 1] * np.array([l1, l2, l3])[:, None], atol=1e-12)
    np.testing.assert_allclose(rots[:, 1, :, 0], rots[:, 0, :, 0], atol=1e-12)
    np.testing.assert_allclose(rots[:, 2, :, 0], rots[:, 0, :, 0], atol=1e-12)
    cos_flex = np.einsum("fi,fi->f", rots[:, 0, :, 1], rots[:, 1, :, 1])
    np.testing.assert_allclose(cos_flex, np.cos(alpha), atol=1e-9)
    assert np.all(np.einsum("fi,fi->f", rots[:, 1, :, 1], rots[:, 0, :, 2]) >= -1e-12)  # curls toward +Z


def test_realignment_clamps_to_the_anatomical_limits():
    ref = np.broadcast_to(np.eye(3), (2, 3, 3))
    l1, l2, l3 = LENGTHS[0]
    mcp = np.zeros((2, 3))
    # Far sideways and bent backwards: yaw 60°, pitch +45° (hyperextension): both clamped.
    y, p = np.deg2rad(60), np.deg2rad(45)
    d = np.array([np.sin(y), np.cos(y) * np.cos(p), -np.cos(y) * np.sin(p)])
    pose = fg.pose_finger(mcp, ref, l1, l2, l3, np.stack([d, d]) * 0.08)
    assert np.rad2deg(pose.yaw) == pytest.approx([15.0, 15.0])
    assert np.rad2deg(pose.pitch) == pytest.approx([10.0, 10.0])
    thumb = fg.pose_finger(mcp, ref, l1, l2, l3, np.stack([d, d]) * 0.08, thumb=True, roll=0.0)
    assert np.rad2deg(thumb.yaw) == pytest.approx([40.0, 40.0])
    assert np.rad2deg(thumb.pitch) == pytest.approx([15.0, 15.0])


def test_degenerate_targets_are_finite():
    ref = np.broadcast_to(np.eye(3), (3, 3, 3))
    mcp = np.zeros((3, 3))
    target = np.array([[0.0, 0.0, 0.0], [0.0, 5.0, 0.0], [0.0, -0.01, 0.0]])
    pose = fg.pose_finger(mcp, ref, 0.04, 0.03, 0.02, target)
    assert np.all(np.isfinite(pose.joints)) and np.all(np.isfinite(pose.rotations))


def test_pitch_clamps_to_the_nearer_limit_around_the_circle():
    # Finger pitch limits [-85°, 10°]: the excluded arc runs from 10° up through 180° to -85°,
    # its middle at 142.5°.
    pitch = np.deg2rad([-85.0, 0.0, 10.0, 30.0, 140.0, 145.0, 179.0, -179.0, -100.0])
    clamped = np.rad2deg(fg._clamp_angle(pitch, np.deg2rad(-85.0), np.deg2rad(10.0)))
    np.testing.assert_allclose(clamped, [-85.0, 0.0, 10.0, 10.0, 10.0, -85.0, -85.0, -85.0, -85.0])


@pytest.mark.parametrize("thumb", [False, True])
def test_a_curled_finger_turns_smoothly_with_its_target(thumb):
    """A fingertip curled under the base joint (Figure 16's pole, where a yaw about the hand's up
    axis is undefined) moved by a tenth of a millimetre turns the finger by about as much as the
    move subtends, never by a jump between yaw limits."""
    rng = np.random.default_rng(11)
    n = 400
    l1, l2, l3 = LENGTHS[0]
    ref = np.broadcast_to(np.eye(3), (n, 3, 3))
    mcp = np.zeros((n, 3))
    # Directions a few degrees from straight down the palm side (+Z), a little ahead of or behind
    # the base joint (pitch near -90°, beyond the -85° limit): a fist.
    pole = np.array([0.0, 0.0, 1.0]) + rng.normal(scale=0.1, size=(n, 3))
    pole[:, 1] = np.abs(pole[:, 1]) * rng.choice([-1, 1], n)
    target = 0.03 * pole / np.linalg.norm(pole, axis=-1, keepdims=True)
    step = 1e-4 * rng.normal(size=(n, 3)) / np.sqrt(3)
    a = fg.pose_finger(mcp, ref, l1, l2, l3, target, thumb=thumb, roll=0.0)
    b = fg.pose_finger(mcp, ref, l1, l2, l3, target + step, thumb=thumb, roll=0.0)
    turn = np.arccos(np.clip((np.trace(np.swapaxes(a.rotations[:, 0], -1, -2) @ b.rotations[:, 0],
                                       axis1=-2, axis2=-1) - 1) / 2, -1, 1))
    subtended = np.linalg.norm(step, axis=-1) / 0.03
    # A turn may exceed the subtended angle by the flexion's own change (the distance moves too),
    # bounded by a few times it; the flip this guards against was 30°.
    assert np.rad2deg(turn).max() < 0.5
    assert np.all(turn <= 8 * subtended + 1e-9)


def _rx_rz_rx_entry_by_entry(a, b, c):
    """Rx(a) Rz(b) Rx(c) of one item in Python floats, entry by entry as _rx_rz_rx once wrote it
    (ca r1 - sa r2, sa r1 + ca r2 on the rows r1 = (sb, cb cc, -cb sc), r2 = (0, sc, cc)); the
    cosines and sines are numpy's."""
    (ca, cb, cc), (sa, sb, sc) = np.cos([a, b, c]).tolist(), np.sin([a, b, c]).tolist()
    r1, r2 = (sb, cb * cc, -cb * sc), (0.0, sc, cc)
    return [[cb, -sb * cc, sb * sc], [ca * r1[k] - sa * r2[k] for k in range(3)],
            [sa * r1[k] + ca * r2[k] for k in range(3)]]


def test_rx_rz_rx_a_few_rows_at_a_time_is_entry_by_entry_to_the_bit():
    """_rx_rz_rx builds its rows a few at a time (u - v w as u + (-v) w, -u v as u (-v)): exact
    rewrites, so every entry has the bits of the one-entry-at-a-time formula (angles where the
    entries are signed zeros included)."""
    rng = np.random.default_rng(5)
    angles = rng.uniform(-np.pi, np.pi, (3, 300))
    angles[:, :6] = [[0.0, -0.0, np.pi, 0.0, -np.pi / 2, 0.0], [0.0, 0.0, -0.0, np.pi / 2, 0.0, -np.pi],
                     [-0.0, 0.0, 0.0, -0.0, np.pi, np.pi / 2]]
    got = fg._rx_rz_rx(*angles)
    want = np.array([_rx_rz_rx_entry_by_entry(*angles[:, i]) for i in range(angles.shape[1])])
    assert got.tobytes() == want.tobytes()
    # a few items at a time (a live frame's fingers) take the gathered products: the same bits
    for part in np.array_split(np.arange(300), 30):
        assert len(part) < fg.FEW_ITEMS
        assert fg._rx_rz_rx(*angles[:, part]).tobytes() == want[part].tobytes()


def test_a_few_fingers_pose_as_many_do_and_the_distal_axis_alone_is_the_pose_s():
    """A FingerSet of a few items (its scalars as arrays, a live frame's) poses each item to the
    bit as a set of many (its scalars as they are) does; `distal_z` is the pose's distal +Z."""
    rng = np.random.default_rng(8)
    n = 120  # a set of many (>= FEW_ITEMS), still posed with np.matmul (fewer than MANY_PRODUCTS)
    assert fg.FEW_ITEMS <= n < 256
    lens = rng.uniform(0.015, 0.05, (3, n))
    thumb = rng.random(n) < 0.3
    ref = random_rotations(rng, n)
    mcp = rng.normal(size=(n, 3)) * 0.1
    tip = mcp + rng.normal(size=(n, 3)) * rng.choice([0.002, 0.03, 0.08], size=(n, 1))  # pitches beyond limits too
    many = fg.FingerSet(*lens, thumb=thumb, roll=fg.THUMB_ROLL).pose(mcp, ref, tip)
    for part in np.array_split(np.arange(n), 12):  # 10 items each, as a live frame's fingers
        few_set = fg.FingerSet(*lens[:, part], thumb=thumb[part], roll=fg.THUMB_ROLL)
        few = few_set.pose(mcp[part], ref[part], tip[part])
        for field in ("joints", "rotations", "flexion", "yaw", "pitch"):
            assert getattr(few, field).tobytes() == getattr(many, field)[part].tobytes(), field
        z = few_set.distal_z(mcp[part], ref[part], tip[part])
        assert z.tobytes() == np.ascontiguousarray(few.rotations[:, 2, :, 2]).tobytes()
        frames_only = few_set.pose(mcp[part], ref[part], tip[part], joints=False)
        assert frames_only.joints is None and frames_only.rotations.tobytes() == few.rotations.tobytes()
