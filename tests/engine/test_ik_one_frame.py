"""The avatar IK of one frame (DESIGN.md "Prepared solver", "Decision (the limbs in floats)"): the
limbs read out of the arrays once, solved in Python floats (`ik.two_bone_floats`) and written back in
one scatter (`PreparedSolver._limbs_one`), with the user's swivel and the shoulders' direction in
floats too: numpy's path's values, to the bit for the helpers and to float64's sums for a solve."""

from __future__ import annotations

import numpy as np
import pytest

from bodycal_addon.core import one_frame
from bodycal_addon.core.transforms import normalize
from bodycal_addon.retarget import ik
from bodycal_addon.retarget import solver as solver_module
from bodycal_addon.retarget.pose_source import RecordingSource
from bodycal_addon.retarget.solver import PreparedSolver
from bodycal_dev import retarget_fixtures as rt


class _Up:
    def __init__(self, joints):
        self.joints = joints


def test_the_user_s_swivel_and_the_shoulders_of_one_frame_are_numpy_s_to_the_bit():
    rng = np.random.default_rng(3)
    for case in range(200):
        joints = rng.normal(size=(1, 80, 3)) * rng.uniform(0.01, 2.0)
        rows = rng.choice(80, size=(3, 2), replace=False)
        if case % 7 == 0:  # an effector on its anchor (the axis vanishes)
            joints[0, rows[2, 0]] = joints[0, rows[0, 0]]
        up = _Up(joints)
        want = PreparedSolver._user_swivel(up, rows)
        got = np.array(PreparedSolver._user_swivel_one(up, rows))
        assert np.array_equal(got, want) and np.isfinite(got).all()
        if case % 5 == 0:  # shoulders on each other
            joints[0, solver_module._SHOULDER_ROWS[0]] = joints[0, solver_module._SHOULDER_ROWS[1]]
        want = normalize(joints[:, solver_module._SHOULDER_ROWS[0]] - joints[:, solver_module._SHOULDER_ROWS[1]])
        assert np.array_equal(solver_module._top_right(joints), want)


@pytest.fixture(scope="module")
def take():
    return rt.synthetic_take(seed=4)


@pytest.mark.parametrize("method", ["egocentric", "offsets"])  # (the rotation copy has no limb IK)
def test_one_frame_s_limbs_in_floats_are_the_numpy_path_s(take, monkeypatch, method):
    # The same one-frame solve with the limbs in floats end to end (FEW_LIMBS 4) and on numpy's
    # path (FEW_LIMBS 0: `_limbs` and numpy's `two_bone`); everything else the same kernels.
    rec, user = take
    avatar = rt.plain_and_turned_avatars()[1]
    assert one_frame.ENABLED
    used = []
    limbs_one = PreparedSolver._limbs_one
    monkeypatch.setattr(PreparedSolver, "_limbs_one", lambda *a, **k: used.append(1) or limbs_one(*a, **k))
    poses = {}
    for few in (4, 0):
        used.clear()
        monkeypatch.setattr(ik, "FEW_LIMBS", few)
        solver = PreparedSolver(RecordingSource(rec, user), avatar, method, plant_feet=False)
        poses[few] = [solver.solve(f, f + 1) for f in range(0, len(rec.time), 7)]
        assert bool(used) == (few == 4)
    for a, b in zip(poses[4], poses[0]):
        np.testing.assert_allclose(a.joints, b.joints, rtol=0, atol=1e-9)
        np.testing.assert_allclose(a.basis, b.basis, rtol=0, atol=1e-9)
