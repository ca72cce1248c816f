"""Six devices with the controller pivots and touches (DESIGN.md §3, "Touches with six devices"), on
recordings an outside tool made from real motion (`evaluation/touching.py`: the clip's skeleton
pivots each controller's tip on a table, then touches the wrists, elbows, knees and ankles on the
skin with it, a person's scatter in every placement; the tip is a point of the controller the
engine is not told). 05_06 (CMU subject 5) is held out of the default benchmarks."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from outside_takes import clip_performer, outside_recording

from bodycal_addon.calibration import calibrate_user
from bodycal_addon.calibration import touches as calibration_touches
from bodycal_addon.calibration.common import Session, State
from bodycal_addon.recording.model import Segment

DANCE = "05_06_dance.bvh"
WALK = "02_01_walk.bvh"
TARGET = ("hip", "knee", "ankle", "shoulder", "elbow")


@pytest.fixture(scope="module")
def performers(data_dir):
    return {DANCE: clip_performer(data_dir, DANCE, "cmu_bvh_held_out"), WALK: clip_performer(data_dir, WALK)}


@pytest.fixture(scope="module")
def recorded(performers, tmp_path_factory):
    """(recording, capture) of a clip's session, with or without the touches, made once per module
    (a test that changes the recording changes a copy)."""
    made = {}

    def get(clip: str, seed: int, touches: bool = False):
        key = (clip, seed, touches)
        if key not in made:
            folder = tmp_path_factory.mktemp("six")
            made[key] = outside_recording(performers[clip], folder, "six", seed, touches=touches)
        rec, cap = made[key]
        return copy.copy(rec), cap

    return get


def errors_mm(user, cap) -> dict[str, float]:
    truth = cap.truth()
    ref = int(round(user.reference_time * truth["fps"]))
    return {n: 1000 * float(np.linalg.norm(user.joints[n].world - truth["positions"][ref, k]))
            for k, n in enumerate(truth["joints"]) if n in user.joints}


def worst(err: dict[str, float]) -> tuple[str, float]:
    name = max((f"{j}_{s}" for j in TARGET for s in "lr"), key=lambda n: err[n])
    return name, round(err[name], 1)


@pytest.mark.parametrize("clip", (WALK, DANCE))
def test_the_touches_bring_every_hip_knee_ankle_shoulder_and_elbow_within_20_mm(recorded, clip):
    """Session 3 of both clips without the touches: 02_01's left knee 29.9 mm off, 05_06's left
    ankle 32.7 (the ankle's height and the knee's place between hip and ankle, which a foot tracker
    alone does not observe). With the pivots and the touches every one of these joints is within the
    issue's 20 mm, and the report says what measured them."""
    before, cap0 = recorded(clip, 3)
    after, cap1 = recorded(clip, 3, touches=True)
    assert worst(errors_mm(calibrate_user(before), cap0))[1] > 25.0  # the premise
    user = calibrate_user(after)
    assert worst(errors_mm(user, cap1))[1] <= 20.0, worst(errors_mm(user, cap1))
    cal = user.calibration
    assert not cal["warnings"]
    for s in "lr":
        assert {f"pivot_tip_{s}", f"ankle_{s}", f"wrist_{s}", f"knee_{s} touches", f"elbow_{s} touches"} \
            <= set(cal["steps_used"])
        assert "knee touches" in cal["defaulted"][f"knee_{s}"] and "elbow touches" in cal["defaulted"][f"elbow_{s}"]
        assert f"ankle_{s}" not in cal["defaulted"] and f"controller_tip_{s}" not in cal["defaulted"]
        assert cal["quality"][f"swing_hip_{s}"]["height_from_legs_mm"] != 0.0


