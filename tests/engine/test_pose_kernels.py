"""The bake's rig-posing kernels (retarget/pose_kernels.py, DESIGN.md "Prepared solver") give the
general helpers' values to the bit: the pose-bone quaternions from entry rows are
transforms.quat_from_rows' (every Shepperd candidate, ties, NaN), X^T's entries are
transforms.matmul_stack's sums, and a many-frame pose-bone basis is the general formula's."""

from __future__ import annotations

import numpy as np

from bodycal_addon.core import transforms as tf
from bodycal_addon.retarget import pose_kernels as pk
from bodycal_addon.retarget.rig import basis as rig_basis
from bodycal_addon.retarget.rig import fk as rig_fk
from bodycal_dev import retarget_fixtures as rt


def _same(a, b):
    return np.array_equal(a, b, equal_nan=True)


def test_quaternions_from_entry_rows_are_quat_from_rows_to_the_bit():
    rng = np.random.default_rng(11)
    q = rng.normal(size=(3000, 4))
    rot = tf.quat_to_matrix(q / np.linalg.norm(q, axis=1, keepdims=True))
    half_turns = [np.diag(d) for d in ([1.0, -1, -1], [-1.0, 1, -1], [-1.0, -1, 1])]  # each diagonal the largest
    ties = [np.eye(3), np.diag([1.0, 1, -1]), np.diag([-1.0, 1, 1]), np.zeros((3, 3))]
    nan = np.full((3, 3), np.nan)
    odd = np.eye(3)
    odd[0, 1] = np.nan  # NaN off the diagonal: the candidate is still chosen by the diagonal
    mats = np.concatenate([rot, rng.normal(size=(500, 3, 3)), np.stack(half_turns + ties + [nan, odd])])
    comp = np.ascontiguousarray(mats.reshape(-1, 9).T)
    picks = np.argmax(np.stack([comp[0] + comp[4] + comp[8], comp[0], comp[4], comp[8]]), axis=0)
    assert set(picks.tolist()) == {0, 1, 2, 3}  # every candidate is exercised
    with np.errstate(invalid="ignore", divide="ignore"):
        assert _same(pk.quat_from_entries(comp), tf.quat_from_rows(comp))
        # blocks where every item picks one candidate (quat_from_rows' slice path): small turns
        # (the trace's, most of a pose's bones), then half turns about x
        near = np.concatenate([np.ones((50, 1)), 0.1 * rng.normal(size=(50, 3))], axis=1)
        small = tf.quat_to_matrix(near / np.linalg.norm(near, axis=1, keepdims=True))
        for block in (small, np.repeat(half_turns[:1], 5, axis=0)):
            rows = np.ascontiguousarray(block.reshape(-1, 9).T)
            assert _same(pk.quat_from_entries(rows), tf.quat_from_rows(rows))


def test_entry_row_products_are_matmul_stack_to_the_bit():
    rng = np.random.default_rng(12)
    child, parent = rng.normal(size=(2, 40, 30, 3, 3))  # 1200 items: matmul_stack's sums
    out = np.empty((40, 30, 3, 3))
    pk.product_t_into(out, pk.entry_rows(child), pk.entry_rows(parent))
    assert np.array_equal(out, tf.matmul_stack(child.swapaxes(-1, -2), parent))
    rows = np.array([0, 3, 6, 1, 4, 7, 2, 5, 8])
    assert np.array_equal(pk.entry_rows(child, rows), tf.transposed(child).reshape(-1, 9).T.reshape(9, 40, 30))


def test_a_bake_chunk_s_basis_is_the_general_formula_s_to_the_bit():
    for rig, frames, pelvis in rt.rigs_on_a_take(3, ("clap", "walk_in_place"), 1.5):
        P, _ = rig_fk.pose(rig, rig.memo, frames, pelvis)
        assert P.shape[1] >= tf.STACKED_FRAMES and P.shape[0] * P.shape[1] >= tf.MANY_PRODUCTS
        # the general formula (`basis.solve` of a few frames): X^T = P_child^T P_parent, times the
        # fixed factors bone by bone, Shepperd's quaternions of the transposed products
        kids, parents, fixed = rig.basis_plan.kids, rig.basis_plan.parents, rig.basis_plan.fixed
        rel_t = tf.transposed(P)
        rel_t[kids] = tf.matmul_stack(P.take(kids, axis=0).swapaxes(-1, -2), P.take(parents, axis=0))
        basis_t = tf.stacks_mul(rel_t, fixed)
        n, nf = basis_t.shape[:2]
        want = tf.quat_from_rows(basis_t.transpose(3, 2, 1, 0).reshape(9, nf * n)).T.reshape(nf, n, 4)
        got = rig_basis.solve(rig.basis_plan, P)
        assert got.shape == want.shape and np.array_equal(got, want)


