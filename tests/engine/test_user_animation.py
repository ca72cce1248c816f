"""Step 1: the user's skeleton animated from the trackers (Delahaye 2023, appendix D), against the
synthetic performer's true joint tracks."""

from __future__ import annotations

import numpy as np
import pytest

from bodycal_addon.body import skeleton as sk
from bodycal_addon.core import one_frame
from bodycal_addon.core.errors import BodyCalError
from bodycal_addon.core.transforms import quat_normalize, quat_to_matrix
from bodycal_addon.recording.model import Recording
from bodycal_addon.retarget import trackers
from bodycal_addon.retarget import user_animation as ua
from bodycal_dev import synthetic

TRACKED_JOINTS = ("pelvis", "skull_base", "head", "shoulder_l", "shoulder_r", "elbow_l", "elbow_r", "wrist_l",
                  "wrist_r", "hip_l", "hip_r", "knee_l", "knee_r", "ankle_l", "ankle_r", "toe_l", "toe_r")


@pytest.fixture(scope="module")
def exact():
    perf = synthetic.make_performer(seed=0)
    rec, truth = synthetic.record_session(perf, motions=("hand_on_belly", "clap"), calibration=False,
                                          motion_seconds=1.5, noise_mm=0.0, wobble_mm=0.0)
    return rec, truth, truth.body_model()


def _err_mm(up, truth, joint):
    return np.linalg.norm(up.joints[:, sk.JOINT_INDEX[joint]] - truth.joint_tracks[joint], axis=-1) * 1e3


def test_tracked_joints_follow_the_trackers_exactly(exact):
    rec, truth, model = exact
    up = ua.animate_user(rec, model)
    assert up.joints.shape == (rec.frame_count, len(sk.JOINTS), 3)
    assert up.frames.shape == (rec.frame_count, len(sk.BONES), 3, 3)
    for j in TRACKED_JOINTS:
        assert _err_mm(up, truth, j).max() < 0.5, j


def test_limb_bones_keep_the_hinge_right_and_join(exact):
    rec, truth, model = exact
    up = ua.animate_user(rec, model)
    for s in ("l", "r"):
        for a, m, e, ab, mb in (("shoulder", "elbow", "wrist", "upperarm", "forearm"),
                                ("hip", "knee", "ankle", "thigh", "shin")):
            upper, lower = up.frames[:, sk.BONE_INDEX[f"{ab}_{s}"]], up.frames[:, sk.BONE_INDEX[f"{mb}_{s}"]]
            # Same +X on both bones: the limb flexes about the hinge axis only, no twist.
            np.testing.assert_allclose(upper[..., :, 0], lower[..., :, 0], atol=1e-6)
            # +Y runs from the anchor to the intermediate joint and on to the effector.
            d1 = up.joint(f"{m}_{s}") - up.joint(f"{a}_{s}")
            d2 = up.joint(f"{e}_{s}") - up.joint(f"{m}_{s}")
            np.testing.assert_allclose(upper[..., :, 1], d1 / np.linalg.norm(d1, axis=-1, keepdims=True), atol=1e-9)
            np.testing.assert_allclose(lower[..., :, 1], d2 / np.linalg.norm(d2, axis=-1, keepdims=True), atol=1e-9)
    det = np.linalg.det(up.frames)
    np.testing.assert_allclose(det, 1.0, atol=1e-9)


def test_fingertips_from_markers(exact):
    rec, truth, model = exact
    up = ua.animate_user(rec, model)
    for s in ("l", "r"):
        for f in ("thumb", "index", "middle", "ring", "pinky"):
            assert np.median(_err_mm(up, truth, f"tip_{f}_{s}")) < 2.0, (f, s)


def test_spine_reaches_the_skull_base(exact):
    rec, truth, model = exact
    up = ua.animate_user(rec, model)
    np.testing.assert_allclose(up.joint("spine_12"), up.joint("skull_base"), atol=1e-6)
    np.testing.assert_allclose(up.joint("spine_root"), truth.joint_tracks["spine_root"], atol=1e-3)


def test_forward_fill_holds_the_last_valid_frame():
    valid = np.array([False, False, True, False, False, True, True, False])
    np.testing.assert_array_equal(trackers.forward_fill(valid), [2, 2, 2, 2, 2, 5, 6, 6])


