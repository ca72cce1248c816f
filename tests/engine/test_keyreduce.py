"""Key reduction (FORMATS.md §4.2, "Keys"): the bound holds at every sample whatever the curve, and
it really reduces what is reducible."""

from __future__ import annotations

from unittest import mock

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bodycal_addon.body.animation import AvatarAnimation, resample
from bodycal_addon.core import transforms as tf
from bodycal_addon.output import keyreduce as kr


def _motion(frames: int, bones: int, seed: int, noise_deg: float) -> np.ndarray:
    """Smooth random rotations (random walks of angular velocity) plus white noise."""
    rng = np.random.default_rng(seed)
    omega = np.cumsum(rng.normal(0.0, 0.02, (frames, bones, 3)), axis=0) * 0.05
    omega += rng.normal(0.0, np.radians(noise_deg), (frames, bones, 3))
    q = np.empty((frames, bones, 4))
    q[0] = tf.quat_normalize(rng.normal(size=(bones, 4)))
    for f in range(1, frames):  # test data only
        angle = np.linalg.norm(omega[f], axis=-1)
        q[f] = tf.quat_normalize(tf.quat_mul(tf.axis_angle_to_quat(omega[f], angle), q[f - 1]))
    return tf.continuous_quaternions(q)


def _worst_angle(q: np.ndarray, keep: np.ndarray, values: np.ndarray) -> float:
    """The largest angle between a sample and what linear keys (values at kept frames) evaluate to."""
    frames = np.arange(len(q), dtype=float)
    worst = 0.0
    for b in range(q.shape[1]):
        approx = kr.interpolate(frames, keep[:, b], values[:, b])
        worst = max(worst, float(kr.rotation_error(q[:, b], approx).max()))
    return worst


def _blocks_of(frames: int):
    """The search's block length set small, so that short test curves span several blocks."""
    return mock.patch.object(kr, "BLOCK_FRAMES", frames)


@settings(max_examples=40, deadline=None)
@given(frames=st.integers(2, 300), bones=st.integers(1, 12), seed=st.integers(0, 2**31),
       noise=st.sampled_from([0.0, 0.05, 0.5, 3.0]), tol_deg=st.sampled_from([0.01, 0.1, 0.5, 2.0]),
       block=st.sampled_from([1, 2, 7, 64, kr.BLOCK_FRAMES]))
def test_every_sample_is_within_the_rotation_tolerance(frames, bones, seed, noise, tol_deg, block):
    q = _motion(frames, bones, seed, noise)
    with _blocks_of(block):
        keep, values = kr.rotation_keys(q, np.radians(tol_deg))
    assert keep.shape == (frames, bones) and values.shape == q.shape
    assert keep[0].all() and keep[-1].all()
    assert _worst_angle(q, keep, values) <= np.radians(tol_deg) * (1 + 1e-6) + 1e-9


@settings(max_examples=40, deadline=None)
@given(frames=st.integers(2, 400), seed=st.integers(0, 2**31), tol_mm=st.sampled_from([0.1, 0.5, 5.0]),
       block=st.sampled_from([1, 5, 64, kr.BLOCK_FRAMES]))
def test_every_sample_is_within_the_location_tolerance(frames, seed, tol_mm, block):
    rng = np.random.default_rng(seed)
    p = np.cumsum(np.cumsum(rng.normal(0, 1e-4, (frames, 3)), axis=0), axis=0) + rng.normal(0, 2e-4, (frames, 3))
    with _blocks_of(block):
        keep, values = kr.location_keys(p, tol_mm / 1000.0)
    approx = kr.interpolate(np.arange(frames, dtype=float), keep, values)
    assert keep[0] and keep[-1]
    assert np.linalg.norm(approx - p, axis=1).max() <= tol_mm / 1000.0 * (1 + 1e-9)


def test_zero_tolerance_keeps_every_sample_as_it_is():
    q = _motion(50, 3, 0, 0.5)
    keep, values = kr.rotation_keys(q, 0.0)
    assert keep.all()
    np.testing.assert_array_equal(values, q)
    p = np.random.default_rng(0).normal(size=(50, 3))
    keep, values = kr.location_keys(p, 0.0)
    assert keep.all()
    np.testing.assert_array_equal(values, p)


