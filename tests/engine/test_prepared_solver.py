"""The prepared solver (bodycal_addon/retarget/solver.py) and its live entry (live/solver.py): one
solver for the bake and the live loop, the same values whatever the block of frames; and the
causal variants a live stream needs (the forward One Euro carried across blocks, the stance from
the frames so far)."""

from __future__ import annotations

import pathlib
from dataclasses import replace

import numpy as np
import pytest

from bodycal_addon.body.skeleton import JOINTS
from bodycal_addon.core import one_frame
from bodycal_addon.core.errors import BodyCalError
from bodycal_addon.live.solver import LiveSolver
from bodycal_addon.recording import filters
from bodycal_addon.recording.filters import OneEuro, OneEuroStream
from bodycal_addon.recording.live.buffer import LiveRecording
from bodycal_addon.recording.model import Recording
from bodycal_addon.retarget import feet
from bodycal_addon.retarget import pipeline as pl
from bodycal_addon.retarget.pose_source import RecordingSource
from bodycal_addon.retarget.solver import PreparedSolver
from bodycal_dev import synthetic
from bodycal_dev.retarget_fixtures import one_frame_atol, procedural_avatar

REFERENCE = pathlib.Path(__file__).parent / "data" / "bake_before_prepared_solver.npz"


@pytest.fixture(scope="module")
def take():
    perf = synthetic.make_performer(seed=0)
    rec, truth = synthetic.record_session(perf, motions=("clap", "hand_on_belly"), calibration=False, seed=3,
                                          motion_seconds=1.0, dropout_rate=0.03)
    return rec, truth.body_model(), procedural_avatar()


def _blocks(solver, start, stop, size):
    parts = [solver.solve(a, min(stop, a + size)) for a in range(start, stop, size)]
    names = set().union(*(p.targets for p in parts))
    targets = {n: np.concatenate([p.targets.get(n, np.full((len(p.basis), 3), np.nan)) for p in parts])
               for n in names}
    return (np.concatenate([p.basis for p in parts]), np.concatenate([p.root_location for p in parts]),
            np.concatenate([p.joints for p in parts]), targets)


@pytest.mark.parametrize("method", pl.METHODS)
@pytest.mark.parametrize("plant", [False, True])
@pytest.mark.parametrize("path", ["numpy", "mathutils"])
def test_one_frame_at_a_time_is_the_chunk_s_solve(take, method, plant, path, monkeypatch):
    # The live loop's and a scrubbed preview's one-frame solve is the bake's, frame for frame
    # (planting: the plan found over the whole take, as a bake has it): numpy's one-frame path
    # within 1e-9, mathutils' (float32) within retarget_fixtures.ONE_FRAME_ATOL.
    monkeypatch.setattr(one_frame, "ENABLED", path == "mathutils")
    rec, user, avatar = take
    solver = PreparedSolver(RecordingSource(rec, user), avatar, method, plant_feet=plant)
    lo, hi = 150, 190
    whole = _blocks(solver, lo, hi, hi - lo)
    for size in (1, 3, 11):  # one frame; a few (one stacked product per 3x3); longer (one per stack)
        got = _blocks(solver, lo, hi, size)
        # a block of one frame (size 1, and the last of the blocks of 3) is solved in mathutils
        one = path == "mathutils" and 1 in {min(size, hi - a) for a in range(lo, hi, size)}
        for a, b, kind in zip(whole[:3], got[:3], ("basis", "root", "joints")):
            np.testing.assert_allclose(b, a, rtol=0, atol=one_frame_atol(kind) if one else 1e-9)
        assert set(got[3]) == set(whole[3])
        for n in whole[3]:
            np.testing.assert_allclose(got[3][n], whole[3][n], rtol=0, atol=one_frame_atol(n) if one else 1e-9,
                                       err_msg=n)


