"""The One Euro filter on device poses (bodycal_addon/recording/filters.py)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bodycal_addon.core import transforms as tf
from bodycal_addon.core.errors import BodyCalError
from bodycal_addon.recording import filters as F
from bodycal_addon.recording.model import Device, Recording


def _reference_one_euro(t, x, min_cutoff, beta, d_cutoff):
    """Casiez's reference implementation, one scalar stream, sample by sample (the derivative of
    the raw samples, low-passed, sets the cutoff)."""
    out, x_prev, t_prev, dx_hat, x_hat = [], None, None, 0.0, None
    for ti, xi in zip(t, x):
        if x_prev is None:
            x_hat = xi
        else:
            dt = ti - t_prev
            a_d = 1.0 / (1.0 + 1.0 / (2 * math.pi * d_cutoff * dt))
            dx_hat += a_d * ((xi - x_prev) / dt - dx_hat)
            a = 1.0 / (1.0 + 1.0 / (2 * math.pi * (min_cutoff + beta * abs(dx_hat)) * dt))
            x_hat += a * (xi - x_hat)
        out.append(x_hat)
        x_prev, t_prev = xi, ti
    return np.array(out)


def test_causal_filter_matches_the_reference_implementation():
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.010, 0.012, 700))  # uneven frame times
    x = np.sin(3 * t) + np.where(t > 4, 0.3, 0.0) + rng.normal(0, 0.01, len(t))
    pos = np.stack([x, np.zeros_like(x), np.zeros_like(x)], -1)[:, None]
    mine = F.smooth_positions(t, pos, 1.5, 4.0, 1.0, two_pass=False)[:, 0, 0]
    np.testing.assert_allclose(mine, _reference_one_euro(t, x, 1.5, 4.0, 1.0), atol=1e-12)


def test_affine_scan_is_the_recurrence():
    rng = np.random.default_rng(1)
    c, b = rng.uniform(0, 1, (1000, 3)), rng.normal(size=(1000, 3))
    y, want = 0.5, []
    for ci, bi in zip(c, b):
        y = ci * y + bi
        want.append(y)
    np.testing.assert_allclose(F.affine_scan(c, b, 0.5), np.array(want), rtol=1e-10, atol=1e-12)


def test_a_still_device_is_smoothed_and_a_moving_one_followed():
    rng = np.random.default_rng(2)
    t = np.arange(900) / 90.0
    still = np.zeros((900, 1, 3)) + rng.normal(0, 0.0005, (900, 1, 3))
    out = F.smooth_positions(t, still, 3.0, 5.0)
    assert np.std(out) < 0.35 * np.std(still)
    # a brisk 1 m/s sweep: the two-pass filter neither lags nor leads it (its middle stays put)
    ramp = np.zeros((900, 1, 3))
    ramp[:, 0, 0] = np.clip((t - 4.0) * 1.0, 0.0, 1.0)
    out = F.smooth_positions(t, ramp, 3.0, 5.0)
    mid = int(4.5 * 90)
    assert abs(out[mid, 0, 0] - ramp[mid, 0, 0]) < 0.002
    causal = F.smooth_positions(t, ramp, 3.0, 5.0, two_pass=False)
    assert causal[mid, 0, 0] < ramp[mid, 0, 0] - 0.005  # the causal one lags behind


def test_rotations_stay_unit_and_keep_their_hemisphere():
    rng = np.random.default_rng(3)
    t = np.arange(400) / 90.0
    axis = tf.normalize(np.array([0.3, 1.0, 0.2]))
    q = tf.axis_angle_to_quat(np.broadcast_to(axis, (400, 3)), 0.8 * np.sin(t))
    noisy = tf.quat_normalize(q + rng.normal(0, 0.003, q.shape))
    noisy[::7] *= -1  # the same rotations, written with the other sign now and then
    out = F.smooth_rotations(t, noisy[:, None], 4.0, 1.0)[:, 0]
    np.testing.assert_allclose(np.linalg.norm(out, axis=-1), 1.0, atol=1e-12)
    err = tf.quat_angle(tf.quat_mul(tf.quat_conj(q), out))
    raw = tf.quat_angle(tf.quat_mul(tf.quat_conj(q), noisy))
    assert np.percentile(err, 95) < 0.6 * np.percentile(raw, 95)


def test_filter_recording_leaves_the_input_alone():
    t = np.arange(50) / 90.0
    pos = np.random.default_rng(4).normal(size=(50, 1, 3))
    rot = np.tile([1.0, 0, 0, 0], (50, 1, 1))
    rec = Recording("r", t, [Device("hmd", "hmd", "head")], pos.copy(), rot.copy(), np.ones((50, 1), bool))
    out = F.filter_recording(rec)
    np.testing.assert_array_equal(rec.positions, pos)
    assert not np.allclose(out.positions, pos) and "One Euro" in out.notes[-1]


@pytest.mark.parametrize("text,want", [("", F.OneEuro()), ("on", F.OneEuro()), ("2,8", F.OneEuro(2.0, 8.0)),
                                       ("2,8,3,0.5", F.OneEuro(2.0, 8.0, 3.0, 0.5))])
def test_parse(text, want):
    assert F.OneEuro.parse(text) == want


@pytest.mark.parametrize("text", ["abc", "1,2,3", "0,2", "-1,2", "1,nan"])
def test_parse_rejects_what_it_cannot_use(text):
    with pytest.raises(BodyCalError, match="filter"):
        F.OneEuro.parse(text)