def test_what_linear_keys_reproduce_exactly_needs_only_its_ends():
    """A still bone, a constant-speed location and a rotation about one axis at constant speed
    (component-wise lerp of two quaternions is the same path, normalised) keep only the ends."""
    f = 500
    still = np.tile([[0.6, 0.0, 0.8, 0.0]], (f, 1))
    turn = tf.axis_angle_to_quat(np.tile([[0.0, 0.0, 1.0]], (f, 1)), np.linspace(0.0, np.radians(60), f))
    keep, _ = kr.rotation_keys(np.stack([still, turn], axis=1), np.radians(0.1))
    assert keep[:, 0].sum() == 2
    # nlerp and slerp part by at most ~0.05 deg over 60 deg: a few keys, nowhere near 500
    assert keep[:, 1].sum() <= 4
    ramp = np.linspace([0, 0, 0], [1.0, -2.0, 0.5], f)
    assert kr.location_keys(ramp, 1e-4)[0].sum() == 2


def test_a_long_take_is_searched_in_blocks_whose_ends_are_keys():
    """Past one block the bound still holds across the block ends, each block end is a key, and
    those are nearly all the keys a still bone gets (one per block)."""
    f = 3 * kr.BLOCK_FRAMES + 100
    still = np.tile([[0.6, 0.0, 0.8, 0.0]], (f, 1))
    q = np.stack([still, _motion(f, 1, 3, 0.05)[:, 0]], axis=1)
    keep, values = kr.rotation_keys(q, np.radians(0.1))
    ends = np.r_[np.arange(0, f, kr.BLOCK_FRAMES), f - 1]
    assert keep[ends].all()
    assert keep[:, 0].sum() == len(ends)
    assert _worst_angle(q, keep, values) <= np.radians(0.1) * (1 + 1e-6) + 1e-9
    assert kr.location_keys(np.linspace([0, 0, 0], [1.0, -2.0, 0.5], f), 1e-4)[0].sum() == len(ends)


def _slow_swings(frames: int, bones: int, fps: float = 90.0) -> np.ndarray:
    """Each bone swings +-30 deg at 0.3 Hz about its own axis: peak angular acceleration ~100
    deg/s^2, so linear keys 8 frames apart stay within 0.1 deg (error ~ a h^2 / 8)."""
    rng = np.random.default_rng(1)
    t = np.arange(frames) / fps
    axes = tf.normalize(rng.normal(size=(bones, 3)))
    angle = np.radians(30.0) * np.sin(2 * np.pi * 0.3 * t[:, None] + rng.uniform(0, 6, bones))
    return tf.continuous_quaternions(tf.axis_angle_to_quat(np.broadcast_to(axes, (frames, bones, 3)), angle))


def test_smooth_motion_is_reduced_and_the_reduction_tightens_with_the_tolerance():
    q = _slow_swings(2000, 6)
    counts = [int(kr.rotation_keys(q, np.radians(t))[0].sum()) for t in (0.5, 0.1, 0.02)]
    assert counts[0] < counts[1] < counts[2] < q.shape[0] * q.shape[1]
    assert counts[1] * 5 <= q.shape[0] * q.shape[1], counts


def test_bones_are_reduced_independently_of_each_other():
    """Batched bone by bone: the result for a bone never depends on its neighbours."""
    q = _motion(400, 19, 5, 0.5)
    together, values = kr.rotation_keys(q, np.radians(0.2))
    for b in (0, 7, 8, 18):
        alone, alone_values = kr.rotation_keys(q[:, b:b + 1], np.radians(0.2))
        np.testing.assert_array_equal(together[:, b], alone[:, 0])
        np.testing.assert_array_equal(values[:, b], alone_values[:, 0])


def _anim(frames: int, fps: float, seed: int = 0) -> AvatarAnimation:
    q = _motion(frames, 4, seed, 0.0)
    rng = np.random.default_rng(seed)
    root = np.cumsum(rng.normal(0, 0.01, (frames, 3)), axis=0)
    return AvatarAnimation("a", ["b0", "b1", "b2", "b3"], q, "b0", root, 2.0 + np.arange(frames) / fps,
                           joints_world={"pelvis": root.copy()})


def test_resampling_keeps_the_duration_and_the_samples_it_lands_on():
    anim = _anim(901, 90.0)  # 10 s
    out = resample(anim, 30.0)
    assert out.frame_count == 301
    assert out.time[0] == anim.time[0] and abs(out.time[-1] - anim.time[-1]) < 1e-9
    # Every third 90 Hz sample is a 30 fps sample: the same pose there.
    np.testing.assert_allclose(np.abs((out.rotations * anim.rotations[::3]).sum(-1)), 1.0, atol=1e-9)
    np.testing.assert_allclose(out.root_location, anim.root_location[::3], atol=1e-12)
    np.testing.assert_allclose(out.joints_world["pelvis"], anim.joints_world["pelvis"][::3], atol=1e-12)


