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


def _body(frames=900, fps=90.0, seed=0, noise=0.0005):
    """A pelvis swaying and turning fast through the room, a hand held still on the belly (rigid
    with the pelvis), the other hand clapping onto it once; 0.5 mm of tracker noise."""
    rng = np.random.default_rng(seed)
    t = np.arange(frames) / fps
    yaw = 0.8 * np.sin(2 * np.pi * 1.2 * t)
    q_pelvis = tf.axis_angle_to_quat(np.array([0.0, 0.0, 1.0]), yaw)
    p_pelvis = np.stack([0.6 * np.sin(2 * np.pi * 0.7 * t), 0.4 * t, 1.0 + 0.03 * np.sin(2 * np.pi * 2 * t)], -1)
    belly = p_pelvis + tf.rotate(q_pelvis, np.array([0.0, -0.18, 0.05]))
    # the clapping hand: from 0.5 m away to the resting hand in 0.15 s and back (a V in distance)
    clap_t = 5.0
    reach = np.clip(np.abs(t - clap_t) / 0.15, 0.0, 1.0)
    clap = belly + tf.rotate(q_pelvis, np.array([0.0, 0.0, 0.08])) + tf.rotate(q_pelvis, np.array([0.5, 0.0, 0.0])) \
        * reach[:, None]
    pos = np.stack([p_pelvis, belly, clap], 1) + rng.normal(0, noise, (frames, 3, 3))
    rot = np.stack([q_pelvis] * 3, 1)
    devices = [Device("tracker_pelvis", "tracker", "pelvis"), Device("ctl_l", "controller", "hand_l"),
               Device("ctl_r", "controller", "hand_r")]
    rec = Recording("body", t, devices, pos, rot, np.ones((frames, 3), bool))
    return rec, belly, clap, q_pelvis, p_pelvis


def test_a_hand_resting_on_a_moving_body_keeps_its_place_on_it():
    """Smoothed on the pelvis (the default), the resting hand stays where it rests on the body (the
    smoothed body the avatar is given) while the body sways and turns; smoothed in the room it
    lags the body by millimetres."""
    rec, belly, _clap, q, p = _body()

    def on_body(r):  # the hand in its recording's pelvis frame
        return tf.rotate(tf.quat_conj(r.rotations[:, 0]), r.positions[:, 1] - r.positions[:, 0])

    truth = tf.rotate(tf.quat_conj(q), belly - p)
    err = {}
    for anchored in (True, False):
        out = F.filter_recording(rec, F.OneEuro(anchored=anchored))
        err[anchored] = np.percentile(np.linalg.norm(on_body(out) - truth, axis=-1), 95) * 1000
    assert err[True] < 1.5, err
    assert err[False] > 3 * err[True], err


def test_a_clap_is_not_rounded_off(monkeypatch):
    """The hands meeting fast are hardly smoothed at that moment: the filtered hands come as near as
    the recorded ones; without the contact term they stop short by centimetres."""
    rec, belly, clap, _q, _p = _body(noise=0.0)
    nearest, gain = {}, F.CONTACT_BETA
    for beta in (gain, 0.0):
        monkeypatch.setattr(F, "CONTACT_BETA", beta)
        out = F.filter_recording(rec, F.OneEuro())
        nearest[beta] = np.linalg.norm(out.positions[:, 2] - out.positions[:, 1], axis=-1).min()
    raw = np.linalg.norm(clap - belly, axis=-1).min()
    assert nearest[gain] - raw < 0.002, nearest
    assert nearest[0.0] - raw > 0.006, nearest


def test_without_a_pelvis_tracker_every_device_is_smoothed_in_the_room_the_hands_with_the_contact_term():
    """No body part to smooth on (a headset's kit): the room, and a clap is still not rounded off."""
    rec, *_ = _body()
    rec.devices[0].role = None
    cfg = F.OneEuro()
    out = F.filter_recording(rec, cfg)
    room = F.filter_recording(rec, F.OneEuro(anchored=False))
    hands = [i for i, d in enumerate(rec.devices) if d.role in ("hand_l", "hand_r")]
    others = [i for i in range(len(rec.devices)) if i not in hands]
    assert len(hands) == 2
    np.testing.assert_array_equal(out.positions[:, others], room.positions[:, others])
    np.testing.assert_array_equal(out.rotations, room.rotations)
    np.testing.assert_array_equal(out.positions[:, hands], F.smooth_positions(
        rec.time, rec.positions[:, hands], cfg.min_cutoff, cfg.beta, cfg.d_cutoff, cfg.two_pass,
        F.contact_cutoff(rec, hands)))
    assert not np.array_equal(out.positions[:, hands], room.positions[:, hands])  # the hands do meet here
    assert "no pelvis tracker" in out.notes[-1] and "the hands with the contact term" in out.notes[-1]
