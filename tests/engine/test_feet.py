"""Planted feet (bodycal_addon/retarget/feet.py): stance from the foot tracker, the weights, the
planted place, the rolling foot's ankle, the pelvis coming down."""

from __future__ import annotations

import numpy as np

from bodycal_addon.retarget import feet

FPS = 90.0


def _walk(n=400):
    """An ankle that stands, steps 40 cm, stands, steps again, stands."""
    t = np.arange(n) / FPS
    x = np.interp(t, [0, 1.0, 1.5, 2.5, 3.0, 10], [0, 0, 0.4, 0.4, 0.8, 0.8])
    z = 0.09 + 0.08 * np.clip(np.sin(np.pi * np.clip((t - 1.0) / 0.5, 0, 1)), 0, None) \
        + 0.08 * np.clip(np.sin(np.pi * np.clip((t - 2.5) / 0.5, 0, 1)), 0, None)
    return t, np.stack([x, np.zeros(n), z], axis=1)


def test_stances_are_found_and_eased_outside_them():
    t, ankle = _walk()
    st = feet.detect(ankle + np.random.default_rng(0).normal(0, 0.0005, ankle.shape), t, 0.09)
    assert st.count == 3
    stand = (t < 0.95) | ((t > 1.55) & (t < 2.45)) | (t > 3.05)
    assert np.all(st.weight[stand] == 1.0)
    mid_step = (np.abs(t - 1.25) < 0.08) | (np.abs(t - 2.75) < 0.08)
    assert np.all(st.weight[mid_step] == 0.0)
    assert np.abs(np.diff(st.weight)).max() < 0.2  # eased, never switched


def test_planted_place_is_the_stance_s_own():
    t, ankle = _walk()
    st = feet.detect(ankle, t, 0.09)
    none = feet.eased(np.zeros(len(t), bool), 10)
    xy, other = feet.rolling_places(ankle, ankle, st, none)
    np.testing.assert_allclose(xy[t < 0.9, 0], 0.0, atol=1e-6)
    np.testing.assert_allclose(xy[(t > 1.7) & (t < 2.3), 0], 0.4, atol=1e-6)
    np.testing.assert_allclose(xy[t > 3.2, 0], 0.8, atol=1e-6)
    assert np.isnan(other).all()


def test_planted_ankle_holds_still_on_the_floor_and_never_sinks():
    t, ankle = _walk()
    st = feet.detect(ankle, t, 0.09)
    none = feet.eased(np.zeros(len(t), bool), 10)
    wander = ankle + np.stack([0.01 * np.sin(7 * t), 0.01 * np.cos(5 * t), -0.03 + 0.0 * t], axis=1)
    heel_at, ball_at = feet.rolling_places(ankle, ankle, st, none)
    weight, share, heel_at, ball_at = feet.rolling(st, none, feet.blend_frames(FPS), heel_at, ball_at)
    under = np.array([0.0, 0.0, -0.085])
    contact = feet.Contact(under, under, under[None])
    frames = np.repeat(np.eye(3)[None], len(t), axis=0)
    out = feet.roll(wander, heel_at, ball_at, weight, share, frames, contact)
    full = weight == 1.0
    assert np.ptp(out[full & (t < 0.9)], axis=0).max() < 1e-9
    # on the floor, within the guard's smooth blend above it
    assert np.all((out[full, 2] >= 0.085) & (out[full, 2] <= 0.085 + contact.floor_blend / 2))
    assert out[:, 2].min() >= 0.085 - 1e-12  # never below the floor, planted or not
    assert np.linalg.norm(np.diff(out, axis=0), axis=1).max() < 0.02  # no pop at the easings


def test_sole_lift_is_the_lowest_point():
    frames = np.broadcast_to(np.eye(3), (2, 3, 3)).copy()
    c, s = np.cos(0.3), np.sin(0.3)
    frames[1] = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])  # toe down
    sole = np.array([[0.0, -0.05, -0.08], [0.0, 0.15, -0.06]])
    lift = feet.sole_lift(frames, sole)
    np.testing.assert_allclose(lift[0], 0.08)
    assert np.isclose(lift[1], max(-(frames[1] @ p)[2] for p in sole))


def test_pelvis_comes_down_only_as_far_as_a_planted_leg_needs():
    hips = np.array([[[0.1, 0.0, 0.95], [-0.1, 0.0, 0.95]]] * 3)
    targets = np.array([[[0.1, 0.0, 0.09], [-0.1, 0.2, 0.09]]] * 3)
    lengths = np.array([0.82, 0.82])
    weights = np.array([[1.0, 1.0], [0.5, 0.0], [0.0, 0.0]])
    drop = feet.pelvis_drop(hips, targets, lengths, weights)
    need_l = 0.95 - 0.09 - feet.REACH * 0.82
    need_r = 0.95 - 0.09 - np.sqrt((feet.REACH * 0.82) ** 2 - 0.04)
    np.testing.assert_allclose(drop, [max(need_l, need_r), 0.5 * need_l, 0.0])
