"""AvatarRig's posing (DESIGN.md "Prepared solver"): a pose of a few frames (fewer than
avatar_pose.FEW_FRAMES: the heads the spine chain does not read placed in one padded pass, a
one-frame chain aimed in Python floats) is the level-by-level pose of the same frames, to the bit."""

from __future__ import annotations

import numpy as np

from bodycal_addon.body.rest_frames import model_rest_frames
from bodycal_addon.body.skeleton import JOINT_INDEX as JI
from bodycal_addon.retarget import avatar_pose as ap
from bodycal_addon.retarget import user_animation as ua
from bodycal_dev import retarget_fixtures as rt
from bodycal_dev import synthetic


def test_a_few_frames_pose_as_level_by_level_bit_for_bit(monkeypatch):
    perf = synthetic.make_performer(seed=2)
    rec, truth = synthetic.record_session(perf, motions=("clap", "hand_on_head"), calibration=False,
                                          motion_seconds=1.0)
    user = truth.body_model()
    up = ua.animate_user(rec, user)
    for avatar in (rt.procedural_avatar(), rt.procedural_avatar(matrix_world=rt.rigid_matrix_world(30.0, 1.2),
                                                                arm_drop_deg=30.0)):
        rig = ap.AvatarRig.from_model(avatar)
        assert rig._pose_plan(None).deferred is not None  # the padded pass is taken
        frames = ap.copy_frames(up.frames, model_rest_frames(user), rig.frames0)
        pelvis = up.joints[:, JI["pelvis"]] * 1.1
        for f in range(0, len(frames) - 3, 7):
            for n in (1, 3):
                poses = []
                for few in (ap.FEW_FRAMES, 0):  # the padded pass, then level by level
                    monkeypatch.setattr(ap, "FEW_FRAMES", few)
                    rig._chain_memo = None  # the chain aimed each time (not the last pose's, reused)
                    poses.append(rig.solve(frames[f:f + n], pelvis[f:f + n]))
                    if few:
                        # the one-frame chain's Python floats against numpy's turn
                        monkeypatch.setattr(ap, "turn_between_one", lambda a, b: None)
                monkeypatch.undo()
                for name in ("basis", "root_location", "joints", "frames"):
                    assert np.array_equal(getattr(poses[0], name), getattr(poses[1], name)), (name, f, n)
