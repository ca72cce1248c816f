"""One path for every pose source (retarget/takes.py, retarget/methods.py): a take of either kind
animates an avatar exactly as the pipeline's own entry for that kind does, the method registry is
the one the pipeline runs, and each kind takes only the methods that can use it."""

from __future__ import annotations

import numpy as np
import pytest

from bodycal_addon.core.errors import BodyCalError
from bodycal_addon.recording.filters import OneEuro
from bodycal_addon.retarget import methods
from bodycal_addon.retarget import pipeline as pl
from bodycal_addon.retarget.avatar_pose import AvatarRig
from bodycal_addon.retarget.takes import CharacterTake, RecordingTake
from bodycal_addon.retarget.transfer import transfer
from bodycal_dev import retarget_fixtures as rt
from bodycal_dev import synthetic


@pytest.fixture(scope="module")
def recorded():
    perf = synthetic.make_performer(seed=3)
    rec, truth = synthetic.record_session(perf, motions=("hand_on_belly",), calibration=False, motion_seconds=0.5,
                                          noise_mm=0.5, wobble_mm=0.0)
    return rec, truth.body_model()


def test_the_registry_is_the_pipelines_methods():
    assert set(methods.METHOD_INFO) == set(pl.METHOD_CLASSES)
    assert pl.METHODS == tuple(m.name for m in methods.REGISTRY) and pl.METHODS[0] == "egocentric"
    assert methods.methods_for("animation") == ("egocentric", "rotations")  # offsets need trackers
    assert all(set(m.sources) <= set(methods.SOURCE_KINDS) for m in methods.REGISTRY)


def test_a_kind_refuses_a_method_it_cannot_use_in_one_line():
    assert methods.check_method("offsets", "recording") == "offsets"
    with pytest.raises(BodyCalError, match="unknown transfer method 'offsets'.*use one of egocentric, rotations"):
        methods.check_method("offsets", "animation")
    with pytest.raises(BodyCalError, match="unknown method 'ik'"):
        methods.check_method("ik", "recording")


@pytest.mark.parametrize("method", pl.METHODS)
def test_a_recording_take_animates_as_the_pipeline_does(recorded, method):
    rec, user = recorded
    avatar = rt.procedural_avatar(matrix_world=rt.rigid_matrix_world(20.0, 1.1))
    take = RecordingTake(rec, user, filter=None)
    assert take.name == rec.name and take.rate == pytest.approx(rec.fps)
    got = take.animate(avatar, method, placement="performer")
    want = pl.retarget(rec, user, avatar, method, placement="performer")
    # Two runs of the same numpy code may differ in the last bit (sums vectorised differently with
    # the arrays' alignment, seen at 3e-17): the same animation, not a bit-identical one.
    np.testing.assert_allclose(got.rotations, want.rotations, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got.root_location, want.root_location, rtol=0, atol=1e-12)
    assert got.notes == want.notes


def test_a_filtered_take_smooths_a_copy(recorded):
    rec, user = recorded
    before = rec.positions.copy()
    avatar = rt.procedural_avatar()
    plain = RecordingTake(rec, user, filter=None).animate(avatar, "rotations")
    smooth = RecordingTake(rec, user).animate(avatar, "rotations")  # smoothed by default (DEFAULT_FILTER)
    assert RecordingTake(rec, user).filter == OneEuro()
    np.testing.assert_array_equal(rec.positions, before)
    dot = np.clip(np.abs(np.sum(smooth.rotations * plain.rotations, axis=-1)), 0.0, 1.0)
    turn_deg = np.degrees(2 * np.arccos(dot))
    assert turn_deg.max() > 1e-2 and np.median(turn_deg) < 2.0  # smoothed, not another motion


def test_a_character_take_animates_as_the_transfer_does(recorded):
    rec, user = recorded
    source = rt.procedural_avatar()
    performed = pl.retarget(rec, user, source, "rotations", plant_feet=False)
    rig = AvatarRig.from_model(source)
    locations = np.zeros((performed.frame_count, len(rig.names), 3))
    locations[:, rig.root] = performed.root_location
    take = CharacterTake(source, performed.rotations, locations, performed.time, rec.fps, "clip", "src")
    assert take.name == "clip" and take.kind == "animation" and not take.estimated
    target = rt.procedural_avatar(matrix_world=rt.rigid_matrix_world(-40.0, 0.9))
    got = take.animate(target, "egocentric")
    want = transfer(source, performed.rotations, locations, performed.time, target, "egocentric", name="src")
    np.testing.assert_allclose(got.rotations, want.rotations, rtol=0, atol=1e-12)
    take.release()
    assert take.basis is None and take.locations is None


def test_a_window_keeps_the_frames_its_samples_play_at(recorded):
    """A take imported at frame 101 and limited to frames 110-120: its samples are those at those
    frames (jittered timestamps included: the frames are the import's mean-rate mapping), at the
    take's rate, starting at the first of them; a character take keeps its action's frames; a
    range past the take is one error."""
    rec, user = recorded
    rec = rec.window(0, rec.frame_count)
    rng = np.random.default_rng(2)
    rec.time = rec.time + np.r_[0.0, rng.uniform(-0.3, 0.3, rec.frame_count - 2) / rec.fps, 0.0]
    take = RecordingTake(rec, user, frame_start=101.0)
    frames = 101.0 + (rec.time - rec.time[0]) * take.rate
    part = take.window(110, 120)
    inside = (frames >= 110 - 1e-3) & (frames <= 120 + 1e-3)
    np.testing.assert_array_equal(part.recording.time, rec.time[inside])
    np.testing.assert_array_equal(part.recording.positions, rec.positions[inside])
    assert part.rate == take.rate != pytest.approx(part.recording.fps, rel=1e-9)
    assert part.frame_start == frames[inside][0] and part.name == take.name
    with pytest.raises(BodyCalError, match=r"frame range 1e\+06-2e\+06 holds none of the take.s frames \(101-"):
        take.window(1e6, 2e6)

    source = rt.procedural_avatar()
    n = 30
    char = CharacterTake(source, np.tile([1.0, 0, 0, 0], (n, 5, 1)), np.zeros((n, 5, 3)), np.arange(n) / 30.0,
                         30.0, "clip", "src", frame_start=21.0)
    part = char.window(1, 30)
    assert part.frame_start == 21.0 and len(part.time) == 10 and part.basis.shape[0] == 10
