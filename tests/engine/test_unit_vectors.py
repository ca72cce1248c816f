"""transforms.unit_and_norm, the one normaliser behind `normalize` and the egocentric kernels: the
same bits as `np.linalg.norm` and a division (the baked keys depend on them), any axis, the
fallback where a vector vanishes, float32 kept."""

import numpy as np

from bodycal_addon.core import transforms as tf


def _vectors(shape, axis=-1, dtype=float):
    v = np.random.default_rng(7).normal(size=shape).astype(dtype)
    np.moveaxis(v, axis, -1)[::5] = 0.0  # every fifth vector vanishes
    return v


def test_norms_and_units_are_numpys_to_the_bit():
    for shape, axis in (((400, 3), -1), ((400, 4), -1), ((3, 40, 10), 0), ((40, 3, 10), 1)):
        v = _vectors(shape, axis)
        u, n = tf.unit_and_norm(v, 0.0, axis)
        ref_n = np.linalg.norm(v, axis=axis)
        assert np.array_equal(n, ref_n)
        keep = np.expand_dims(ref_n, axis)
        assert np.array_equal(u, np.divide(v, keep, out=np.zeros_like(v), where=keep > tf.EPS))
        assert np.array_equal(tf.normalize(v, axis), u)


def test_fallback_where_a_vector_vanishes_and_float32_stays_float32():
    v = _vectors((3, 50), 0, np.float32)
    fallback = np.broadcast_to(np.array([[0.0], [0.0], [1.0]], np.float32), v.shape)
    u, n = tf.unit_and_norm(v, fallback, axis=0)
    assert u.dtype == n.dtype == np.float32
    gone = n <= tf.EPS
    assert gone.any() and np.all(u[:, gone] == fallback[:, gone])
    np.testing.assert_allclose(np.linalg.norm(u[:, ~gone], axis=0), 1.0, rtol=1e-6)
    assert np.all(np.isfinite(tf.normalize(np.zeros((4, 3)))))


def test_one_turn_in_python_floats_is_the_numpy_turn_to_the_bit():
    # transforms.turn_between_one: the spine chain's one-frame aim, quat_between and quat_to_matrix
    # written out in Python floats; any lengths, near-opposite and near-equal directions.
    rng = np.random.default_rng(3)
    a = rng.normal(size=(2000, 3)) * rng.uniform(1e-3, 5.0, (2000, 1))
    b = rng.normal(size=(2000, 3)) * rng.uniform(1e-3, 5.0, (2000, 1))
    b[::7] = -a[::7] + rng.normal(size=(len(a[::7]), 3)) * 1e-3  # nearly opposite
    b[1::7] = a[1::7] * 2.0 + rng.normal(size=(len(a[1::7]), 3)) * 1e-9  # nearly the same direction
    want = tf.quat_to_matrix(tf.quat_between(a, b))
    opposite = (tf.normalize(a) * tf.normalize(b)).sum(-1) < -1.0 + 1e-9  # quat_between's half turn
    assert 0 < opposite.sum() < len(a[::7])
    for k in range(len(a)):
        got = tf.turn_between_one(a[k].tolist(), b[k].tolist())
        assert (got is None) == opposite[k], k
        if got is not None:
            assert np.array_equal(np.array(got), want[k]), k
    # where quat_between takes its other paths, the caller is told to use it
    assert tf.turn_between_one([1.0, 2.0, 3.0], [-2.0, -4.0, -6.0]) is None
    assert tf.turn_between_one([0.0, 0.0, 0.0], [1.0, 0.0, 0.0]) is None
