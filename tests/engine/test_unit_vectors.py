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
