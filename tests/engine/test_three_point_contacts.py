"""The hands' self-contacts with a kit of HMD and two controllers (DESIGN.md §3 "The device ladder",
§6b, §7 "Three points"): what opened them on the synthetic performer's contact motions, each
measured against the performer's own truth: the hands smoothed in the room with no contact term (a
clap rounded off), and the calibration's estimated pelvis and feet carried down with the head while
the performer crouched to touch a knee or an ankle (the legs' surface elsewhere)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from bodycal_addon.calibration import calibrate_user
from bodycal_addon.recording.filters import DEFAULT_FILTER, filter_recording
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
