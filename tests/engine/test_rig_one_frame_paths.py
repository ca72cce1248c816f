"""One frame's rig paths (DESIGN.md "Prepared solver"): the basis of every bone in one
product pass (`basis._solve_one`), the root placed and its location read in Python floats
(`fk._place_root`, `basis._root_location_one`), consecutive rows written as slices
(`pose_plan.rows_of`) give the values a pose of more frames gives that frame: bit for bit where
the armature is not turned, to the sums' rounding where it is (its W^-1 products' order). One
frame of a turned armature, posed in its turned space (`fk.posed`), gives the armature-space pose."""

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


def test_a_turned_armature_s_frame_posed_in_its_turned_space_is_the_armature_space_pose():
    """One frame of a turned armature (mathutils' chain) is posed as W P and W H (`fk.posed`,
    `plan.TurnedOne`): its basis, root location, joints, realised frames and (read back) its
    rotations and heads are those of the same pose in the armature's space, which a two-frame
    pose holding the same chain rotations gives (to the sums' rounding); an unturned armature
    is never posed turned."""
    from bodycal_addon.retarget.rig import fk as rig_fk
    from bodycal_addon.retarget.rig.chain import ChainMemo

    turned_rigs = 0
    for rig, frames, pelvis in rt.rigs_on_a_take(5, ("clap", "hand_on_head"), 1.0):
        for f in range(0, len(frames) - 3, 7):
            one_f, one_p = frames[f:f + 1], pelvis[f:f + 1]
            rig.memo.clear()
            P1, H1, turned, _ = rig_fk.posed(rig, rig.memo, one_f, one_p)
            assert turned == (not rig.w_identity and one_frame.ENABLED)
            if not turned:
                continue
            turned_rigs += 1
            rig.memo.clear()
            one = rig.solve(one_f, one_p, realised=True)
            held = np.matmul(rig.w_rot.T, rig.memo.rotations)  # the chain's rotations, armature space
            # the same pose in the armature's space: two frames (numpy's flat pass) holding that chain
            two_f, two_p = np.concatenate([one_f, one_f]), np.concatenate([one_p, one_p])
            memo = ChainMemo()
            memo.keep(ChainMemo.key_of(rig.chain, two_f, two_p), np.concatenate([held, held], axis=1))
            P2, H2 = rig_fk.pose(rig, memo, two_f, two_p)
            assert memo.rotations is not None
            two = rig_fk.finish(rig, rig_basis.solve(rig.basis_plan, P2), P2, H2,
                                rig_basis.root_location(rig.basis_plan, P2, H2), True)
            for name in ("basis", "root_location", "joints", "frames", "rotations", "heads"):
                a, b = getattr(one, name), getattr(two, name)[:1]
                assert a.shape == b.shape, name
                np.testing.assert_allclose(a, b, rtol=0, atol=1e-13, err_msg=name)
            # and the armature-space pose `pose` hands back is the turned one turned back
            np.testing.assert_allclose(np.matmul(rig.w_rot.T, P1), P2[:, :1], rtol=0, atol=1e-13)
    assert turned_rigs > 0