def test_the_bake_is_the_one_before_the_prepared_solver():
    # A 20-frame window baked (chunks of 7) by the code before the prepared solver (commit
    # af591eb), each method with its defaults: the same pose-bone values.
    ref = np.load(REFERENCE)
    perf_rec, truth = synthetic.record_session(synthetic.make_performer(seed=0), motions=("clap",),
                                               calibration=False, seed=0, motion_seconds=0.2)
    rec = Recording("window", ref["time"], perf_rec.devices, ref["positions"], ref["rotations"], ref["valid"],
                    list(perf_rec.marker_names), ref["markers"], ref["marker_valid"])
    user = synthetic.record_session(synthetic.make_performer(seed=0), motions=("clap",), calibration=False,
                                    seed=0, motion_seconds=0.2)[1].body_model()
    # The feet changed on purpose since (feet.py: rolling about the heel's and the ball's contact
    # points; the foot turned by the performer's since the reference pose, avatar_pose.DELTA_COPY):
    # the legs are not compared, and the methods whose other bones answer to where the feet stand
    # (AvatarGo's pelvis where a planted foot is out of reach, the egocentric soles on the surface)
    # are pinned since by test_solver_speedup_pin.py, written after the feet changed. The rotation
    # copy's other bones and its root owe nothing to the feet: still exact.
    legs = ("thigh_", "calf_", "foot_", "ball_")
    anim = pl.retarget(rec, user, procedural_avatar(), "rotations", chunk_frames=7)
    keep = [i for i, n in enumerate(anim.bone_names) if not n.startswith(legs)]
    np.testing.assert_allclose(anim.rotations[:, keep], ref["rotations_basis"][:, keep], rtol=0, atol=1e-9)
    np.testing.assert_allclose(anim.root_location, ref["rotations_root"], rtol=0, atol=1e-9)


def test_solve_refuses_frames_outside_the_take(take):
    rec, user, avatar = take
    solver = PreparedSolver(RecordingSource(rec, user), avatar, "rotations", plant_feet=False)
    with pytest.raises(BodyCalError, match="not within the take"):
        solver.solve(rec.frame_count - 1, rec.frame_count + 1)
    with pytest.raises(BodyCalError, match="stance"):
        PreparedSolver(RecordingSource(rec, user), avatar, "rotations", stance="lookahead")


@pytest.mark.parametrize("method", pl.METHODS)
def test_a_streamed_take_is_the_bake_of_it(take, method):
    # Frames pushed one at a time as a live source gives them (every device tracked, no filter,
    # no planting): the offline bake of the same frames. (Where a device is lost the two differ by
    # design: the bake sees the gap's far end and bridges it, the stream cannot; test below.)
    rec, user, avatar = take
    n = 60
    rec = replace(rec.window(0, n), valid=np.ones((n, len(rec.devices)), bool))
    want = pl.retarget(rec, user, avatar, method, plant_feet=False)
    live = LiveSolver(user, avatar, method, devices=rec.devices, marker_names=rec.marker_names, plant_feet=False)
    got = [live.push(rec.time[f], rec.positions[f], rec.rotations[f], rec.valid[f], rec.markers[f],
                     rec.marker_valid[f]) for f in range(n)]
    assert live.first_solved == 0
    # one frame in mathutils: float32 (retarget_fixtures.ONE_FRAME_ATOL)
    np.testing.assert_allclose(np.concatenate([g.basis for g in got]), want.rotations, rtol=0,
                               atol=one_frame_atol("basis"))
    joints = np.stack([want.joints_world[j] for j in JOINTS], axis=1)
    np.testing.assert_allclose(np.concatenate([g.joints for g in got]), joints, rtol=0, atol=one_frame_atol("joints"))


