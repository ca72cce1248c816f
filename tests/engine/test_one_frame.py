"""One frame's kernels in Blender's mathutils (bodycal_addon/core/one_frame.py, DESIGN.md "Prepared
solver"): PyPI's build imports in the engine lane, it is single precision as Blender's is, and each
one-frame kernel gives its numpy path's values to float32's rounding, on a plain and on a turned and
scaled armature (the rig's W not the identity)."""

from __future__ import annotations

import numpy as np
import pytest

from bodycal_addon.body.rest_frames import model_rest_frames
from bodycal_addon.body.skeleton import JOINT_INDEX as JI
from bodycal_addon.core import one_frame
from bodycal_addon.retarget import avatar_pose as ap
from bodycal_addon.retarget import offsets as ofs
from bodycal_addon.retarget import user_animation as ua
from bodycal_addon.retarget.pose_source import RecordingSource
from bodycal_addon.retarget.solver import PreparedSolver
from bodycal_dev import retarget_fixtures as rt
from bodycal_dev import synthetic


def test_mathutils_is_there_and_single_precision():
    assert one_frame.ENABLED and one_frame.mathutils is not None
    assert one_frame.Vector((0.1, 0.0, 0.0))[0] == float(np.float32(0.1)) != 0.1


@pytest.fixture(scope="module")
def take():
    perf = synthetic.make_performer(seed=2)
    rec, truth = synthetic.record_session(perf, motions=("clap", "hand_on_head"), calibration=False,
                                          motion_seconds=1.0)
    return rec, truth.body_model()


def test_one_frame_s_chain_aim_is_numpy_s(take, monkeypatch):
    # The spine chain aimed bone by bone in mathutils (rig_one_frame.ChainOneFrame), the rest of
    # the pose in numpy: the numpy path's pose to float32's rounding (measured at most 2e-7).
    rec, user = take
    up = ua.animate_user(rec, user)
    for avatar in rt.plain_and_turned_avatars():
        rigs = {on: ap.AvatarRig.from_model(avatar) for on in (False, True)}
        frames = ap.copy_frames(up.frames, model_rest_frames(user), rigs[True].frames0)
        pelvis = up.joints[:, JI["pelvis"]] * 1.1
        for f in range(0, len(frames), 9):
            poses = {}
            for on, rig in rigs.items():
                monkeypatch.setattr(one_frame, "ENABLED", on)
                rig.memo.clear()
                poses[on] = rig.solve(frames[f:f + 1], pelvis[f:f + 1])
            for name, atol in (("basis", 1e-6), ("joints", 1e-6), ("frames", 1e-6), ("root_location", 1e-6)):
                np.testing.assert_allclose(getattr(poses[True], name), getattr(poses[False], name), rtol=0,
                                           atol=atol, err_msg=name)


def test_offsets_one_frame_kernels_are_numpy_s(take, monkeypatch):
    # AvatarGo's effector targets and spine frames of one frame in mathutils: numpy's values to
    # float32's rounding (measured at most 1.6e-7), over every frame of a take.
    rec, user = take
    solver = PreparedSolver(RecordingSource(rec, user), rt.procedural_avatar(), "offsets", plant_feet=False)
    st = solver.impl.ofs
    tr = solver.src.trackers(0, rec.frame_count)
    for f in range(0, rec.frame_count, 5):
        pos = {k: v[f:f + 1] for k, v in tr.pos.items()}
        rot = {k: v[f:f + 1] for k, v in tr.rot.items()}
        sacrum = solver.src.pose(f, f + 1, rest=(solver.user_pos, solver.user_frames0)).frames[:, 0]
        got = {}
        for on in (False, True):
            monkeypatch.setattr(one_frame, "ENABLED", on)
            got[on] = ofs.effector_targets(st, pos, rot), ofs.spine_frames(st, pos, sacrum)
        (p0, r0), s0 = got[False]
        (p1, r1), s1 = got[True]
        assert set(p0) == set(p1) and set(r0) == set(r1)
        for k in p0:
            np.testing.assert_allclose(p1[k], p0[k], rtol=0, atol=1e-6, err_msg=k)
        for k in r0:
            np.testing.assert_allclose(r1[k], r0[k], rtol=0, atol=1e-6, err_msg=k)
        np.testing.assert_allclose(s1, s0, rtol=0, atol=1e-6)
