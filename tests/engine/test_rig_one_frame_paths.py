"""One frame's rig paths (DESIGN.md "Prepared solver"): the basis of every bone in one
product pass (`basis._solve_one`), the root placed and its location read in Python floats
(`fk._place_root`, `basis._root_location_one`), consecutive rows written as slices
(`pose_plan.rows_of`) give the values a pose of more frames gives that frame: bit for bit where
the armature is not turned, to the sums' rounding where it is (its W^-1 products' order)."""

from __future__ import annotations

import numpy as np

from bodycal_addon.core import one_frame
from bodycal_addon.retarget.rig import basis as rig_basis
from bodycal_addon.retarget.rig.pose_plan import rows_of
from bodycal_dev import retarget_fixtures as rt

NAMES = ("basis", "root_location", "joints", "rotations", "heads")


def test_one_frame_is_the_frame_of_a_longer_pose(monkeypatch):
    monkeypatch.setattr(one_frame, "ENABLED", False)  # numpy's chain on both sides
    for rig, frames, pelvis in rt.rigs_on_a_take(3, ("clap", "hand_on_head"), 1.0):
        pelvis = pelvis * 1.1 + 0.05
        for f in range(0, len(frames) - 3, 5):
            for held in (False, True):  # the chain aimed, then held from that pose (the flat pass)
                if not held:
                    rig.memo.clear()
                one = rig.solve(frames[f:f + 1], pelvis[f:f + 1])
                rig.memo.clear()
                two = rig.solve(frames[f:f + 2], pelvis[f:f + 2])
                for name in NAMES:
                    a, b = getattr(one, name), getattr(two, name)[:1]
                    assert a.shape == b.shape, name
                    if rig.w_identity:
                        assert np.array_equal(a, b), (name, f)
                    else:
                        np.testing.assert_allclose(a, b, rtol=0, atol=4e-15, err_msg=name)


def test_one_frame_basis_and_root_location_are_the_general_products():
    rng = np.random.default_rng(7)
    for rig, frames, pelvis in rt.rigs_on_a_take(4, ("clap",), 0.5):
        P, H = rig.solve(frames[:2], pelvis[:2]).rotations, rig.solve(frames[:2], pelvis[:2]).heads
        P, H = np.ascontiguousarray(P.swapaxes(0, 1)), np.ascontiguousarray(H.swapaxes(0, 1))
        H = H + rng.normal(0, 0.1, H.shape)  # heads off the pose's: the location is not zero
        plan = rig_basis.BasisPlan.of(rig.parent, rig.rest, rig.head, rig.root)
        for f in range(2):
            p1, h1 = np.ascontiguousarray(P[:, f:f + 1]), np.ascontiguousarray(H[:, f:f + 1])
            one = rig_basis.solve(plan, p1)
            both = rig_basis.solve(plan, P)[f:f + 1]
            np.testing.assert_array_equal(one, both)  # the same sums in the same order
            loc1 = rig_basis.root_location(plan, p1, h1)
            loc2 = rig_basis.root_location(plan, P, H)[f:f + 1]
            np.testing.assert_allclose(loc1, loc2, rtol=0, atol=1e-15)
            assert np.abs(loc1).max() > 1e-3


def test_rows_of_is_a_slice_only_for_consecutive_rows():
    assert rows_of([3, 4, 5]) == slice(3, 6)
    assert rows_of(np.array([7])) == slice(7, 8)
    got = rows_of([1, 2, 4])
    assert isinstance(got, np.ndarray) and got.tolist() == [1, 2, 4]
    assert isinstance(rows_of([]), np.ndarray)
    a = np.zeros(8)
    a[rows_of([2, 3])] = 1.0
    a[rows_of([5, 7])] = 2.0
    assert a.tolist() == [0, 0, 1, 1, 0, 2, 0, 2]