def test_a_stream_rides_a_lost_device_where_the_bake_bridges_it(take):
    # A hand lost for 10 frames: before and after the gap stream and bake agree; inside it the
    # bake bridges (it sees the far end), the stream holds the hand (no carrier) and differs.
    rec, user, avatar = take
    n = 60
    valid = np.ones((n, len(rec.devices)), bool)
    hand = [d.role for d in rec.devices].index("hand_l")
    valid[30:40, hand] = False
    rec = replace(rec.window(0, n), valid=valid)
    want = pl.retarget(rec, user, avatar, "rotations", plant_feet=False)
    live = LiveSolver(user, avatar, "rotations", devices=rec.devices, marker_names=rec.marker_names, plant_feet=False)
    got = np.concatenate([live.push(rec.time[f], rec.positions[f], rec.rotations[f], rec.valid[f], rec.markers[f],
                                    rec.marker_valid[f]).joints for f in range(n)])
    wrist = JOINTS.index("wrist_l")
    atol = one_frame_atol("joints")  # one frame in mathutils: float32
    np.testing.assert_allclose(got[:30, wrist], want.joints_world["wrist_l"][:30], rtol=0, atol=atol)
    np.testing.assert_allclose(got[40:, wrist], want.joints_world["wrist_l"][40:], rtol=0, atol=atol)
    assert np.abs(got[30:40, wrist] - want.joints_world["wrist_l"][30:40]).max() > 1e-3


def test_a_stream_is_solved_once_every_needed_device_is_tracked(take):
    rec, user, avatar = take
    valid = rec.valid.copy()
    valid[:5, [d.role for d in rec.devices].index("foot_l")] = False
    live = LiveSolver(user, avatar, "rotations", devices=rec.devices, marker_names=rec.marker_names)
    out = [live.push(rec.time[f], rec.positions[f], rec.rotations[f], valid[f], rec.markers[f], rec.marker_valid[f])
           for f in range(8)]
    assert out[:5] == [None] * 5 and all(o is not None for o in out[5:]) and live.first_solved == 5
    assert out[5].basis.shape == (1, len(live.solver.bone_names), 4)


def test_the_forward_one_euro_in_blocks_is_the_whole_take_s():
    rng = np.random.default_rng(1)
    t = np.cumsum(rng.uniform(0.009, 0.013, 300))
    pos = np.cumsum(rng.normal(0, 0.01, (300, 2, 3)), axis=0)
    q = rng.normal(size=(300, 2, 4)) * 0.05 + np.array([1.0, 0, 0, 0])
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    q[::7] *= -1  # hemisphere flips a stream must align as the whole take does
    cfg = OneEuro(two_pass=False)
    want_p = filters.smooth_positions(t, pos, cfg.min_cutoff, cfg.beta, cfg.d_cutoff, two_pass=False)
    want_q = filters.smooth_rotations(t, q, cfg.rot_min_cutoff, cfg.rot_beta, cfg.d_cutoff, two_pass=False)
    cuts = [0, 1, 2, 40, 41, 150, 300]
    sp, sq = OneEuroStream(cfg), OneEuroStream(cfg, rotations=True)
    got_p = np.concatenate([sp(t[a:b], pos[a:b]) for a, b in zip(cuts, cuts[1:])])
    got_q = np.concatenate([sq(t[a:b], q[a:b]) for a, b in zip(cuts, cuts[1:])])
    np.testing.assert_allclose(got_p, want_p, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got_q, want_q, rtol=0, atol=1e-12)


def test_a_live_recording_filters_forward_and_holds_untracked_devices(take):
    rec, _, _ = take
    n = 50
    cfg = OneEuro(two_pass=False, anchored=False)  # the stream filters in the room (DESIGN.md §6b)
    live = LiveRecording(rec.devices, rec.marker_names, smooth=cfg)
    for f in range(n):
        live.append(rec.time[f], rec.positions[f], rec.rotations[f], rec.valid[f], rec.markers[f], rec.marker_valid[f])
    want = filters.filter_recording(rec.window(0, n), cfg)
    np.testing.assert_allclose(live.positions, want.positions, rtol=0, atol=1e-12)
    np.testing.assert_allclose(live.rotations, want.rotations, rtol=0, atol=1e-12)
    np.testing.assert_allclose(live.markers, want.markers, rtol=0, atol=1e-12)
    with pytest.raises(BodyCalError, match="only be filtered forward"):
        LiveRecording(rec.devices, smooth=OneEuro())
    raw = LiveRecording(rec.devices)
    bad = rec.positions[0].copy()
    bad[0] = np.nan
    raw.append(0.0, rec.positions[0], rec.rotations[0], np.ones(len(rec.devices), bool))
    raw.append(0.01, bad, rec.rotations[0], np.r_[False, np.ones(len(rec.devices) - 1, bool)])
    np.testing.assert_array_equal(raw.positions[1, 0], rec.positions[0, 0])  # held
    with pytest.raises(BodyCalError, match="strictly increasing"):
        raw.append(0.01, rec.positions[0], rec.rotations[0], np.ones(len(rec.devices), bool))


