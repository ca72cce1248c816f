"""Vectorised rotations, checked against Blender's mathutils on random data."""

import numpy as np
from mathutils import Quaternion, Vector

from bodycal_addon.core import transforms as tf

rng = np.random.default_rng(7)


def _random_quats(n):
    return tf.quat_normalize(rng.normal(size=(n, 4)))


def test_rotate_and_matrix_match_mathutils():
    q = _random_quats(50)
    v = rng.normal(size=(50, 3))
    out = tf.rotate(q, v)
    mats = tf.quat_to_matrix(q)
    for i in range(50):
        ref = Quaternion(q[i]) @ Vector(v[i])
        np.testing.assert_allclose(out[i], ref, atol=1e-5)  # mathutils is single precision
        np.testing.assert_allclose(mats[i], np.array(Quaternion(q[i]).to_matrix()), atol=1e-6)


def test_matrix_to_quat_round_trips_including_half_turns():
    q = _random_quats(200)
    half_turns = tf.axis_angle_to_quat(rng.normal(size=(20, 3)), np.full(20, np.pi))
    q = np.concatenate([q, tf.quat_normalize(half_turns), [[1.0, 0, 0, 0]]])
    back = tf.matrix_to_quat(tf.quat_to_matrix(q))
    # Same rotation: q and -q are equal.
    np.testing.assert_allclose(np.abs((back * q).sum(-1)), 1.0, atol=1e-9)


def test_quat_mul_composes_like_mathutils():
    a, b = _random_quats(30), _random_quats(30)
    ab = tf.quat_mul(a, b)
    for i in range(30):
        ref = Quaternion(a[i]) @ Quaternion(b[i])
        assert abs(abs(np.dot(ab[i], np.array(ref))) - 1) < 1e-6  # single precision


def test_quat_between_maps_a_to_b_even_when_opposite():
    a = rng.normal(size=(40, 3))
    b = rng.normal(size=(40, 3))
    b[:5] = -a[:5]
    q = tf.quat_between(a, b)
    np.testing.assert_allclose(tf.rotate(q, tf.normalize(a)), tf.normalize(b), atol=1e-9)


def test_frame_transforms_invert_each_other_and_zero_vectors_stay_finite():
    pos, rot = rng.normal(size=(10, 3)), _random_quats(10)
    local = rng.normal(size=(10, 3))
    world = tf.transform_points(pos, rot, local)
    np.testing.assert_allclose(tf.inverse_transform_points(pos, rot, world), local, atol=1e-12)
    assert np.all(tf.normalize(np.zeros((3, 3))) == 0)
    m = tf.frame_from_axes(np.array([0, 0, 2.0]), np.array([1.0, 0, 0.3]))
    np.testing.assert_allclose(m, np.eye(3)[:, [0, 2, 1]] * [1, 1, -1], atol=1e-12)
