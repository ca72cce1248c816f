"""The hands' self-contacts with a kit of HMD and two controllers (DESIGN.md §3 "The device ladder",
§6b, §7 "Three points"): what opened them on the synthetic performer's contact motions, each
measured against the performer's own truth: the hands smoothed in the room with no contact term (a
clap rounded off), and the calibration's estimated pelvis and feet carried down with the head while
the performer crouched to touch a knee or an ankle (the legs' surface elsewhere)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from bodycal_addon.body.skeleton import JOINT_INDEX as JI
from bodycal_addon.calibration import calibrate_user
from bodycal_addon.core import transforms as tf
from bodycal_addon.recording.filters import DEFAULT_FILTER, filter_recording
from bodycal_addon.retarget import lower_body
from bodycal_addon.retarget.lower_body import body_path, touch
from bodycal_addon.retarget.user_animation import animate_user
from bodycal_dev import synthetic

THREE = ("head", "hand_l", "hand_r")


def _three(rec):
    keep = [i for i, d in enumerate(rec.devices) if d.role in THREE]
    return replace(rec, devices=[rec.devices[i] for i in keep], positions=rec.positions[:, keep],
                   rotations=rec.rotations[:, keep], valid=rec.valid[:, keep])


@pytest.fixture(scope="module")
def session():
    """The minimal protocol (HMD, controllers, pelvis and feet) with a clap, and its truth."""
    perf = synthetic.make_performer(height=1.75, build="average", seed=1)
    rec, truth = synthetic.record_session(perf, profile="minimal", motions=("clap",), seed=1)
    return perf, rec, truth


def _hands_apart(rec, frames) -> np.ndarray:
    roles = [d.role for d in rec.devices]
    return np.linalg.norm(rec.positions[frames, roles.index("hand_l")] - rec.positions[frames, roles.index("hand_r")],
                          axis=1)


def test_a_clap_with_three_devices_is_not_rounded_off_by_the_filter(session):
    """No pelvis tracker, no body part to smooth the hands on: they are smoothed in the room, with
    the contact term still (before: the controllers 15 mm further apart at the claps than recorded,
    the avatar's clap open 13.4 mm p95)."""
    _, rec, truth = session
    (clap,) = [c for c in truth.contacts if c["motion"] == "clap"]
    frames = np.flatnonzero(clap["frames"])
    three = _three(rec)
    smoothed = filter_recording(three, DEFAULT_FILTER)
    recorded = _hands_apart(three, frames)
    opened = _hands_apart(smoothed, frames) - recorded
    assert np.median(np.abs(opened)) < 2.0e-3 and np.percentile(np.abs(opened), 95) < 4.0e-3
    # as with a pelvis tracker (the hands smoothed on the body, the same contact term)
    with_pelvis = _hands_apart(filter_recording(rec, DEFAULT_FILTER), frames) - recorded
    assert abs(np.median(opened) - np.median(with_pelvis)) < 1.5e-3
    assert "the hands with the contact term" in smoothed.notes[-1]


def test_touching_the_knees_and_ankles_with_three_devices_places_the_legs(session):
    """The performer crouches to touch a knee, an ankle, a sole: the estimated feet stay on the floor
    where they stood and the estimated pelvis where it stood, so the touches land on the legs
    (before: each ankle 1.04 m up in its foot's frame, the knees 46 cm off, a thigh of 6 cm)."""
    perf, rec, _ = session
    user = calibrate_user(_three(rec))
    for s in "lr":
        assert np.linalg.norm(user.joints[f"ankle_{s}"].world - perf.rest[f"ankle_{s}"]) < 0.040
        assert np.linalg.norm(user.joints[f"knee_{s}"].world - perf.rest[f"knee_{s}"]) < 0.025
        for bone in (f"thigh_{s}", f"shin_{s}"):
            true = np.linalg.norm(perf.rest[f"{'knee' if bone.startswith('thigh') else 'ankle'}_{s}"]
                                  - perf.rest[f"{'hip' if bone.startswith('thigh') else 'knee'}_{s}"])
            assert abs(user.bones[bone].length - true) < 0.025, bone
    # what stands still under a crouching performer is what the pelvis and hips were before
    for j in ("pelvis", "hip_l", "hip_r"):
        assert np.linalg.norm(user.joints[j].world - perf.rest[j]) < 0.010


@pytest.fixture(scope="module")
def belly():
    """The minimal protocol with a hand on the belly and one on the head (the body swaying under
    each), HMD and controllers kept; its truth and the three-point user."""
    perf = synthetic.make_performer(height=1.75, build="average", seed=1)
    rec, truth = synthetic.record_session(perf, profile="minimal", motions=("hand_on_belly", "hand_on_head"), seed=1)
    three = _three(rec)
    return three, truth, calibrate_user(three)


def test_a_hand_resting_on_the_belly_holds_the_estimated_pelvis(belly):
    """The performer sways over a pelvis that stays, a hand on the belly: the estimated pelvis stays
    with the hand (before: it swayed with the head, 26 mm from the performer's median, the avatar's
    palm 30 mm off the belly p95). A hand on the head rests nowhere near the lower trunk: there the
    pelvis is the head's, as without the hold."""
    rec, truth, user = belly
    full = lower_body.complete(filter_recording(rec, DEFAULT_FILTER), user)
    pose = animate_user(full, user)
    err = {}
    for c in truth.contacts:
        idx = np.flatnonzero(c["frames"])
        err[c["motion"]] = np.linalg.norm(pose.joints[idx, JI["pelvis"]] - truth.joints[idx, JI["pelvis"]], axis=1)
    assert np.median(err["hand_on_belly"]) < 6e-3 and np.percentile(err["hand_on_belly"], 95) < 10e-3
    # the hand on the head holds nothing: the pelvis sways with the head as the body path puts it
    (head,) = [c for c in truth.contacts if c["motion"] == "hand_on_head"]
    idx = np.flatnonzero(head["frames"])
    shape = lower_body.LowerBodyShape.of(user)
    hp, hq, _ = full.pose("head")
    path = body_path.offline_path(shape, full.time, hp, tf.quat_to_matrix(hq))
    held = touch.hold_pelvis(shape, full.time, path, lower_body.estimate.wrists(full, shape))
    assert np.array_equal(held.pelvis[idx], path.pelvis[idx])
    assert np.ptp(path.pelvis[idx, 1]) > 0.03  # it does sway there


def test_a_body_swaying_over_its_planted_feet_does_not_step_them(belly):
    """The performer sways its trunk over planted feet, a hand on the head (the skull base 7 cm back
    and forth over 4 s), and bows over them in the calibration to touch its knees, ankles and soles:
    its feet never move. The estimated mass centre, carried with the head, sways 7 cm back; a
    standing body's stands over the rear of its feet (the synthetic performer's over its ankles),
    so the support reaches back to the ankles: the estimated feet stay where the performer's stand
    through the sway (before: a balance step put the left foot 55 mm behind the performer's, where
    the hands-on-thighs squat then found its thigh)."""
    rec, truth, user = belly
    full = lower_body.complete(filter_recording(rec, DEFAULT_FILTER), user)
    pose = animate_user(full, user)
    (head,) = [c for c in truth.contacts if c["motion"] == "hand_on_head"]
    idx = np.flatnonzero(head["frames"])
    around = np.arange(idx[0] - 90, idx[-1] + 90)  # the sway's first and last second too
    for s in "lr":
        feet = full.pose(f"foot_{s}")[0][around]
        assert np.abs(feet - feet[0]).max() < 1e-9, s
        ankle = np.linalg.norm(pose.joints[around, JI[f"ankle_{s}"]] - truth.joints[around, JI[f"ankle_{s}"]], axis=1)
        assert ankle.max() < 0.04, s


def test_a_hand_passing_in_front_of_the_belly_does_not_hold_the_pelvis():
    """A rest is a hand still in front of the lower trunk for a while: a hand swinging through the
    zone, or held still out of it, leaves the head's pelvis as it is."""
    fps, n = 90.0, 540
    t = np.arange(n) / fps
    neck = np.stack([np.zeros(n), 0.04 * np.sin(2 * np.pi * 0.25 * t), np.full(n, 1.56)], axis=1)
    shape = _Shape(stature=1.75)
    level = np.broadcast_to(np.eye(3), (n, 3, 3))
    path = body_path.BodyPath(neck, np.zeros(n), np.zeros(n), neck - [0.0, 0.0, 0.63], level, np.zeros(n),
                              np.zeros((n, 2)))
    fwd = np.array([0.0, 1.0, 0.0])  # body_axes(0): y forward
    still = np.broadcast_to(np.array([0.0, 0.0, 0.93 + 0.15]) + 0.12 * fwd, (n, 3))
    swinging = still + np.stack([0.3 * np.sin(2 * np.pi * 1.0 * t), np.zeros(n), np.zeros(n)], axis=1)
    raised = still + [0.0, 0.0, 0.45]  # at the chest: not the lower trunk
    for wrist in (swinging, raised):
        held = touch.hold_pelvis(shape, t, path, np.stack([wrist, wrist + [0.4, 0.0, 0.0]], axis=1))
        assert np.array_equal(held.pelvis, path.pelvis)
    held = touch.hold_pelvis(shape, t, path, np.stack([still, still + [0.4, 0.0, 0.0]], axis=1))
    middle = slice(int(0.5 * fps), n - int(0.5 * fps))
    assert np.ptp(held.pelvis[middle, 1]) < 0.1 * np.ptp(path.pelvis[middle, 1])


class _Shape:
    """What `touch.hold_pelvis` reads of a `LowerBodyShape`."""

    def __init__(self, stature: float):
        self.stature = stature


@pytest.fixture(scope="module")
def thighs():
    """The minimal protocol with the leaning squat, the hands resting on the thighs (the feet planted
    throughout), HMD and controllers kept; its truth and the three-point user."""
    perf = synthetic.make_performer(height=1.75, build="average", seed=1)
    rec, truth = synthetic.record_session(perf, profile="minimal", motions=("hands_on_thighs",), seed=1)
    three = _three(rec)
    return three, truth, calibrate_user(three)


def test_a_squat_with_the_hands_on_the_thighs_keeps_the_feet_where_they_stand(thighs):
    """Going down into a squat the estimated pelvis goes back as the trunk leans (and first forward,
    the lean lagging the head): the body's mass centre stays over the feet, and the performer's feet
    stay planted. So do the estimated ones, and the thighs come under the resting palms (before: the
    right foot stepped 12 cm back, led by the pelvis's backward speed, its knee and thigh lower, the
    palm 67 mm off the thigh's skin)."""
    rec, truth, user = thighs
    full = lower_body.complete(filter_recording(rec, DEFAULT_FILTER), user)
    pose = animate_user(full, user)
    for c in (c for c in truth.contacts if c["motion"] == "hands_on_thighs"):
        idx, s = np.flatnonzero(c["frames"]), c["effector"][-1]
        ankle = np.linalg.norm(pose.joints[idx, JI[f"ankle_{s}"]] - truth.joints[idx, JI[f"ankle_{s}"]], axis=1)
        assert ankle.max() < 0.03, s
        palm = truth.contact_tracks[(c["effector"], c["target"])][0][idx]
        hip, knee = pose.joints[idx, JI[f"hip_{s}"]], pose.joints[idx, JI[f"knee_{s}"]]
        along = np.clip(np.einsum("fi,fi->f", palm - hip, knee - hip) / np.einsum("fi,fi->f", knee - hip, knee - hip),
                        0.0, 1.0)
        bone = user.bones[f"thigh_{s}"]
        skin = np.linalg.norm(palm - (hip + along[:, None] * (knee - hip)), axis=1) - (
            bone.radius_head + along * (bone.radius_tail - bone.radius_head))
        assert np.median(skin) < 0.04, s  # the trunk held rigid (4 cm shorter flexed) leaves the rest


def test_hands_resting_on_the_thighs_lift_the_pelvis_until_the_thighs_meet_them(thighs):
    """A leaning squat curls the spine: the pelvis is 4 cm nearer the skull base than the trunk held
    rigid puts it, and the thighs below the palms resting on them. The estimated pelvis rises along
    the trunk until the thighs meet the palms (before: the pelvis 39 mm from the performer's, the
    palms 30 and 23 mm above the thighs' skin). Hands still elsewhere lift nothing."""
    rec, truth, user = thighs
    full = lower_body.complete(filter_recording(rec, DEFAULT_FILTER), user)
    pose = animate_user(full, user)
    shape = lower_body.LowerBodyShape.of(user)
    for c in (c for c in truth.contacts if c["motion"] == "hands_on_thighs"):
        idx, s = np.flatnonzero(c["frames"]), c["effector"][-1]
        pelvis = np.linalg.norm(pose.joints[idx, JI["pelvis"]] - truth.joints[idx, JI["pelvis"]], axis=1)
        assert np.median(pelvis) < 0.03
        palm = truth.contact_tracks[(c["effector"], c["target"])][0][idx]
        hip, knee = pose.joints[idx, JI[f"hip_{s}"]], pose.joints[idx, JI[f"knee_{s}"]]
        along = np.clip(np.einsum("fi,fi->f", palm - hip, knee - hip) / np.einsum("fi,fi->f", knee - hip, knee - hip),
                        0.0, 1.0)
        skin = np.linalg.norm(palm - (hip + along[:, None] * (knee - hip)), axis=1) - (
            shape.thigh_radii[0] + along * (shape.thigh_radii[1] - shape.thigh_radii[0]))
        assert np.median(np.abs(skin)) < 0.015, s
    # the hands hanging still at the sides while the performer stands (the reference pose) lift nothing
    hp, hq, _ = full.pose("head")
    path = body_path.offline_path(shape, full.time, hp, tf.quat_to_matrix(hq))
    stood = slice(0, int(0.5 * rec.fps))
    lifted = touch.rest_on_thighs(shape, full.time, path, lower_body.estimate.palms(full, shape),
                                  lambda p: lower_body.estimate._stand(shape, rec.fps, p))
    assert np.array_equal(lifted.pelvis[stood], path.pelvis[stood])
