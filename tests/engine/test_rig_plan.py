"""The rig's plan and its state (DESIGN.md §1 "The rig posed", `retarget/rig/`): the plan's caches are
keyed by value, the chain memo compares its inputs bit for bit, and a pickled rig (a live worker's)
poses as the one it was pickled from."""

from __future__ import annotations

import pickle

import numpy as np

from bodycal_addon.body.rest_frames import model_rest_frames
from bodycal_addon.body.skeleton import JOINT_INDEX as JI
from bodycal_addon.retarget import avatar_pose as ap
from bodycal_addon.retarget import user_animation as ua
from bodycal_addon.retarget.rig.chain import ChainMemo
from bodycal_dev import retarget_fixtures as rt
from bodycal_dev import synthetic


def _take():
    perf = synthetic.make_performer(seed=5)
    rec, truth = synthetic.record_session(perf, motions=("clap",), calibration=False, motion_seconds=0.5)
    user = truth.body_model()
    return ua.animate_user(rec, user), user


def test_the_plan_s_caches_are_keyed_by_value():
    rig = ap.AvatarRig.from_model(rt.procedural_avatar())
    bones = (0, 1, 2, 3)
    assert rig.pose_plan(bones) is rig.pose_plan(tuple(np.array(bones).tolist()))
    assert rig.pose_plan(bones) is not rig.pose_plan(None)
    assert rig.joints_plan(("shoulder_l", "hip_r")) is rig.joints_plan(tuple(["shoulder_l", "hip_r"]))
    # the few frames' one product of the driven bones then the chain's vertebrae is the plan's own
    plan = rig.pose_plan(None)
    rows, fixed = plan.driven_and_chain
    assert np.array_equal(rows, np.concatenate([plan.canon, rig.chain.vertebra]))
    assert np.array_equal(fixed[:, 0], np.concatenate([plan.fixed, rig.chain.fixed]))


def test_the_chain_memo_compares_bits():
    rig = ap.AvatarRig.from_model(rt.procedural_avatar())
    frames = np.broadcast_to(rig.frames0, (2,) + rig.frames0.shape).copy()
    pelvis = np.zeros((2, 3))
    memo = ChainMemo()
    key = ChainMemo.key_of(rig.chain, frames, pelvis)
    memo.keep(key, np.ones(3))
    assert memo.held(ChainMemo.key_of(rig.chain, frames.copy(), pelvis.copy())) is memo.rotations
    negated = pelvis.copy()
    negated[0, 0] = -0.0  # equal as numbers, another input bit for bit
    assert memo.held(ChainMemo.key_of(rig.chain, frames, negated)) is None
    assert memo.held(ChainMemo.key_of(rig.chain, frames, pelvis, b"float32")) is None  # aimed another way
    memo.clear()
    assert memo.held(key) is None


def test_a_pickled_rig_poses_as_its_original():
    up, user = _take()
    for avatar in rt.plain_and_turned_avatars():
        rig = ap.AvatarRig.from_model(avatar)
        frames = ap.copy_frames(up.frames, model_rest_frames(user), rig.frames0)
        pelvis = up.joints[:, JI["pelvis"]]
        for f, n in ((3, 1), (5, 4), (0, 30)):
            want = rig.solve(frames[f:f + n], pelvis[f:f + n])
            copy = pickle.loads(pickle.dumps(rig))  # the memo travels, the mathutils chain is made again
            again = copy.solve(frames[f:f + n], pelvis[f:f + n])
            copy.memo.clear()
            aimed = copy.solve(frames[f:f + n], pelvis[f:f + n])
            for name in ("basis", "root_location", "joints", "frames"):
                assert np.array_equal(getattr(again, name), getattr(want, name)), (name, f, n)
                assert np.array_equal(getattr(aimed, name), getattr(want, name)), (name, f, n)