def test_resampling_between_samples_is_the_slerp_and_the_lerp():
    anim = _anim(11, 10.0, seed=2)
    out = resample(anim, 20.0)  # every other output sample is halfway between two inputs
    assert out.frame_count == 21
    mid = tf.slerp(anim.rotations[3], anim.rotations[4], 0.5)
    np.testing.assert_allclose(np.abs((out.rotations[7] * mid).sum(-1)), 1.0, atol=1e-12)
    np.testing.assert_allclose(out.root_location[7], anim.root_location[3:5].mean(0), atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(out.rotations, axis=-1), 1.0, atol=1e-12)


@pytest.mark.parametrize("fps", [0.0, -30.0, float("nan")])
def test_resampling_refuses_a_rate_that_is_not_positive(fps):
    with pytest.raises(ValueError):
        resample(_anim(10, 30.0), fps)


def test_continuous_quaternions_in_place_is_the_copy_without_the_copy():
    """The bake makes a given-away animation's rotations continuous in place (87 MB less on a
    10-minute take): the same numbers as the copy, in the array it was given."""
    rng = np.random.default_rng(3)
    q = rng.normal(size=(500, 7, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    expected = tf.continuous_quaternions(q)
    assert not np.array_equal(expected, q)  # some signs do flip
    out = tf.continuous_quaternions(q, in_place=True)
    assert out is q
    np.testing.assert_array_equal(q, expected)
    assert (np.einsum("fbi,fbi->fb", q[1:], q[:-1]) >= 0).all()


@settings(max_examples=25, deadline=None)
@given(frames=st.integers(2, 300), seed=st.integers(0, 2**31), noise=st.sampled_from([0.0, 0.05, 0.5]),
       block=st.sampled_from([1, 2, 7, 64]))
def test_key_values_stay_in_the_band_and_do_not_depend_on_the_blocks(frames, seed, noise, block):
    """A key's value is within BAND x the tolerance of its own sample, and it is the same value
    whatever the block length (a frame shared by two blocks gets one value)."""
    q = _motion(frames, 3, seed, noise)
    tol = np.radians(0.1)
    keep, values = kr.rotation_keys(q, tol)
    with _blocks_of(block):
        keep_b, values_b = kr.rotation_keys(q, tol)
    assert kr.rotation_error(q[keep], values[keep]).max() <= kr.BAND * tol * (1 + 1e-6) + 1e-9
    both = keep & keep_b
    np.testing.assert_allclose(values[both], values_b[both], rtol=0, atol=1e-12)
    p = np.cumsum(np.random.default_rng(seed).normal(0, 1e-3, (frames, 3)), axis=0)
    keep, values = kr.location_keys(p, 1e-3)
    assert np.linalg.norm(values[keep] - p[keep], axis=1).max() <= kr.BAND * 1e-3 * (1 + 1e-9)


@pytest.mark.parametrize("block", [1, 2, 3, 4, 7, 64])
def test_keys_written_into_the_samples_array_are_the_keys_of_a_copy(block):
    """`out=` the samples themselves (the bake's own float32 array): the same keys and values as
    with a separate array, across block ends (blocks shorter than the smoothing window too), and
    the frames not kept are left as they were."""
    q = _motion(300, 4, 2, 0.3).astype(np.float32)
    with _blocks_of(block):
        keep, values = kr.rotation_keys(q, np.radians(0.1))
        inplace = q.copy()
        keep_i, values_i = kr.rotation_keys(inplace, np.radians(0.1), out=inplace)
    assert values_i is inplace
    np.testing.assert_array_equal(keep_i, keep)
    np.testing.assert_array_equal(values_i[keep], values[keep])
    np.testing.assert_array_equal(inplace[~keep], q[~keep])


def test_keys_off_the_noise_save_keys_on_jitter_and_cost_none_on_smooth_motion():
    """Slow swings with white jitter of half the tolerance: key values in the band keep fewer keys
    than key values on the samples (BAND 0: 22% fewer); on the swings alone, as many."""
    smooth = _slow_swings(3000, 6)
    rng = np.random.default_rng(4)
    jitter = tf.axis_angle_to_quat(tf.normalize(rng.normal(size=smooth.shape[:2] + (3,))),
                                   np.abs(rng.normal(0.0, np.radians(0.05), smooth.shape[:2])))
    noisy = tf.continuous_quaternions(tf.quat_mul(jitter, smooth))
    tol = np.radians(0.1)
    for q, most in ((noisy, 0.85), (smooth, 1.02)):
        with mock.patch.object(kr, "BAND", 0.0):
            on_samples = int(kr.rotation_keys(q, tol)[0].sum())
        keep, values = kr.rotation_keys(q, tol)
        assert int(keep.sum()) <= most * on_samples, (int(keep.sum()), on_samples)
        assert _worst_angle(q, keep, values) <= tol * (1 + 1e-6) + 1e-9


def _worst_bezier_angle(q: np.ndarray, keep: np.ndarray, values: np.ndarray, frames=None) -> float:
    """The largest angle between a sample and what Bézier keys with Auto Clamped handles (values at
    kept frames) evaluate to (output/bezier.py: Blender's rule, checked against Blender in
    tests/blender/test_output.py)."""
    from bodycal_addon.output import bezier

    return float(kr.rotation_error(q, bezier.evaluate_keys(keep, values, frames)).max())


@settings(max_examples=30, deadline=None)
@given(frames=st.integers(2, 300), bones=st.integers(1, 8), seed=st.integers(0, 2**31),
       noise=st.sampled_from([0.0, 0.05, 0.5, 3.0]), tol_deg=st.sampled_from([0.05, 0.1, 0.5, 2.0]),
       block=st.sampled_from([7, 64, kr.BLOCK_FRAMES]), uneven=st.booleans(), f32=st.booleans())
def test_bezier_keys_keep_every_sample_within_the_rotation_tolerance(frames, bones, seed, noise, tol_deg, block,
                                                                     uneven, f32):
    """Bézier keys (FORMATS.md §4.2): the curve Blender draws through them with Auto Clamped handles
    stays within the tolerance at every sample, on evenly or unevenly spaced frames, from float32
    rotations as the bake keys them too (their norms off by ~6e-8: 0.01 deg near the bound if
    taken as unit); the keys are the linear ones plus what the Bézier curve needs."""
    q = _motion(frames, bones, seed, noise)
    given_q = q.astype(np.float32) if f32 else q
    at = np.cumsum(np.random.default_rng(seed).uniform(0.5, 2.0, frames)) if uneven else None
    with _blocks_of(block):
        linear, _ = kr.rotation_keys(given_q, np.radians(tol_deg))
        keep, values = kr.rotation_keys(given_q.copy(), np.radians(tol_deg), bezier=True, frames=at)
    assert (keep >= linear).all()
    assert _worst_bezier_angle(q, keep, values, at) <= np.radians(tol_deg) * (1 + 1e-6) + 1e-9


def test_linear_keys_drawn_as_bezier_stray_and_the_bezier_reduction_mends_it():
    """The same kept keys as Bézier curves leave the tolerance between keys far behind (a key at a
    corner with long straight spans each side: the handles swing past the lines); the Bézier-aware
    reduction adds the keys that bring it back, a few percent more."""
    q = _motion(600, 6, 3, 0.05)
    linear, values = kr.rotation_keys(q, np.radians(0.1))
    assert _worst_bezier_angle(q, linear, values) > np.radians(0.3)
    keep, values = kr.rotation_keys(q, np.radians(0.1), bezier=True)
    assert _worst_bezier_angle(q, keep, values) <= np.radians(0.1) * (1 + 1e-6)
    assert linear.sum() < keep.sum() < 1.5 * linear.sum()


@settings(max_examples=30, deadline=None)
@given(frames=st.integers(2, 300), seed=st.integers(0, 2**31), tol_mm=st.sampled_from([0.1, 0.5, 5.0]))
def test_bezier_keys_keep_every_sample_within_the_location_tolerance(frames, seed, tol_mm):
    from bodycal_addon.output import bezier

    rng = np.random.default_rng(seed)
    p = np.cumsum(np.cumsum(rng.normal(0, 1e-4, (frames, 3)), axis=0), axis=0) + rng.normal(0, 2e-4, (frames, 3))
    keep, values = kr.location_keys(p, tol_mm / 1000.0, bezier=True)
    got = bezier.evaluate_keys(keep[:, None], values[:, None])[:, 0]
    assert np.linalg.norm(got - p, axis=1).max() <= tol_mm / 1000.0 * (1 + 1e-6) + 1e-12