def test_the_pivot_finds_the_controller_tip_the_engine_is_not_told(recorded):
    """The tip is a point of the controller past the thumb, fixed in the hand for the session; the
    capture straps the controller at a random angle, so its place in the controller's frame is
    unknown (7-13 cm from the origin). The pivot finds it within a millimetre here (0.3 mm; 1.6 mm
    at most over 36 pivots, its standard error 0.7-1.0 mm)."""
    rec, cap = recorded(DANCE, 1, touches=True)
    session, state = Session(rec), State()
    calibration_touches.controller_tips(session, state)
    for s in "lr":
        mount = next(m for m in cap.mounts if m.role == f"hand_{s}")
        truth = mount.rotation.T @ (cap.session.notes["controller_tip_hand"][s] - mount.offset)
        found = state.extra["controller_tip_local"][s]
        assert np.linalg.norm(found - truth) < 1e-3, (s, found, truth)
        assert session.quality[f"pivot_tip_{s}"]["tip_se_mm"] < calibration_touches.PIVOT_MAX_SE_MM


def test_a_pivot_that_hardly_turns_is_refused_and_the_touches_say_their_tip_was_assumed(recorded):
    """The left pivot's segment moved onto the `stand` step, where the controller hangs still: the
    fit cannot fix a tip, the step is left out with one line saying what to redo, and the left
    controller's touches are read at the assumed tip (reported among the defaults)."""
    rec, _ = recorded(WALK, 0, touches=True)
    stand = rec.segments_of("stand")[0]
    rec.segments = [Segment("pivot_tip_l", stand.start, stand.end) if s.step == "pivot_tip_l" else s
                    for s in rec.segments]
    cal = calibrate_user(rec).calibration
    line = next(w for w in cal["warnings"] if w.startswith("pivot_tip_l not used"))
    assert "circle the controller" in line, line
    assert "pivot_tip_l" in cal["missing"] and "pivot_tip_r" in cal["steps_used"]
    assert "controller_tip_l" in cal["defaulted"] and "controller_tip_r" not in cal["defaulted"]


def test_without_the_touches_six_devices_calibrate_as_before_and_say_what_was_assumed(recorded):
    """The touches are optional: a six-device recording without them takes the knees at the
    thigh : shin ratio, the ankles behind the foot trackers, the elbows from the flex step and the
    ratio, and says so."""
    rec, _ = recorded(WALK, 0)
    cal = calibrate_user(rec).calibration
    for s in "lr":
        assert "thigh : shin ratio" in cal["defaulted"][f"knee_{s}"]
        assert "behind the foot tracker" in cal["defaulted"][f"ankle_{s}"]
        assert "mean of its flex step's" in cal["defaulted"][f"elbow_{s}"]
        assert f"knee_{s} touches" not in cal["steps_used"] and f"pivot_tip_{s}" not in cal["steps_used"]
        assert "height_from_legs_mm" not in cal["quality"][f"swing_hip_{s}"]


def test_the_knee_touches_measure_thigh_and_shin_and_hold_the_hips_at_the_legs_height(recorded):
    """Without a shin or thigh tracker the knee touches, taken in the foot tracker's frame, measure
    the thigh from the hip (pelvis tracker) and the shin from the ankle (foot tracker); the foot's
    swing had left this session's hips 12 and 16 mm low, the legs' reach above the ankles puts
    them within 8 mm of the clip's height (measured: 2.3 and 5.9 mm low; 7 mm at most over
    sessions 0-5 of three clips, DESIGN.md)."""
    before, _ = recorded(WALK, 3)
    rec, cap = recorded(WALK, 3, touches=True)
    user = calibrate_user(rec)
    truth = cap.truth()
    ref = int(round(user.reference_time * truth["fps"]))
    J = {n: k for k, n in enumerate(truth["joints"])}
    T = truth["positions"][ref]
    low = calibrate_user(before)
    for s in "lr":
        assert low.joints[f"hip_{s}"].world[2] - T[J[f"hip_{s}"]][2] < -0.010  # the premise
        assert abs(user.joints[f"hip_{s}"].world[2] - T[J[f"hip_{s}"]][2]) < 0.008
        q = user.calibration["quality"][f"knee_{s} touches"]
        thigh = 1000 * np.linalg.norm(T[J[f"knee_{s}"]] - T[J[f"hip_{s}"]])
        shin = 1000 * np.linalg.norm(T[J[f"ankle_{s}"]] - T[J[f"knee_{s}"]])
        assert abs(q["thigh_mm"] - thigh) < 10.0 and abs(q["shin_mm"] - shin) < 10.0, (s, q, thigh, shin)
