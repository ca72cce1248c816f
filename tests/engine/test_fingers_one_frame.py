"""A live frame's fingers in Python floats (`fingers.FingerSet.pose_floats`, issue 41), the user's
and the avatar's finger IK alike: the numpy passes' values (`distal_z` then `pose`, the
fingertip LED's offset aimed at the tip joint) to float64's rounding, thumbs rolled or not,
targets beyond every limit, joints or frames only; the user animation's one frame, which takes
it, gives the block's fingers; one egocentric frame's solve is the numpy passes'."""

import numpy as np
import pytest
from retarget_bodies import random_rotations

from bodycal_addon.body.skeleton import JOINT_INDEX as JI
from bodycal_addon.core import one_frame
from bodycal_addon.retarget import fingers as fg
from bodycal_addon.retarget import user_animation as ua
from bodycal_addon.retarget.pose_source import RecordingSource
from bodycal_addon.retarget.solver import PreparedSolver
from bodycal_dev import retarget_fixtures as rt
from bodycal_dev import synthetic


@pytest.mark.parametrize("roll", [fg.THUMB_ROLL, 0.0, None])
def test_floats_pose_a_few_fingers_as_the_numpy_passes_do(roll):
    rng = np.random.default_rng(11)
    worst = 0.0
    for _ in range(40):
        n = 10
        lens = rng.uniform(0.015, 0.05, (3, n))
        thumb = rng.random(n) < 0.3
        ref = random_rotations(rng, n)
        mcp = rng.normal(size=(n, 3)) * 0.1
        # close, mid and far targets: flexions capped and pitches beyond their limits too
        tip = mcp + rng.normal(size=(n, 3)) * rng.choice([0.002, 0.03, 0.08], size=(n, 1))
        fs = fg.FingerSet(*lens, thumb=thumb, roll=roll)
        radius = rng.uniform(0.0, 0.01, (n, 1))
        for rad in (None, radius):
            aim = tip if rad is None else tip + rad * fs.distal_z(mcp, ref, tip)
            want = fs.pose(mcp, ref, aim)
            joints, rotations = fs.pose_floats(mcp, ref, tip, radius=rad)
            worst = max(worst, np.abs(joints - want.joints).max(), np.abs(rotations - want.rotations).max())
            none, frames = fs.pose_floats(mcp, ref, tip, joints=False, radius=rad)
            assert none is None and frames.tobytes() == rotations.tobytes()
    assert worst < 1e-12, worst


def test_frames_from_local_targets_are_pose_floats_frames():
    # `frames_floats` (the avatar's one frame: targets taken into the reference frames by its
    # caller) is `pose_floats`' frames for the same local targets, to the bit; from a target formed
    # as the avatar's caller does (wrist, offset in the rest frame), float64's rounding
    rng = np.random.default_rng(5)
    n = 10
    fs = fg.FingerSet(*rng.uniform(0.015, 0.05, (3, n)), thumb=rng.random(n) < 0.3, roll=0.0)
    hands, rest = random_rotations(rng, n), random_rotations(rng, n)
    wrist, offset = rng.normal(size=(n, 3)) * 0.1, rng.normal(size=(n, 3)) * 0.03
    ref = hands @ rest
    mcp = wrist + np.einsum("fij,fj->fi", hands, offset)
    tip = mcp + rng.normal(size=(n, 3)) * rng.choice([0.002, 0.03, 0.08], size=(n, 1))
    want = fs.pose_floats(mcp, ref, tip, joints=False)[1]
    def frames(local):  # (item, phalanx, row, column) as pose_floats gives them
        return fs.frames_floats(ref, local).reshape(n, 3, 3, 3).transpose(0, 2, 1, 3)

    assert frames(np.einsum("fji,fj->fi", ref, tip - mcp)).tobytes() == want.tobytes()
    from_wrist = np.einsum("fji,fj->fi", ref, tip - wrist) - np.einsum("fji,fj->fi", rest, offset)
    assert np.abs(frames(from_wrist) - want).max() < 1e-12


def test_one_frame_s_user_fingers_are_the_block_s(monkeypatch):
    # the trunk's one-frame kernels (mathutils, float32) switched off: one frame's values are then
    # float64's throughout, and its fingers (posed from the floats) the whole take's numpy passes'
    monkeypatch.setattr(one_frame, "ENABLED", False)
    perf = synthetic.make_performer(seed=4)
    rec, truth = synthetic.record_session(perf, motions=("clap", "hand_on_head"), calibration=False,
                                          motion_seconds=0.5, seed=4)
    anim = ua.UserAnimator(rec, truth.body_model())
    assert anim.plan.tips  # fingertip markers: the one-frame pose takes the floats
    whole = anim.animate(0, rec.frame_count)
    names, bones = anim._tables["fingers"][:2]
    bones = np.array(bones).ravel()
    joints = np.array([JI[j] for n in names for j in n])
    calls = []
    floats = fg.FingerSet.pose_floats
    monkeypatch.setattr(fg.FingerSet, "pose_floats", lambda *a, **k: calls.append(1) or floats(*a, **k))
    for f in range(0, rec.frame_count, 7):
        one = anim.animate(f, f + 1)
        assert calls.pop()  # taken by the one frame
        np.testing.assert_allclose(one.joints[0, joints], whole.joints[f, joints], rtol=0, atol=1e-9)
        np.testing.assert_allclose(one.frames[0, bones], whole.frames[f, bones], rtol=0, atol=1e-9)


def _numpy_passes(self, mcp, ref, tip, joints=True, radius=None):
    """`FingerSet.pose_floats` as the numpy passes compute it (`distal_z` then `pose`)."""
    aim = tip if radius is None else tip + radius * self.distal_z(mcp, ref, tip)
    fp = self.pose(mcp, ref, aim, joints=joints)
    return fp.joints, fp.rotations


def test_one_egocentric_frame_s_fingers_user_and_avatar_are_the_numpy_passes(monkeypatch):
    # The same one-frame solves with every finger (the user's and the avatar's two arm passes')
    # posed by the float kernel and by the numpy passes; everything else the same kernels.
    rec, user = rt.synthetic_take(seed=4)
    avatar = rt.plain_and_turned_avatars()[1]
    floats, local_floats = fg.FingerSet.pose_floats, fg.FingerSet.frames_floats
    avatar_calls = []

    def counted(self, ref, local):
        avatar_calls.append(True)  # the avatar's IK: its targets in the reference frames already
        return local_floats(self, ref, local)

    def local_numpy(self, ref, local):  # the numpy pass from an MCP at the origin, frames side by side
        rots = self.pose(np.zeros_like(local), ref, np.einsum("fij,fj->fi", ref, local), joints=False).rotations
        return rots.transpose(0, 2, 1, 3).reshape(len(local), 3, 9)

    poses = {}
    for kernel, local_kernel in ((floats, counted), (_numpy_passes, local_numpy)):
        monkeypatch.setattr(fg.FingerSet, "pose_floats", kernel)
        monkeypatch.setattr(fg.FingerSet, "frames_floats", local_kernel)
        solver = PreparedSolver(RecordingSource(rec, user), avatar, "egocentric", plant_feet=False)
        poses[kernel] = [solver.solve(f, f + 1) for f in range(0, len(rec.time), 9)]
    assert sum(avatar_calls) >= 2 * len(poses[floats])  # both arm passes took the floats every frame
    worst = 0.0
    for a, b in zip(poses[floats], poses[_numpy_passes]):
        worst = max(worst, np.abs(a.joints - b.joints).max(), np.abs(a.basis - b.basis).max())
    assert worst < 1e-9, worst
