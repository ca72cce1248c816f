"""The user animation of ONE frame (issue 41; DESIGN.md "Prepared solver"): the
one-frame path (`UserAnimator._animate_one`: every tracker-rotation product in one call, the
trackers' joints in one weighted sum) gives
the block's values to float64's rounding, on both tracker profiles (the minimal one's elbows and
knees from two bones, shoulders reaching, toes rigid on the foot) and through dropouts (a joint's
mean over the trackers tracking it); the numpy fallback (no mathutils) is the block's path."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from bodycal_addon.body.skeleton import BONES
from bodycal_addon.core import one_frame
from bodycal_addon.retarget import user_animation as ua
from bodycal_dev import synthetic
from bodycal_dev.retarget_fixtures import one_frame_atol

_CONDITIONED = [k for k, b in enumerate(BONES) if not b.shortcut]  # bones whose x hint is off their axis


@pytest.fixture(scope="module", params=["full", "minimal"])
def take(request):
    perf = synthetic.make_performer(seed=3)
    rec, truth = synthetic.record_session(perf, profile=request.param, motions=("clap", "hand_on_head"),
                                          calibration=False, motion_seconds=1.0, dropout_rate=0.02, seed=3)
    if request.param == "full":
        return rec, truth.body_model()
    # six devices, the elbows, knees and toes known in none of them (as a six-device calibration
    # leaves them): the elbows and knees from two bones, the shoulders reaching for far wrists,
    # the toes rigid on the foot
    user = copy.deepcopy(truth.body_model())
    for j in ("elbow_l", "elbow_r", "knee_l", "knee_r", "toe_l", "toe_r"):
        user.joints[j].frames = {}
    return rec, user


def _one_frame_and_block_path(anim, f, monkeypatch):
    """(one frame by `_animate_one`, the same frame by the block's path)."""
    one = anim.animate(f, f + 1)
    with monkeypatch.context() as m:
        m.setattr(ua.UserAnimator, "_animate_one", lambda *a: None)
        block = anim.animate(f, f + 1)
    return one, block


def test_one_frame_user_animation_is_the_blocks(take, monkeypatch):
    rec, user = take
    anim = ua.UserAnimator(rec, user)
    plan = anim.plan
    if "full" in rec.name:  # fingertip markers: the fingers posed within the one-frame path
        assert plan.tips
    else:
        assert not any(tracked for *_, tracked in plan.limbs) and plan.reaching == ["l", "r"]
        assert {t[0] for t in plan.toes.values()} == {"rigid"}
    whole = anim.animate(0, rec.frame_count)
    used = 0
    for f in range(0, rec.frame_count, 5):
        one, block = _one_frame_and_block_path(anim, f, monkeypatch)
        used += bool(anim._one)
        # the same arithmetic as the block's, reassociated: within the numpy path's pin tolerance
        # (measured: joints 4e-15, frames 1e-11; the hip shortcuts 6e-9, see below)
        np.testing.assert_allclose(one.joints, block.joints, rtol=0, atol=1e-9)
        np.testing.assert_allclose(one.frames[:, _CONDITIONED], block.frames[:, _CONDITIONED], rtol=0, atol=1e-9)
        # and the bake's, within the one-frame tolerances (the trunk's mathutils kernels: float32),
        # but for the shortcut bones: a hip bone lies along the sacrum's lateral, its x hint, so its
        # x is the hint's float32 residue (measured on main too: hip_l 0.036 off on this take's
        # frame 730, six devices)
        np.testing.assert_allclose(one.joints[0], whole.joints[f], rtol=0, atol=one_frame_atol("joints"))
        np.testing.assert_allclose(one.frames[0, _CONDITIONED], whole.frames[f, _CONDITIONED], rtol=0,
                                   atol=one_frame_atol("basis"))
        assert one.valid[0] == whole.valid[f]
    assert used


@pytest.mark.parametrize("fingers, finger_joints", [(True, True), (True, False), (False, True)])
def test_one_frame_leaves_out_what_the_tips_pose_and_keeps_the_values(take, monkeypatch, fingers, finger_joints):
    # The tipped fingers' second and third phalanges' frames (and, when the joints are posed, their
    # joints after the MCP) are overwritten by `pose_user_fingers`: the one-frame tables leave
    # their products out, and every value read is still the block's, whatever the callers' flags.
    rec, user = take
    anim = ua.UserAnimator(rec, user)
    plan = anim.plan
    for f in range(0, rec.frame_count, 23):
        one = anim.animate(f, f + 1, fingers=fingers, finger_joints=finger_joints)
        with monkeypatch.context() as m:
            m.setattr(ua.UserAnimator, "_animate_one", lambda *a, **k: None)
            block = anim.animate(f, f + 1, fingers=fingers, finger_joints=finger_joints)
        np.testing.assert_allclose(one.joints, block.joints, rtol=0, atol=1e-9)
        np.testing.assert_allclose(one.frames[:, _CONDITIONED], block.frames[:, _CONDITIONED], rtol=0, atol=1e-9)
    posed = (bool(plan.tips) and fingers, bool(plan.tips) and fingers and finger_joints)
    assert list(anim._one) == [posed]
    left_out = len(anim._one_frame_tables(plan)["V"]) - len(anim._one[posed]["V"])
    assert left_out == len(plan.tips) * (6 * posed[0] + 3 * posed[1])
    assert ("full" in rec.name) == bool(plan.tips)


def test_one_frame_path_is_taken_and_steps_aside_for_a_partly_tracked_joint(take, monkeypatch):
    # Where one of a joint's estimates is not tracked this frame, the joint is the mean of those
    # tracked: the block's path computes it (`_animate_one` returns None), so the values match.
    rec, user = take
    anim = ua.UserAnimator(rec, user)
    calls = {"one": 0, "fell_back": 0}
    original = ua.UserAnimator._animate_one

    def counting(self, *a):
        out = original(self, *a)
        calls["one" if out is not None else "fell_back"] += 1
        return out

    monkeypatch.setattr(ua.UserAnimator, "_animate_one", counting)
    whole = anim.animate(0, rec.frame_count)
    tr = anim.reader.read()
    multi = anim._one_frame_tables(anim.plan)["multi"]
    partly = np.flatnonzero(~tr.tracked.take(multi, axis=0).all(0)) if multi is not None else np.array([], int)
    for f in list(partly[:5]) + [0, rec.frame_count // 2]:
        got = anim.animate(int(f), int(f) + 1)
        np.testing.assert_allclose(got.joints[0], whole.joints[f], rtol=0, atol=one_frame_atol("joints"))
        np.testing.assert_allclose(got.frames[0, _CONDITIONED], whole.frames[f, _CONDITIONED], rtol=0,
                                   atol=one_frame_atol("basis"))
    assert calls["one"] >= 2
    assert calls["fell_back"] == min(len(partly), 5)


def test_numpy_fallback_is_the_blocks_path(take, monkeypatch):
    rec, user = take
    anim = ua.UserAnimator(rec, user)
    whole = anim.animate(0, rec.frame_count)
    monkeypatch.setattr(one_frame, "ENABLED", False)
    for f in range(3, rec.frame_count, 17):
        got = anim.animate(f, f + 1)
        np.testing.assert_allclose(got.joints[0], whole.joints[f], rtol=0, atol=1e-9)
        np.testing.assert_allclose(got.frames[0], whole.frames[f], rtol=0, atol=1e-9)
    assert not anim._one  # none made: the fallback is the block's path


def test_one_frame_reads_of_a_whole_take_are_the_blocks_to_the_bit(take, monkeypatch):
    """A frame read alone from a whole take takes its rotations from a block converted at once
    (`TrackerReader._whole_rotations`): every field is the block read's, bit for bit, on either
    side of a block's edge, and a caller writing into them leaves the next read alone."""
    from bodycal_addon.retarget import trackers as trk
    rec, user = take
    monkeypatch.setattr(trk, "ROTATION_BLOCK", 7)  # several blocks in the short take
    whole = trk.TrackerReader(rec, user).read()
    reader = trk.TrackerReader(rec, user)
    assert reader._whole is not None
    for f in [0, 6, 7, 13, 14, 20, rec.frame_count - 1, 6, 0]:
        one = reader.read(f, f + 1)
        assert one.rotations.tobytes() == whole.rotations[:, f:f + 1].tobytes()
        assert one.positions.tobytes() == whole.positions[:, f:f + 1].tobytes()
        assert np.array_equal(one.valid, whole.valid[f:f + 1])
        one.rotations[:] = np.nan  # the caller's own copy
        reader._last = None
    assert reader._rotation_block[0][0] == 0  # the last frames read came from the first block


def test_one_frame_trunk_in_floats_is_numpys():
    # The sacrum turned toward the hip line of one frame (`_sacrum_turned`, Python floats) is the
    # numpy path's (two frames at once) to float64's rounding, turned hips and a sacrum far from
    # them included; the mathutils turn it replaced was float32's (about 1e-7 off).
    from bodycal_addon.core.transforms import quat_to_matrix
    rng = np.random.default_rng(5)
    q = rng.normal(size=(200, 4))
    sac = quat_to_matrix(q / np.linalg.norm(q, axis=1, keepdims=True))
    hip_l, hip_r = rng.normal(size=(200, 3)), rng.normal(size=(200, 3))
    worst = 0.0
    for f in range(0, 200, 2):
        block = ua.sacrum_toward_hip_line(sac[f:f + 2], hip_l[f:f + 2], hip_r[f:f + 2])
        for k in (0, 1):
            one = ua.sacrum_toward_hip_line(sac[f + k:f + k + 1], hip_l[f + k:f + k + 1], hip_r[f + k:f + k + 1])
            worst = max(worst, float(np.abs(one[0] - block[k]).max()))
    assert worst < 1e-12, worst


def test_one_frame_pelvis_is_the_blocks_in_float64(take, monkeypatch):
    # The trunk of one frame (`UserAnimator._trunk_one`): the pelvis (the tracker's estimate and the
    # hips' through the turned sacrum) and the sacrum's frame are the block path's float64 values
    # (the spine's joints and vertebrae stay the mathutils kernel's: the pins' tolerance).
    assert one_frame.ENABLED, "the engine lane installs mathutils (requirements-dev.txt)"
    rec, user = take
    anim = ua.UserAnimator(rec, user)
    whole = anim.animate(0, rec.frame_count)
    pelvis, sacrum = ua.JI["pelvis"], ua.BI["sacrum"]
    for f in range(0, rec.frame_count, 7):
        one = anim.animate(f, f + 1)
        if not whole.valid[f]:
            continue
        np.testing.assert_allclose(one.joints[0, pelvis], whole.joints[f, pelvis], rtol=0, atol=1e-12)
        np.testing.assert_allclose(one.frames[0, sacrum], whole.frames[f, sacrum], rtol=0, atol=1e-12)
