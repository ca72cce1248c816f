"""What the rotation copy does not read of the user (issue 41; DESIGN.md "Prepared solver"): it
copies the user's bone frames, the fingers' phalanges among them, and its joints are the avatar's
forward kinematics, so the pose source poses the fingers' frames from their tip markers but not
their joints (`Method.user_finger_joints`). The same solve to the bit, one frame or a block,
mathutils or numpy, planted or not."""

from __future__ import annotations

import numpy as np
import pytest

from bodycal_addon.body.skeleton import JOINT_INDEX as JI
from bodycal_addon.core import one_frame
from bodycal_addon.retarget.pose_source import RecordingSource
from bodycal_addon.retarget.solver import PreparedSolver
from bodycal_dev import synthetic
from bodycal_dev.retarget_fixtures import procedural_avatar


@pytest.fixture(scope="module")
def take():
    rec, truth = synthetic.record_session(synthetic.make_performer(seed=4), motions=("clap", "hand_on_head"),
                                          calibration=False, seed=4, motion_seconds=1.0)
    return rec, truth.body_model()


@pytest.mark.parametrize("plant", [True, False])
@pytest.mark.parametrize("path", ["mathutils", "numpy"])
def test_rotations_skips_the_finger_joints_and_solves_the_same(take, monkeypatch, path, plant):
    monkeypatch.setattr(one_frame, "ENABLED", path == "mathutils" and one_frame.ENABLED)
    rec, user = take
    skipping = PreparedSolver(RecordingSource(rec, user), procedural_avatar(), "rotations", plant_feet=plant)
    posing = PreparedSolver(RecordingSource(rec, user), procedural_avatar(), "rotations", plant_feet=plant)
    assert skipping.impl.user_finger_joints is False and all(skipping.has_fingers.values())
    posing.impl.user_finger_joints = True  # this instance reads them as every other method does
    for a, b in [(f, f + 1) for f in range(5, rec.frame_count, 23)] + [(40, 52)]:
        got, want = skipping.solve(a, b), posing.solve(a, b)
        for field in ("basis", "root_location", "joints"):
            assert getattr(got, field).tobytes() == getattr(want, field).tobytes(), (a, b, field)
        assert got.targets.keys() == want.targets.keys()
        for n in got.targets:
            assert got.targets[n].tobytes() == want.targets[n].tobytes(), (a, b, n)


@pytest.mark.parametrize("frames", [(30, 31), (30, 42)])
def test_the_fingers_frames_are_posed_and_their_joints_left_as_calibrated(take, frames):
    """Skipped, the joints after each MCP are the hand's rigid ones; every frame is the posed one's."""
    rec, user = take
    solver = PreparedSolver(RecordingSource(rec, user), procedural_avatar(), "rotations", plant_feet=False)
    rest = (solver.user_pos, solver.user_frames0)
    posed = solver.src.pose(*frames, rest)
    frames_only = solver.src.pose(*frames, rest, finger_joints=False)
    rigid = solver.src.pose(*frames, rest, fingers=False)
    tips = [JI[f"tip_{f}_{s}"] for s in "lr" for f in ("index", "thumb")]
    assert frames_only.frames.tobytes() == posed.frames.tobytes()
    assert frames_only.joints[:, tips].tobytes() == rigid.joints[:, tips].tobytes()
    assert np.abs(posed.joints[:, tips] - rigid.joints[:, tips]).max() > 1e-3  # the markers move them
    finger_joints = [j for n, j in JI.items() if n.split("_")[1:2] in (["thumb"], ["index"], ["middle"], ["ring"],
                                                                      ["pinky"])]
    others = np.setdiff1d(np.arange(posed.joints.shape[1]), finger_joints)
    assert len(finger_joints) == 40 and len(others)
    assert frames_only.joints[:, others].tobytes() == posed.joints[:, others].tobytes()