def test_dropouts_are_bridged_and_never_nan():
    perf = synthetic.make_performer(seed=1)
    rec, truth = synthetic.record_session(perf, motions=("clap",), calibration=False, motion_seconds=1.0,
                                          dropout_rate=0.05, seed=3)
    assert not rec.valid.all()
    # Readers may have filled the gaps; put NaNs where the devices dropped out to be sure the
    # animation never reads them.
    rec.positions = np.where(rec.valid[..., None], rec.positions, np.nan)
    rec.rotations = np.where(rec.valid[..., None], rec.rotations, np.nan)
    up = ua.animate_user(rec, truth.body_model())
    assert np.isfinite(up.joints).all() and np.isfinite(up.frames).all()
    assert (~up.valid).any() and up.notes
    hand = rec.device_index("hand_l")
    bad = np.flatnonzero(~rec.valid[:, hand] & (np.arange(rec.frame_count) > np.argmax(rec.valid[:, hand])))
    if len(bad):  # bridged from the last tracked pose on (DESIGN.md §6 "Lost devices"): no jump
        f = bad[0]
        assert np.linalg.norm(up.joint("wrist_l")[f] - up.joint("wrist_l")[f - 1]) < 0.02


def test_missing_device_is_one_clear_error(exact):
    rec, truth, model = exact
    keep = [i for i, d in enumerate(rec.devices) if d.role != "pelvis"]
    cut = Recording(rec.name, rec.time, [rec.devices[i] for i in keep], rec.positions[:, keep],
                    rec.rotations[:, keep], rec.valid[:, keep], source="cut.bcrec.json")
    with pytest.raises(BodyCalError, match="pelvis"):
        ua.animate_user(cut, model)


def test_a_frame_of_trackers_reads_as_the_take_does():
    """A few quaternions' rotation matrices (a live frame's devices) are the many's to the bit, and
    the devices by role are views of the roles-first arrays."""
    rng = np.random.default_rng(4)
    q = quat_normalize(rng.normal(size=(7, 3, 4)))
    many = quat_normalize(rng.normal(size=(300, 4)))
    many[:21] = q.reshape(21, 4)
    whole = quat_to_matrix(many)
    rows = np.arange(21).reshape(7, 3)  # q's rows in `many`
    for pick in (lambda a: a, lambda a: a.swapaxes(0, 1), lambda a: a[:, :1], lambda a: a[0]):
        assert quat_to_matrix(pick(q)).tobytes() == whole[pick(rows)].tobytes()
    rec, truth = synthetic.record_session(synthetic.make_performer(seed=2), motions=("clap",), calibration=False,
                                          motion_seconds=0.5)
    reader = trackers.TrackerReader(rec, truth.body_model())
    whole, one = reader.read(), reader.read(20, 21)
    assert set(one.rot) == set(reader.roles) and len(one.pos) == len(reader.roles) and "nose" not in one.pos
    for k, role in enumerate(reader.roles):
        assert one.rot[role].tobytes() == whole.rot[role][20:21].tobytes()
        assert np.shares_memory(one.pos[role], one.positions[k])


def test_one_frame_s_sacrum_turn_is_the_block_s(monkeypatch):
    """`sacrum_toward_hip_line` of one frame (in mathutils, float32: core/one_frame.py) gives the
    block's numpy values to float32's rounding (measured at most 1.2e-6 on 500 random frames), a
    zero hip line (the numpy path's own fallback) to the bit; with mathutils switched off, the
    numpy path's bits."""
    rng = np.random.default_rng(6)
    sacrum = quat_to_matrix(quat_normalize(rng.normal(size=(50, 4))))
    hip_l, hip_r = rng.normal(size=(50, 3)), rng.normal(size=(50, 3))
    hip_r[7] = hip_l[7]
    block = ua.sacrum_toward_hip_line(sacrum, hip_l, hip_r)
    for f in range(50):
        one = ua.sacrum_toward_hip_line(sacrum[f:f + 1], hip_l[f:f + 1], hip_r[f:f + 1])
        if f == 7:
            assert one.tobytes() == block[f:f + 1].tobytes()
        np.testing.assert_allclose(one, block[f:f + 1], rtol=0, atol=5e-6)
    monkeypatch.setattr(one_frame, "ENABLED", False)
    for f in range(50):
        one = ua.sacrum_toward_hip_line(sacrum[f:f + 1], hip_l[f:f + 1], hip_r[f:f + 1])
        assert one.tobytes() == block[f:f + 1].tobytes()
