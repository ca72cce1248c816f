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


def _swing(step=0.7, swing_s=0.4):
    """A foot swinging in, standing a second, swinging out: `step` m forward (lifting 10 cm) in
    `swing_s`, smooth (C1) and as fast as a walker's (2.6 m/s at most); one stance."""
    t = np.arange(int(round(1.95 * FPS))) / FPS
    ease = [np.clip((t - a) / swing_s, 0, 1) for a in (-0.1, 1.5)]
    x = sum(step * u * u * (3 - 2 * u) for u in ease)
    z = 0.09 + sum(0.1 * np.sin(np.pi * u) ** 2 for u in ease)
    return t, np.stack([x, np.zeros(len(t)), z], axis=1)


def test_off_the_contact_the_planted_point_moves_as_the_method_moves_it():
    """Where the method slides the foot while it stands (a child's ankle scaled about the root), the
    plant holds it and the method's ankle is elsewhere when the foot lifts: off the contact the
    pinned point moves as the method's from the contact's edge on, so the easing takes away only
    the offset the plant made there, and the ankle keeps about the method's acceleration (held still
    off the contact, the place fell behind the swing and the easing closed the gap late)."""
    t, ankle = _swing()
    st = feet.detect(ankle, t, 0.09)
    assert st.count == 1
    none = feet.eased(np.zeros(len(t), bool), 10)
    under = np.array([0.0, 0.0, -0.085])
    contact = feet.Contact(under, under, under[None])
    frames = np.repeat(np.eye(3)[None], len(t), axis=0)
    method = ankle + np.stack([0.1 * t, 0 * t, 0 * t], axis=1)  # slides 10 cm/s
    ref = method + under  # where the method puts the contact point
    n = feet.blend_frames(FPS)
    heel_at, ball_at = feet.rolling_places(ref, ref, st, none)
    held = feet.rolling(st, none, n, heel_at, ball_at)
    weight, share, h_at, b_at = feet.rolling(st, none, n, heel_at, ball_at, ref, ref)
    on = weight >= 1.0
    # in the contact: the plant's own places
    np.testing.assert_array_equal(h_at[on], held[2][on])
    # off it, past the first frames (where it takes the method's velocity up): the method's steps
    # over the floor
    far = np.abs(np.arange(len(t))[:, None] - np.flatnonzero(on)[None]).min(axis=1) > int(round(n * feet.FOLLOW))
    steps = far[1:] & far[:-1]
    assert steps.sum() > 40
    np.testing.assert_allclose(np.diff(h_at, axis=0)[steps], np.diff(ref[:, :2], axis=0)[steps], atol=1e-12)

    def acc_p95(p):
        return np.percentile(np.linalg.norm(np.diff(p, 2, axis=0), axis=1), 95) * FPS * FPS

    out = feet.roll(method, h_at, b_at, weight, share, frames, contact)
    before = feet.roll(method, held[2], held[3], held[0], held[1], frames, contact)
    # 1.22x (the height still eases from the floor to the method's), held still 1.69x
    assert acc_p95(out) <= 1.3 * acc_p95(method), (acc_p95(out), acc_p95(method))
    assert acc_p95(before) > 1.5 * acc_p95(method)  # what it was: the easing caught up with the swing
    assert np.linalg.norm(np.diff(out, axis=0), axis=1).max() < 0.04  # no pop at the contact's edges


def test_the_pivot_hands_over_without_a_step():
    """The ball's share of the pivot changes smoothly inside a contact (0.057 a frame at most here):
    where the heel lifts before the ball (a toe-off) and where both lift within a frame (a foot
    lifted flat). The outer weights' tenth the share counts stopped at a stance's end: a step of
    0.098 at a toe-off, and 0.41 where both lifted together (both inner weights at ~0 there, the
    tenths were all the ratio had)."""
    F, n = 120, 11
    frame = np.arange(F)
    for heel_stop, ball_stop in ((50, 80), (79, 80), (80, 80), (80, 79)):
        heel = feet.eased((frame >= 20) & (frame < heel_stop), n)
        ball = feet.eased((frame >= 30) & (frame < ball_stop), n)
        here = np.tile([0.0, 0.0], (F, 1))
        weight, share, _, _ = feet.rolling(heel, ball, n, here, here)
        assert np.abs(np.diff(share)).max() < 0.09, (heel_stop, ball_stop, np.abs(np.diff(share)).max())
        assert share[25] < 0.1 and (heel_stop > 60 or share[70] > 0.9)