def test_a_few_matrices_quaternions_are_quat_from_rows_s_and_pick_the_same_candidate():
    # One frame's kernel (quat_of_few: every candidate in one product, argmax's pick) against the
    # bake's (quat_from_rows): the same candidate for every item (ties and NaN as argmax takes
    # them), so the same quaternion to the sums' rounding, w >= 0, NaN where the bake's is NaN.
    rng = np.random.default_rng(13)
    q = rng.normal(size=(200, 4))
    rot = tf.quat_to_matrix(q / np.linalg.norm(q, axis=1, keepdims=True))
    half_turns = [np.diag(d) for d in ([1.0, -1, -1], [-1.0, 1, -1], [-1.0, -1, 1])]
    ties = [np.eye(3), np.diag([1.0, 1, -1]), np.diag([-1.0, 1, 1])]
    odd = np.eye(3)
    odd[0, 1] = np.nan
    mats = np.concatenate([rot, np.stack(half_turns + ties + [np.full((3, 3), np.nan), odd])])
    comp = np.ascontiguousarray(mats.reshape(-1, 9).T)
    picks = np.argmax(np.stack([comp[0] + comp[4] + comp[8], comp[0], comp[4], comp[8]]), axis=0)
    assert set(picks.tolist()) == {0, 1, 2, 3}
    with np.errstate(invalid="ignore", divide="ignore"):
        got, want = pk.quat_of_few(comp), tf.quat_from_rows(comp)
    assert got.shape == want.shape
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-15)
    assert np.array_equal(np.isnan(got), np.isnan(want))
    finite = np.isfinite(got[0])
    assert (got[0][finite] >= 0).all()


def test_few_matmul_is_matmul_through_numpy_s_own_loop():
    rng = np.random.default_rng(14)
    a, b = rng.normal(size=(2, 50, 1, 3, 3))
    got = pk.few_matmul(a, b, (50, 1, 3, 3))
    np.testing.assert_allclose(got, np.matmul(a, b), rtol=0, atol=1e-15)
    # the plain sums (a_i0 b_0k + a_i1 b_1k) + a_i2 b_2k, not BLAS's
    np.testing.assert_allclose(got, tf.matmul_stack(np.repeat(a, 6, axis=1), np.repeat(b, 6, axis=1))[:, :1],
                               rtol=0, atol=1e-15)
    local = rng.normal(size=(50, 1, 3, 5))
    np.testing.assert_allclose(pk.few_matmul(a, local, (50, 1, 3, 5)), np.matmul(a, local), rtol=0, atol=1e-15)
    w = rng.normal(size=(3, 3))
    np.testing.assert_allclose(pk.few_matmul(w, a, a.shape), np.matmul(w, a), rtol=0, atol=1e-15)


def test_one_frame_rig_solve_is_the_bake_chunk_s_on_a_take(monkeypatch):
    # One frame's rig solve (few_matmul's products, quat_of_few's quaternions, numpy's path and
    # mathutils' chain aim) against a many-frame chunk's (the bake's kernels) on frames of a take,
    # on a plain and a turned armature: numpy's path within 1e-12, mathutils' within float32's.
    from bodycal_addon.core import one_frame
    for rig, frames, pelvis in rt.rigs_on_a_take(4, ("clap", "walk_in_place"), 1.0):
        bake = rig.solve(frames, pelvis)
        assert len(frames) >= rig_fk.FEW_FRAMES
        for on, atol in ((False, 1e-12), (True, 1e-6)):
            monkeypatch.setattr(one_frame, "ENABLED", on)
            for f in range(0, len(frames), 7):
                rig.memo.clear()
                one = rig.solve(frames[f:f + 1], pelvis[f:f + 1])
                for name in ("basis", "root_location", "joints", "frames"):
                    np.testing.assert_allclose(getattr(one, name)[0], getattr(bake, name)[f], rtol=0, atol=atol,
                                               err_msg=f"{name} frame {f} mathutils={on}")
