"""Recordings of real human motion as an outside tool writes them (`evaluation/`: a CMU clip, the
calibration steps performed by its own skeleton, trackers strapped at random angles and offsets, any
facing): what a real session asks of the engine beyond the synthetic performer (DESIGN.md §7, "Real
motion")."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from outside_takes import clip_performer, outside_recording

from bodycal_addon.calibration import calibrate_user
from bodycal_addon.core import transforms as tf
from bodycal_addon.recording import io as recording_io
from bodycal_addon.recording.model import Recording
from bodycal_addon.retarget import pipeline as pl
from bodycal_dev import retarget_fixtures as rt

WALK = "02_01_walk.bvh"


@pytest.fixture(scope="module")
def walker(data_dir):
    return clip_performer(data_dir, WALK)


def outside_truth(perf, tmp_path, profile: str = "full", seed: int = 0, up: str = "Y", **kw) -> tuple:
    rec, cap = outside_recording(perf, tmp_path, profile, seed, up, **kw)
    return rec, cap.truth()


def moved(rec: Recording, yaw_deg: float, offset) -> Recording:
    """The same recording with the whole room turned about the vertical and moved on the floor."""
    a = np.radians(yaw_deg)
    R = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    q = tf.matrix_to_quat(R)
    out = copy.copy(rec)
    out.positions = rec.positions @ R.T + offset
    out.rotations = tf.quat_mul(q, rec.rotations)
    out.markers = rec.markers @ R.T + offset
    out.devices = [copy.copy(d) for d in rec.devices]
    return out, R, np.asarray(offset, float)


@pytest.fixture(scope="module")
def walk_full(walker, tmp_path_factory):
    return outside_truth(walker, tmp_path_factory.mktemp("outside"), "full", seed=0, yaw=np.radians(90.0))


@pytest.mark.slow
@pytest.mark.parametrize("method", pl.METHODS)
def test_turning_and_moving_the_room_turns_and_moves_the_animation(walk_full, method):
    """The same recording rotated by any yaw and moved anywhere on the floor gives the same
    animation up to that rigid motion (<= 1 mm), whichever way the performer faced."""
    rec, _ = walk_full
    other, R, t = moved(rec, 137.0, (1.3, -0.8, 0.0))
    avatar = rt.procedural_avatar(matrix_world=rt.rigid_matrix_world(30.0, 1.1))
    # in the room (placement "performer"); the object placement plays it on the avatar's spot,
    # relative to the play area's origin, which the room's motion moves the performer away from
    a = pl.retarget(rec, calibrate_user(rec), avatar, method, placement="performer")
    b = pl.retarget(other, calibrate_user(other), avatar, method, placement="performer")
    worst = {j: float(np.max(np.linalg.norm(b.joints_world[j] - (a.joints_world[j] @ R.T + t), axis=-1)))
             for j in a.joints_world}
    assert max(worst.values()) < 1e-3, sorted(worst.items(), key=lambda kv: -kv[1])[:5]


@pytest.mark.slow
def test_a_performer_facing_forward_keeps_the_pelvis_with_the_legs(walker, tmp_path):
    """Facing FORMATS.md's forward (internal +Y) the pelvis used to turn 180 degrees against the
    torso and the legs crossed. The avatar's hip line follows the source's."""
    rec, truth = outside_truth(walker, tmp_path, "full", seed=1, yaw=np.radians(180.0))
    user = calibrate_user(rec)
    avatar = rt.procedural_avatar()
    a, b = truth["motion"]
    J = {n: i for i, n in enumerate(truth["joints"])}
    src = truth["positions"][a:b, J["hip_l"]] - truth["positions"][a:b, J["hip_r"]]
    for method in pl.METHODS:
        anim = pl.retarget(rec, user, avatar, method, placement="performer")  # compared in the room
        hip = anim.joints_world["hip_l"][a:b] - anim.joints_world["hip_r"][a:b]
        d = np.degrees(np.arctan2(hip[:, 1], hip[:, 0]) - np.arctan2(src[:, 1], src[:, 0]))
        d = np.abs((d + 180.0) % 360.0 - 180.0)
        assert d.max() < 5.0, (method, d.max())


def _joint_errors_mm(user, truth) -> dict[str, float]:
    ref = int(round(user.reference_time * truth["fps"]))
    return {n: 1000 * float(np.linalg.norm(user.joints[n].world - truth["positions"][ref, k]))
            for k, n in enumerate(truth["joints"]) if n in user.joints}


@pytest.fixture(scope="module")
def walk_six(walker, tmp_path_factory):
    return outside_truth(walker, tmp_path_factory.mktemp("outside_six"), "six", seed=0, up="Z")


@pytest.mark.slow
def test_six_devices_calibrate_every_step_from_the_devices_there(walk_six):
    """HMD, controllers, pelvis and feet only (AvatarGo's six devices). The swing and flex steps are
    fitted from the devices that are there (the report names which, in which frame) and nothing
    aborts; hips, shoulders, knees and elbows land within 25 mm of the clip's joints."""
    rec, truth = walk_six
    user = calibrate_user(rec)
    cal = user.calibration
    assert not cal["warnings"], cal["warnings"]
    for s in ("l", "r"):
        assert cal["quality"][f"swing_shoulder_{s}"]["frames"].startswith(f"hand_{s} in ")
        assert cal["quality"][f"swing_hip_{s}"]["frames"] == f"foot_{s} in pelvis"
        assert cal["quality"][f"flex_elbow_{s}"]["frames"].startswith(f"hand_{s} in ")
        assert cal["quality"][f"flex_knee_{s}"]["frames"] == f"foot_{s} in pelvis"
        # the knee / elbow is not carried by the foot / hand (they bend at the ankle / wrist)
        assert set(user.joints[f"knee_{s}"].frames) <= {"pelvis"}
        assert user.bones[f"shin_{s}"].extra["right_frame"] == f"foot_{s}"
    err = _joint_errors_mm(user, truth)
    worst = {j: err[j] for j in ("hip_l", "hip_r", "shoulder_l", "shoulder_r", "knee_l", "knee_r", "elbow_l",
                                 "elbow_r") if err[j] > 25.0}
    assert not worst, worst


@pytest.mark.slow
def test_full_profile_without_touches_places_the_joints(walk_full):
    """The real-motion targets without touch steps: knees and elbows within 15 mm (their place along
    the hinge axis where the limb is straight from the anchor to the wrist / ankle), ankles within
    20 mm and wrists within 10 mm (fitted from the motion between the limb tracker and the hand /
    foot device)."""
    rec, truth = walk_full
    user = calibrate_user(rec)
    err = _joint_errors_mm(user, truth)
    limits = {"knee": 15.0, "elbow": 15.0, "ankle": 20.0, "wrist": 10.0, "hip": 10.0, "shoulder": 10.0}
    bad = {j: round(e, 1) for j, e in err.items() if j.split("_")[0] in limits and e > limits[j.split("_")[0]]}
    assert not bad, bad
    q = user.calibration["quality"]
    assert q["flex_knee_l"]["along_axis"] == "straight hip_l - ankle_l"
    assert "ankle_r from the motion" in q and "wrist_l from the motion" in q


def _hip_yaw(anim) -> np.ndarray:
    h = anim.joints_world["hip_l"] - anim.joints_world["hip_r"]
    return np.arctan2(h[:, 1], h[:, 0])


@pytest.mark.slow
def test_the_offsets_pelvis_turns_as_the_other_methods_pelvis(walk_six):
    """AvatarGo's eq. 3 turns the avatar's pelvis from the user's sacrum at the T-pose. That is
    the sacrum the other methods see (half way to the fitted hip line), so with the same devices
    the hip lines agree; from the pelvis tracker's frame alone they stood 0.3-0.75 deg apart on
    this walk and 2 deg on 131_01, the offsets hip line then straying past 5 deg."""
    rec, _ = walk_six
    user = calibrate_user(rec)
    avatar = rt.procedural_avatar()
    yaw = [_hip_yaw(pl.retarget(rec, user, avatar, m, placement="performer")) for m in ("egocentric", "offsets")]
    d = np.degrees(np.abs((yaw[1] - yaw[0] + np.pi) % (2 * np.pi) - np.pi))
    assert d.max() < 0.2, d.max()


@pytest.mark.slow
def test_a_csv_round_trip_gives_the_same_body_model_as_the_json(walk_six, tmp_path):
    from bodycal_addon.recording.io import save_recording

    rec, _ = walk_six
    models = [calibrate_user(recording_io.load_recording(save_recording(rec, tmp_path / name)[0]))
              for name in ("take.bcrec.json", "take.csv")]
    a, b = (m.to_dict() for m in models)
    assert a["calibration"] == b["calibration"]
    for j in a["joints"]:
        np.testing.assert_allclose(a["joints"][j]["world"], b["joints"][j]["world"], atol=1e-9, err_msg=j)


@pytest.mark.slow
@pytest.mark.parametrize("method", pl.METHODS)
def test_planted_feet_hold_still_on_the_floor(walk_full, method):
    """Planted feet (DESIGN.md §6): while the source's foot lies flat (its heel and its ball down)
    the avatar's foot slides no more than 1.5 times the source's (scaled), and through the source's
    stance its sole stays on the floor, whatever the method; without planting it does not (the
    test can fail). (The ankle moves in the rest of the stance: the foot rolls about its heel, then
    its ball.)"""
    from bodycal_addon.blender import mesh_metrics
    from bodycal_addon.output import metrics
    from bodycal_addon.retarget.avatar_pose import AvatarRig

    rec, truth = walk_full
    user = calibrate_user(rec)
    avatar = rt.procedural_avatar()
    a, b = truth["motion"]
    J = {n: i for i, n in enumerate(truth["joints"])}
    figures, source = {}, []
    for plant in (True, False):
        anim = pl.retarget(rec, user, avatar, method, plant_feet=plant)
        slide, low = [], []
        for s in ("l", "r"):
            st = truth["stance"][s][a:b]
            flat = metrics.ground_contact(truth["positions"][a:b, J[f"ankle_{s}"]], truth["fps"]) \
                & metrics.ground_contact(truth["positions"][a:b, J[f"toe_{s}"]], truth["fps"])
            both = flat[1:] & flat[:-1]
            sole = mesh_metrics.sole_points(avatar, anim, s)[a:b]
            # this avatar has no measured contact points: its sole's outline stands in, and the
            # foot pivots about the outline's middle (a flat foot: both points there)
            middle = sole.mean(axis=1)
            slide.append(np.linalg.norm(np.diff(middle[:, :2], axis=0), axis=1)[both])
            if plant:  # the source's own foot (its ankle and ball joints' middle) over those frames
                foot = truth["positions"][a:b][:, [J[f"ankle_{s}"], J[f"toe_{s}"]]].mean(axis=1)
                source.append(np.linalg.norm(np.diff(foot[:, :2], axis=0), axis=1)[both])
            low.append(sole[..., 2].min(axis=1)[st])
        figures[plant] = (np.percentile(np.concatenate(slide), 95) * 1000, np.concatenate(low) * 1000)
    slide_mm, low_mm = figures[True]
    leg = np.mean([sum(np.linalg.norm(truth["positions"][a, J[f"{x}_{s}"]] - truth["positions"][a, J[f"{y}_{s}"]])
                       for x, y in (("hip", "knee"), ("knee", "ankle"))) + truth["positions"][a, J[f"ankle_{s}"], 2]
                   for s in "lr"])
    source_mm = np.percentile(np.concatenate(source), 95) * 1000 * AvatarRig.from_model(avatar).leg_length() / leg
    assert slide_mm <= 1.5 * source_mm, (slide_mm, source_mm)
    # on the floor: the guard's smooth blend (feet.above) stands a pinned point up to half of
    # its floor blend above it, never under
    blend = pl.prepare_recording(rec, user, avatar, method).solver.feet.contacts["l"].floor_blend
    assert 0.0 <= np.median(low_mm) < 1000 * blend / 2 and low_mm.min() > -1.0, \
        (np.median(low_mm), low_mm.min())
    unplanted_slide, unplanted_low = figures[False]
    assert unplanted_slide > 1.0 or abs(np.median(unplanted_low)) > 5.0, (unplanted_slide, np.median(unplanted_low))


def _roll_jitter(anim, bone: str) -> float:
    """p95 of the frame-to-frame change of the bone's angular step about its own Y (its roll), rad."""
    R = tf.quat_to_matrix(anim.rotations[:, anim.bone_names.index(bone)])
    step = np.einsum("fji,fjk->fik", R[:-1], R[1:])
    return float(np.percentile(np.abs(np.diff((step[:, 0, 2] - step[:, 2, 0]) / 2.0)), 95))


def test_the_limb_ik_adds_no_roll_jitter_to_nearly_straight_limbs(walk_full):
    """Smoothness: walking arms hang nearly straight and beyond the avatar's reach; the swivel
    measured from the avatar's axis then held the mapping's axis change and the upper arm's roll
    jittered at 2.7-3.2x the rotation copy's. Measured from the user's own axis, with the hinge axis
    weighing as a 10 cm offset: 1.50x measured, the thighs 1.02x."""
    rec, _ = walk_full
    user = calibrate_user(rec)
    avatar = rt.procedural_avatar()
    ego, rot = (pl.retarget(rec, user, avatar, m) for m in ("egocentric", "rotations"))
    for bone in ("upperarm_l", "upperarm_r", "thigh_l", "thigh_r"):
        assert _roll_jitter(ego, bone) <= 1.75 * _roll_jitter(rot, bone), bone
