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


def test_mathutils_is_there_and_single_precision():
    assert one_frame.ENABLED and one_frame.mathutils is not None
    assert one_frame.Vector((0.1, 0.0, 0.0))[0] == float(np.float32(0.1)) != 0.1


@pytest.fixture(scope="module")
def take():
    return rt.synthetic_take(seed=2)


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


def test_one_frame_s_joints_in_the_chain_s_pass_are_numpy_s_and_leave_the_pose_the_same(take, monkeypatch):
    # A frame's few joints (the IK's limb roots) placed in the spine chain's own mathutils pass
    # (rig_one_frame.ChainOneFrame.aimed_and_joints): the numpy pose's joints to float32's rounding
    # (joints at a carrier's head and off it, a rig whose armature is not the world's); the pose
    # solved after them the numpy path's as well, and the same whether or not the joints came first.
    rec, user = take
    up = ua.animate_user(rec, user)
    lists = (("shoulder_l", "shoulder_r", "hip_l", "hip_r"), ("hip_l",), ("skull_base", "spine_06", "wrist_r"))
    for avatar in rt.plain_and_turned_avatars():
        rigs = {on: ap.AvatarRig.from_model(avatar) for on in (False, True)}
        frames = ap.copy_frames(up.frames, model_rest_frames(user), rigs[True].frames0)
        pelvis = up.joints[:, JI["pelvis"]] * 1.1
        for f in range(0, len(frames), 9):
            for joints in lists:
                got, poses = {}, {}
                for on, rig in rigs.items():
                    monkeypatch.setattr(one_frame, "ENABLED", on)
                    rig.memo.clear()
                    got[on] = rig.joint_positions(frames[f:f + 1], pelvis[f:f + 1], list(joints))
                    poses[on] = rig.solve(frames[f:f + 1], pelvis[f:f + 1])
                np.testing.assert_allclose(got[True], got[False], rtol=0, atol=1e-6, err_msg=str(joints))
                np.testing.assert_allclose(poses[True].joints, poses[False].joints, rtol=0, atol=1e-6)
                rigs[True].memo.clear()
                alone = rigs[True].solve(frames[f:f + 1], pelvis[f:f + 1])
                np.testing.assert_array_equal(alone.basis, poses[True].basis)
                np.testing.assert_array_equal(alone.joints, poses[True].joints)


def test_offsets_one_frame_kernels_are_numpy_s(take, monkeypatch):
    # AvatarGo's effector targets and spine frames of one frame (a few stacked numpy products and
    # Python floats, float64): numpy's values to their sums' rounding (measured at most 4.4e-16;
    # the mathutils kernels they replaced held float32's 1.6e-7), over every frame of a take.
    rec, user = take
    solver = PreparedSolver(RecordingSource(rec, user), rt.procedural_avatar(), "offsets", plant_feet=False)
    st = solver.impl.ofs
    for f in range(0, rec.frame_count, 5):
        tr = solver.src.trackers(f, f + 1)
        sacrum = solver.src.pose(f, f + 1, rest=(solver.user_pos, solver.user_frames0)).frames[:, 0]
        got = {}
        for on in (False, True):
            monkeypatch.setattr(one_frame, "ENABLED", on)
            got[on] = ofs.effector_targets(st, tr), ofs.spine_frames(st, tr.pos, sacrum)
        (p0, r0), s0 = got[False]
        (p1, r1), s1 = got[True]
        assert set(p0) == set(p1) and set(r0) == set(r1)
        for k in p0:
            np.testing.assert_allclose(p1[k], p0[k], rtol=0, atol=1e-12, err_msg=k)
        for k in r0:
            np.testing.assert_allclose(r1[k], r0[k], rtol=0, atol=1e-12, err_msg=k)
        np.testing.assert_allclose(s1, s0, rtol=0, atol=1e-12)


@pytest.mark.parametrize("bend", ["none", "parallel", "opposite", "no_length"])
def test_offsets_one_frame_spine_takes_the_bakes_turn_where_it_is_no_turn_or_a_half_turn(take, monkeypatch, bend):
    # The pelvis-to-head vector along w0 (no bend), along it within rounding, against it (the
    # bake's quat_between: a half turn about a perpendicular) or of no length: one frame's spine
    # is the bake's there too.
    rec, user = take
    solver = PreparedSolver(RecordingSource(rec, user), rt.procedural_avatar(), "offsets", plant_feet=False)
    st = solver.impl.ofs
    sacrum = solver.src.pose(3, 4, rest=(solver.user_pos, solver.user_frames0)).frames[:, 0]
    w0 = (sacrum[0] @ st.r0_joint["sacrum"].T) @ st.w0
    w = {"none": w0, "parallel": w0 * 0.7 + 1e-15, "opposite": -w0, "no_length": 0.0 * w0}[bend]
    pos = {"pelvis": np.array([[0.1, 0.2, 0.9]])}
    pos["head"] = pos["pelvis"] + w
    got = {}
    for on in (False, True):
        monkeypatch.setattr(one_frame, "ENABLED", on)
        got[on] = ofs.spine_frames(st, pos, sacrum)
    np.testing.assert_allclose(got[True], got[False], rtol=0, atol=1e-12)
    if bend == "opposite":  # a half turn: the top vertebra's frame is not the sacrum's turn alone
        assert np.abs(got[True][0, -1] - (sacrum[0] @ st.r0_joint["sacrum"].T) @ st.spine0[-1]).max() > 0.5
