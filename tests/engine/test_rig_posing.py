"""Posing a few frames (DESIGN.md "Prepared solver"). AvatarRig: a pose of fewer than
rig/fk.FEW_FRAMES frames (the heads the spine chain does not read placed in one padded pass,
every head in that pass when the chain's rotations are held from the last pose, a one-frame chain
aimed in Python floats, the joints on their carriers in one padded product) is the level-by-level
pose of the same frames, to the bit; SurfacePoser: its padded mesh points are
the per-group ones."""

from __future__ import annotations

import numpy as np

from bodycal_addon.core import one_frame
from bodycal_addon.retarget import user_animation as ua
from bodycal_addon.retarget.rig import fk
from bodycal_dev import retarget_fixtures as rt
from bodycal_dev import synthetic


def test_a_few_frames_pose_as_level_by_level_bit_for_bit(monkeypatch):
    # numpy's paths (one frame's chain aimed in mathutils: test_one_frame.py)
    monkeypatch.setattr(one_frame, "ENABLED", False)
    few_frames = fk.FEW_FRAMES
    for rig, frames, pelvis in rt.rigs_on_a_take(2, ("clap", "hand_on_head"), 1.0):
        assert rig.pose_plan(None).deferred is not None  # the padded pass is taken
        pelvis = pelvis * 1.1
        for f in range(0, len(frames) - 3, 7):
            for n in (1, 3):
                poses = []
                for few in (fk.FEW_FRAMES, 0):  # the padded pass, then level by level
                    monkeypatch.setattr(fk, "FEW_FRAMES", few)
                    rig.memo.clear()  # the chain aimed each time (not the last pose's, reused)
                    poses.append(rig.solve(frames[f:f + n], pelvis[f:f + n]))
                monkeypatch.setattr(fk, "FEW_FRAMES", few_frames)
                # again with the chain's rotations held from that pose: every head in one pass
                held = rig.solve(frames[f:f + n], pelvis[f:f + n])
                assert rig.memo.rotations is not None and rig.pose_plan(None).flat is not None
                for name in ("basis", "root_location", "joints", "frames"):
                    assert np.array_equal(getattr(poses[0], name), getattr(poses[1], name)), (name, f, n)
                    assert np.array_equal(getattr(held, name), getattr(poses[1], name)), (name, f, n)


def test_a_few_frames_surface_is_the_grouped_one(monkeypatch):
    # egocentric.SurfacePoser: fewer than surface.FEW_FRAMES frames pose every mesh point in one
    # padded product; the same points as the product per group of bones (to rounding: the BLAS
    # kernel may change with the padded width).
    from bodycal_addon.retarget import egocentric as ego
    from bodycal_addon.retarget.egocentric import surface

    perf = synthetic.make_performer(seed=2)
    rec, truth = synthetic.record_session(perf, motions=("clap",), calibration=False, motion_seconds=1.0)
    up = ua.animate_user(rec, truth.body_model())
    for model in (truth.body_model(), rt.procedural_avatar()):
        poser = ego.SurfacePoser(model, ego.common_elements(truth.body_model(), rt.procedural_avatar()))
        assert len(poser.point_groups) > 1  # bones carrying different counts of points
        for f in range(0, 60, 13):
            few = poser.pose(up.joints[f:f + 2], up.frames[f:f + 2])
            monkeypatch.setattr(surface, "FEW_FRAMES", 0)
            grouped = poser.pose(up.joints[f:f + 2], up.frames[f:f + 2])
            monkeypatch.undo()
            assert few.tri.shape == grouped.tri.shape and few.tri.size
            np.testing.assert_allclose(few.tri, grouped.tri, rtol=0, atol=1e-12)
            np.testing.assert_allclose(few.tri_normal, grouped.tri_normal, rtol=0, atol=1e-12)


def test_stacked_3x3_helpers_against_numpy():
    """transforms.transposed and mul_stack are numpy's transpose and products to the bit;
    matmul_stack is np.matmul for a few items and within rounding (its sums are not fused
    multiply-adds) for many, whatever the operands' layout."""
    from bodycal_addon.core import transforms as tf

    rng = np.random.default_rng(3)
    stack = rng.normal(size=(4, 300, 3, 3))
    m = rng.normal(size=(3, 3))
    np.testing.assert_array_equal(tf.transposed(stack), stack.swapaxes(-1, -2))
    np.testing.assert_array_equal(tf.mul_stack(m, stack),
                                  tf.stack_mul(np.ascontiguousarray(stack.swapaxes(-1, -2)), m.T).swapaxes(-1, -2))
    other = rng.normal(size=stack.shape)
    few = stack[0, :tf.MANY_PRODUCTS - 1]
    np.testing.assert_array_equal(tf.matmul_stack(few, other[0, :len(few)]), few @ other[0, :len(few)])
    for a in (stack, stack.swapaxes(-1, -2)):  # contiguous and transposed operands
        got = tf.matmul_stack(a, other)
        np.testing.assert_allclose(got, a @ other, rtol=0, atol=1e-14)
        assert got.flags.c_contiguous