def _walk(n=400, fps=90.0):
    """An ankle that stands, steps 40 cm, stands, steps again, stands (as test_feet's)."""
    t = np.arange(n) / fps
    x = np.interp(t, [0, 1.0, 1.5, 2.5, 3.0, 10], [0, 0, 0.4, 0.4, 0.8, 0.8])
    z = 0.09 + 0.08 * np.clip(np.sin(np.pi * np.clip((t - 1.0) / 0.5, 0, 1)), 0, None) \
        + 0.08 * np.clip(np.sin(np.pi * np.clip((t - 2.5) / 0.5, 0, 1)), 0, None)
    ankle = np.stack([x, np.zeros(n), z], axis=1) + np.random.default_rng(0).normal(0, 0.0005, (n, 3))
    return t, ankle


def test_causal_stance_looks_at_no_later_frame_and_any_split_is_the_same():
    t, ankle = _walk()
    whole = feet.CausalStance(0.09, 90.0).update(ankle, t, ankle)
    one = feet.CausalStance(0.09, 90.0)
    parts = [one.update(ankle[f:f + 1], t[f:f + 1], ankle[f:f + 1]) for f in range(len(t))]
    np.testing.assert_array_equal(np.concatenate([p[0] for p in parts]), whole[0])
    np.testing.assert_array_equal(np.concatenate([p[1] for p in parts]), whole[1])
    later = ankle.copy()
    later[200:] += 0.3  # another future
    other = feet.CausalStance(0.09, 90.0).update(later, t, later)
    np.testing.assert_array_equal(other[0][:200], whole[0][:200])


def test_causal_stance_plants_the_bake_s_stances_a_little_later():
    t, ankle = _walk()
    offline = feet.detect(ankle, t, 0.09)
    weight, planted = feet.CausalStance(0.09, 90.0).update(ankle, t, ankle)
    assert np.all(offline.weight[weight >= 1] > 0)  # no stance the bake does not have
    # Each of the two later stances (the first starts with the take) is planted from MIN_STANCE_S
    # after the bake's stance starts, fully within BLEND_S more, at the place the foot stood.
    for start_s, place in ((1.5, 0.4), (3.0, 0.8)):
        on = t[np.argmax((t > start_s) & (weight > 0))]
        full = t[np.argmax((t > start_s) & (weight >= 1))]
        bake = t[np.argmax((t > start_s) & (offline.weight >= 1))]
        assert bake + feet.MIN_STANCE_S - 0.03 <= on <= bake + feet.MIN_STANCE_S + 0.03
        assert full <= on + feet.BLEND_S + 0.02
        np.testing.assert_allclose(planted[(t > full) & (t < full + 0.3), 0], place, atol=2e-3)
    assert np.abs(np.diff(weight)).max() < 0.2  # eased in and out, never switched


@pytest.mark.parametrize("method", ["egocentric", "offsets"])
def test_causal_planting_frame_by_frame_is_the_causal_plan_of_the_whole_take(take, method):
    rec, user, avatar = take
    lo, hi = 0, 40
    a = PreparedSolver(RecordingSource(rec, user), avatar, method, stance="causal")
    b = PreparedSolver(RecordingSource(rec, user), avatar, method, stance="causal")
    whole = _blocks(a, lo, hi, hi - lo)
    frames = _blocks(b, lo, hi, 1)
    for x, y, kind in zip(whole[:3], frames[:3], ("basis", "root", "joints")):
        np.testing.assert_allclose(y, x, rtol=0, atol=one_frame_atol(kind))  # one frame in mathutils: float32
    np.testing.assert_array_equal(a.feet.weight["l"], b.feet.weight["l"])
    assert all(st.drift is None for st in a.feet.stance.values())  # tracked feet: no drift cut (an estimated one's)
