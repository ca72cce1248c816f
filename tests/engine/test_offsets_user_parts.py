"""What the offsets method does not read of the user (issue 41; DESIGN.md "Prepared solver"): it
closes the avatar's fingers on the controller (AvatarGo, `offsets.grip_fingers`), so where the grip
sets every finger bone of each hand that has any, the pose source leaves the user's fingers unposed
(`Method.user_fingers`); it sets the pelvis, sacrum, vertebrae and clavicles from the trackers
(eq. 2-4), so the user's trunk pass is not run (`Method.user_trunk`). The same solve to the bit,
one frame or a block, mathutils or numpy, planted or not. A hand the grip does not close (an avatar
with some finger bones but not all) still gets the user's fingers."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from bodycal_addon.core import one_frame
from bodycal_addon.retarget import user_animation as ua
from bodycal_addon.retarget.pose_source import RecordingSource
from bodycal_addon.retarget.solver import PreparedSolver
from bodycal_dev import synthetic
from bodycal_dev.retarget_fixtures import procedural_avatar


@pytest.fixture(scope="module")
def take():
    rec, truth = synthetic.record_session(synthetic.make_performer(seed=4), motions=("clap", "hand_on_head"),
                                          calibration=False, seed=4, motion_seconds=1.0)
    return rec, truth.body_model()


def _counting(monkeypatch) -> dict:
    calls = {"fingers": 0, "trunk": 0}
    fingers, trunk = ua.pose_user_fingers, ua.UserAnimator._trunk

    def counted_fingers(*a, **k):
        calls["fingers"] += 1
        return fingers(*a, **k)

    def counted_trunk(*a, **k):
        calls["trunk"] += 1
        return trunk(*a, **k)

    monkeypatch.setattr(ua, "pose_user_fingers", counted_fingers)
    monkeypatch.setattr(ua.UserAnimator, "_trunk", counted_trunk)
    return calls


@pytest.mark.parametrize("plant", [True, False])
@pytest.mark.parametrize("path", ["mathutils", "numpy"])
@pytest.mark.parametrize("part", ["fingers", "trunk"])
def test_offsets_skips_what_it_does_not_read_and_solves_the_same(take, monkeypatch, path, part, plant):
    monkeypatch.setattr(one_frame, "ENABLED", path == "mathutils" and one_frame.ENABLED)
    rec, user = take
    calls = _counting(monkeypatch)
    solver = PreparedSolver(RecordingSource(rec, user), procedural_avatar(), "offsets", plant_feet=plant)
    assert solver.impl.user_fingers is False and solver.impl.user_trunk is False
    assert all(solver.has_fingers.values()) and ua.UserAnimator(rec, user).plan.tips  # markers there
    blocks = [(f, f + 1) for f in range(5, rec.frame_count, 23)] + [(40, 52)]
    skipped = [solver.solve(a, b) for a, b in blocks]
    assert calls == {"fingers": 0, "trunk": 0}
    setattr(solver.impl, f"user_{part}", True)  # that part of the user posed, as before
    posed = [solver.solve(a, b) for a, b in blocks]
    assert calls[part] == len(blocks)
    for s, p in zip(skipped, posed):
        for field in ("basis", "root_location", "joints"):
            assert np.array_equal(getattr(s, field), getattr(p, field)), field
        assert s.targets.keys() == p.targets.keys()
        for name in s.targets:
            assert np.array_equal(s.targets[name], p.targets[name]), name


def test_a_hand_the_grip_does_not_close_gets_the_users_fingers(take, monkeypatch):
    rec, user = take
    calls = _counting(monkeypatch)
    avatar = copy.deepcopy(procedural_avatar())
    del avatar.extra["rig"]["bone_map"]["bones"]["pinky_3_l"]  # the left hand: some finger bones, not all
    solver = PreparedSolver(RecordingSource(rec, user), avatar, "offsets", plant_feet=False)
    assert not solver.has_fingers["l"] and solver.finger_bones["l"] and solver.has_fingers["r"]
    assert solver.impl.user_fingers is True
    solver.solve(10, 11)
    assert calls["fingers"] == 1


@pytest.mark.parametrize("method", ["egocentric", "rotations"])
def test_the_other_methods_read_the_whole_user(take, monkeypatch, method):
    rec, user = take
    calls = _counting(monkeypatch)
    solver = PreparedSolver(RecordingSource(rec, user), procedural_avatar(), method, plant_feet=False)
    assert solver.impl.user_fingers and solver.impl.user_trunk
    solver.solve(10, 11)
    assert calls == {"fingers": 1, "trunk": 1}