def _quick_step(move: float, lift: float = 0.02, n: int = 300, swing_s: float = 0.2):
    """An ankle that stands, lifts `lift` m for `swing_s` while moving `move` m, and stands again (a
    three-point kit's shuffle: the stepper's lowest lift on a real A-Frame take)."""
    t = np.arange(n) / FPS
    u = np.clip((t - 1.0) / swing_s, 0.0, 1.0)
    x = move * u * u * u * (10 - 15 * u + 6 * u * u)  # minimum jerk
    z = 0.09 + lift * np.sin(np.pi * u)
    return t, np.stack([x, np.zeros(n), z], axis=1)


def _planned(ankle, t, drift=None):
    st = feet.detect(ankle, t, 0.09, drift)
    none = feet.eased(np.zeros(len(t), bool), 10)
    heel_at, ball_at = feet.rolling_places(ankle, ankle, st, none)
    return st, feet.rolling(st, none, feet.blend_frames(FPS), heel_at, ball_at, ankle, ankle)


def test_a_quick_short_step_is_a_step_not_a_slide_over_the_floor():
    """Two stances a short gap apart were one contact: across the gap the foot was held on the
    floor (weight 1) while its place slid to the next stance's, 12 cm in 0.2 s (the real A-Frame
    takes grabLeft/grabRight: 11-13 cm, up to 15 mm a frame). A foot that comes down elsewhere
    steps: the plant lets go across the gap, and a planted foot's place never moves."""
    t, ankle = _quick_step(0.12)
    st, (weight, share, heel_at, _) = _planned(ankle, t)
    assert st.count == 2
    gap = np.flatnonzero(st.weight < 1.0)  # between the two stances (each eased in and out)
    assert 0 < len(gap) < 2 * feet.blend_frames(FPS)  # a short gap: what was bridged
    planted = (weight[1:] >= 1.0) & (weight[:-1] >= 1.0)
    assert np.abs(np.diff(heel_at, axis=0)[planted]).max() < 1e-9  # no planted frame slides
    assert weight[gap].min() < 0.5  # the foot lifts as the method lifts it


def test_a_foot_lifted_for_a_moment_in_place_stays_one_contact():
    """The bridge kept where it belongs: a foot lifted 8 cm for 0.2 s and set down where it was is
    one contact (the ankle does not dip to the method's and back in a few frames)."""
    t, ankle = _quick_step(0.0, lift=0.08)
    st, (weight, _, heel_at, _) = _planned(ankle, t)
    gap = np.flatnonzero(st.weight < 1.0)
    assert st.count == 2 and 0 < len(gap) < 2 * feet.blend_frames(FPS)
    assert weight.min() >= 1.0
    assert np.ptp(heel_at, axis=0).max() < 1e-9


def test_a_slow_short_step_is_a_step_though_the_foot_never_leaves_the_stance_s_bounds():
    """The real take simsaber's right foot (a three-point kit, the stepper's estimate) steps 7.4 cm
    in 0.5 s with its ankle 2.3 cm up, never faster than 0.29 m/s: within a stance's hold (below
    0.4 m/s and 7 cm), so the whole step was one stance placed at its average, and the avatar's
    heel stood still while the foot turned on it and swept its ball 66 mm over the floor (every
    method, bench_three_point's floor_travel_max_mm). A point that has moved DRIFT from where it
    came down is no longer standing: two stances, each placed where the foot stands. An estimated
    foot's (`DRIFT`, FeetPlan): a tracked foot's points drift within a stance (not measured yet)."""
    t, ankle = _quick_step(0.074, lift=0.023, swing_s=0.5)
    assert feet.detect(ankle, t, 0.09).count == 1  # a tracked foot's stance as before
    st, (weight, _, heel_at, _) = _planned(ankle, t, feet.DRIFT)
    assert st.count == 2
    planted = (weight[1:] >= 1.0) & (weight[:-1] >= 1.0)
    assert np.abs(np.diff(heel_at, axis=0)[planted]).max() < 1e-9  # no planted frame slides
    before, after = t < 0.9, t > 1.7
    assert np.abs(heel_at[before, 0]).max() < 0.005
    assert np.abs(heel_at[after, 0] - 0.074).max() < 0.005


