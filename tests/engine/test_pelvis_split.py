"""evaluation.measure.pelvis_split: the three-point bench's split of the pelvis's error (its
constant in the clip's body frame, the motion about it, and what the tail's frames are)."""

from __future__ import annotations

import numpy as np
import pytest

from evaluation import measure

FPS = 90.0


def _clip(heading_deg: float, frames: int = 180, speed: float = 1.0, turn_deg_s: float = 0.0) -> dict:
    """A clip body walking forward along `heading_deg` (turning at `turn_deg_s`), upright."""
    t = np.arange(frames) / FPS
    psi = np.radians(heading_deg + turn_deg_s * t)
    fwd = np.stack([np.cos(psi), np.sin(psi), np.zeros(frames)], 1)
    left = np.stack([-np.sin(psi), np.cos(psi), np.zeros(frames)], 1)
    up = np.array([0.0, 0.0, 1.0])
    pelvis = np.cumsum(fwd * speed / FPS, axis=0) + 0.9 * up
    body = {"pelvis": pelvis, "skull_base": pelvis + 0.55 * up}
    for s, k in (("l", 1.0), ("r", -1.0)):
        body[f"hip_{s}"] = pelvis + k * 0.09 * left
        body[f"ankle_{s}"] = body[f"hip_{s}"] - 0.82 * up
        body[f"toe_{s}"] = body[f"ankle_{s}"] + 0.14 * fwd - 0.05 * up
    return body, fwd, left


@pytest.mark.parametrize("heading", [0.0, 90.0, 205.0])
def test_a_constant_offset_in_the_body_frame_is_the_constant_whatever_the_heading(heading):
    theirs, fwd, left = _clip(heading, turn_deg_s=40.0)
    off = 0.030 * fwd - 0.012 * left + np.array([0.0, 0.0, -0.050])
    ours = {"pelvis": theirs["pelvis"] + off, "skull_base": theirs["skull_base"]}
    got = measure.pelvis_split(ours, theirs, FPS)
    assert got["offset_mm"] == pytest.approx({"forward": 30.0, "left": -12.0, "up": -50.0}, abs=0.05)
    assert got["motion_mm"]["p95"] < 0.05  # nothing moves about the constant
    assert got["tail"]["moving_share"] == 1.0 and got["tail"]["turning_share"] == 0.0  # 40 deg/s < 60


def test_the_tail_says_how_much_further_the_clips_trunk_leans_there():
    theirs, fwd, left = _clip(30.0, frames=200, turn_deg_s=90.0)
    # the clip's trunk leans 15 deg forward over frames 100-120 (its pelvis goes back under the skull
    # base), ours stays upright under it
    lean = np.zeros(200)
    lean[100:120] = np.radians(15.0)
    skull = theirs["skull_base"].copy()
    theirs["pelvis"] = skull - 0.55 * (np.cos(lean)[:, None] * np.array([0.0, 0.0, 1.0]) + np.sin(lean)[:, None] * fwd)
    for s, k in (("l", 1.0), ("r", -1.0)):
        theirs[f"hip_{s}"] = theirs["pelvis"] + k * 0.09 * left
    ours = {"pelvis": skull - np.array([0.0, 0.0, 0.55]), "skull_base": skull}
    got = measure.pelvis_split(ours, theirs, FPS)
    assert 0 < got["tail"]["frames"] <= 20  # the leaning frames only (10 % of the clip)
    assert got["tail"]["lean_forward_missed_deg"] == pytest.approx(15.0, abs=0.1)
    assert got["tail"]["tilt_left_missed_deg"] == pytest.approx(0.0, abs=0.1)
    assert got["tail"]["turning_share"] == 1.0
    assert got["offset_mm"]["forward"] == pytest.approx(0.0, abs=0.1)  # 10 % of the frames: not the constant
    assert got["motion_mm"]["p95"] == pytest.approx(0.55 * np.hypot(np.sin(np.radians(15)), 1 - np.cos(np.radians(15)))
                                                    * 1000, rel=0.01)


def test_a_bow_past_a_right_angle_is_read_past_it():
    theirs, fwd, left = _clip(0.0, frames=100, speed=0.0)
    bow = np.radians(130.0)
    theirs["skull_base"] = theirs["pelvis"] + 0.55 * (np.cos(bow) * np.array([0.0, 0.0, 1.0]) + np.sin(bow) * fwd)
    ours = {"pelvis": theirs["pelvis"] + np.array([0.0, 0.0, -0.3]), "skull_base": theirs["skull_base"]}
    got = measure.pelvis_split(ours, theirs, FPS)
    # ours: the skull base 0.3 m further above the pelvis than the clip's
    ours_lean = np.degrees(np.arctan2(0.55 * np.sin(bow), 0.55 * np.cos(bow) + 0.3))
    assert got["tail"]["lean_forward_missed_deg"] == pytest.approx(130.0 - ours_lean, abs=0.1)
    assert got["tail"]["moving_share"] == 0.0


def test_the_landings_count_is_a_plain_int_the_bench_can_print():
    """bench_three_point prints its figures with json: a numpy integer there stops the whole run."""
    import json

    t = np.arange(200) / FPS
    foot = np.zeros((200, 3))
    foot[:, 0] = np.where(t < 1.0, 0.0, np.minimum((t - 1.0) * 1.0, 0.5))  # stands, steps 0.5 m, stands
    count = measure.landings(foot, FPS)
    assert count == 1 and type(count) is int
    json.dumps({"steps": count})


def test_the_error_is_split_into_the_calibrations_length_and_the_paths_direction():
    """Our trunk 50 mm longer than the clip's (the calibration's proportions), then also leaning
    10 degrees less (the path): with the clip's trunk length the first error is gone and the second
    left whole; with the clip's trunk direction the reverse."""
    theirs, fwd, _ = _clip(120.0, frames=150, turn_deg_s=30.0)
    skull = theirs["skull_base"]
    longer = {"pelvis": theirs["pelvis"] - np.array([0.0, 0.0, 0.05]), "skull_base": skull}
    got = measure.pelvis_split(longer, theirs, FPS)["by_source"]
    assert got["path_only"]["p95"] < 0.05
    assert got["calibration_only"]["median"] == pytest.approx(50.0, abs=0.05)
    lean = np.radians(10.0)
    theirs["pelvis"] = skull - 0.55 * (np.cos(lean) * np.array([0.0, 0.0, 1.0]) + np.sin(lean) * fwd)
    got = measure.pelvis_split(longer, theirs, FPS)["by_source"]
    assert got["path_only"]["median"] == pytest.approx(0.55 * 2 * np.sin(lean / 2) * 1000, rel=1e-3)
    assert got["calibration_only"]["median"] == pytest.approx(50.0, abs=0.05)
