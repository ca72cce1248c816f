"""The offsets method closes the avatar's fingers on the controller (AvatarGo, `offsets.grip_fingers`):
where the grip sets every finger bone of each hand that has any, nothing reads the user's fingers,
so the pose source leaves them unposed (`Method.user_fingers`, issue 41; DESIGN.md "Prepared
solver"): the same solve to the bit, one frame or a block, mathutils or numpy, without the
fingertip markers' pose. A hand the grip does not close (an avatar with some finger bones but not
all) still gets the user's fingers."""

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
    calls = {"fingers": 0}
    original = ua.pose_user_fingers

    def counted(*a, **k):
        calls["fingers"] += 1
        return original(*a, **k)

    monkeypatch.setattr(ua, "pose_user_fingers", counted)
    return calls


@pytest.mark.parametrize("path", ["mathutils", "numpy"])
def test_offsets_skips_the_users_fingers_and_solves_the_same(take, monkeypatch, path):
    monkeypatch.setattr(one_frame, "ENABLED", path == "mathutils" and one_frame.ENABLED)
    rec, user = take
    calls = _counting(monkeypatch)
    solver = PreparedSolver(RecordingSource(rec, user), procedural_avatar(), "offsets", plant_feet=True)
    assert solver.impl.user_fingers is False and all(solver.has_fingers.values())
    blocks = [(f, f + 1) for f in range(5, rec.frame_count, 23)] + [(40, 52)]
    skipped = [solver.solve(a, b) for a, b in blocks]
    assert calls["fingers"] == 0 and ua.UserAnimator(rec, user).plan.tips  # markers there, not posed
    solver.impl.user_fingers = True  # the user's fingers posed, as before
    posed = [solver.solve(a, b) for a, b in blocks]
    assert calls["fingers"] == len(blocks)
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