def test_live_an_estimated_foot_s_slow_short_step_releases_and_replants():
    """The same slow short step streamed (`CausalStance`, forward only): without the drift cut the
    live stance held the foot where it came down for as long as the hold lasted, 74 mm behind the
    performer's after the step (a three-point avatar's foot left behind, then dragged when the hold
    ended). With an estimated foot's DRIFT it lets go once the point has moved DRIFT and plants
    again where the foot stands, as the bake does; a planted place never moves."""
    t, ankle = _quick_step(0.074, lift=0.023, swing_s=0.5)
    weight, at = feet.CausalStance(0.09, FPS).update(ankle, t, ankle)
    held = t > 0.5  # planted MIN_STANCE_S and an easing after the take's start
    assert weight[held].min() >= 1.0 and np.abs(at[held, 0]).max() < 0.005  # a tracked foot's as before
    weight, at = feet.CausalStance(0.09, FPS, feet.DRIFT).update(ankle, t, ankle)
    foot = ankle[:, 0] + weight * (np.nan_to_num(at[:, 0]) - ankle[:, 0])
    _, (bake_w, _, bake_at, _) = _planned(ankle, t, feet.DRIFT)
    bake = ankle[:, 0] + bake_w * (np.nan_to_num(bake_at[:, 0]) - ankle[:, 0])
    after = t > 1.8  # both planted again where the foot stands
    assert weight[after].min() >= 1.0 and bake_w[after].min() >= 1.0
    assert np.abs(foot[after] - ankle[after, 0]).max() < 0.002
    assert np.abs(foot[after] - bake[after]).max() < 0.002
    assert weight[(t > 1.1) & (t < 1.7)].min() < 0.5  # released in between (the foot moves as the method's)
    planted = (weight[1:] >= 1.0) & (weight[:-1] >= 1.0)
    assert np.abs(np.diff(at[:, 0])[planted]).max() < 1e-12
    assert np.abs(np.diff(weight)).max() < 0.2  # eased out and in, never switched
    # forward only: one frame at a time is the whole take's, and the frames before the step do not
    # depend on it
    one = feet.CausalStance(0.09, FPS, feet.DRIFT)
    parts = [one.update(ankle[f:f + 1], t[f:f + 1], ankle[f:f + 1]) for f in range(len(t))]
    np.testing.assert_array_equal(np.concatenate([p[0] for p in parts]), weight)
    np.testing.assert_array_equal(np.concatenate([p[1] for p in parts]), at)
    still = ankle.copy()
    still[:, 0] = 0.0
    early = t < 1.0
    np.testing.assert_array_equal(feet.CausalStance(0.09, FPS, feet.DRIFT).update(still, t, still)[0][early],
                                  weight[early])


def test_live_the_drift_cut_leaves_what_the_bake_does_not_cut_as_it_was():
    """A walk's steps leave the hold (faster than EXIT_SPEED): nothing to cut. A foot that moves
    4.4 cm never faster than STANCE_SPEED (a real A-Frame take's estimated foot, `tracked`: 0.18
    m/s) is slow and low where it is DRIFT away, and the bake's two stances touch there: one
    stance, as the stream's (cut, the avatar's foot skimmed the floor 27 mm there, 7 mm held)."""
    walk = _walk()
    slow = _quick_step(0.044, lift=0.022, swing_s=0.6)
    t, ankle = slow
    peak = (np.linalg.norm(np.diff(ankle, axis=0), axis=1) / np.diff(t)).max()
    assert 0.05 < peak < feet.STANCE_SPEED  # the step as made: it moves, never as fast as a stance's limit
    assert feet.detect(slow[1], slow[0], 0.09, feet.DRIFT).count == 1
    for t, ankle in (walk, slow):
        plain = feet.CausalStance(0.09, FPS).update(ankle, t, ankle)
        cut = feet.CausalStance(0.09, FPS, feet.DRIFT).update(ankle, t, ankle)
        np.testing.assert_array_equal(cut[0], plain[0])
        np.testing.assert_array_equal(cut[1], plain[1])
