"""A hand nearer its shoulder than the arm can fold (`user_animation.ELBOW_FLEX_MAX`): the
estimated shoulder turns away from it, as a far hand turns it toward it. A real Beat Saber
player (simsaber) holds the controllers beside the head on a third of the frames, 5-10 cm from
the estimated shoulders: the two-bone elbow was folded shut there (180 degrees), on the
shoulder-wrist line, which turns as fast as the hand moves over its few centimetres, and the
rotation copy carried that whirl onto the avatar's wrist (1.39x the controllers')."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bodycal_addon.body.skeleton import JOINT_INDEX as JI
from bodycal_addon.calibration import calibrate_user
from bodycal_addon.core import paths
from bodycal_addon.recording import io as recording_io
from bodycal_addon.recording.filters import DEFAULT_FILTER, filter_recording
from bodycal_addon.retarget import lower_body
from bodycal_addon.retarget import user_animation as ua

FPS = 90.0


def _flexion_deg(joints: np.ndarray, s: str) -> np.ndarray:
    sh, el, wr = (joints[:, JI[f"{j}_{s}"]] for j in ("shoulder", "elbow", "wrist"))
    u, f = el - sh, wr - el
    c = np.einsum("fi,fi->f", u, f) / (np.linalg.norm(u, axis=1) * np.linalg.norm(f, axis=1))
    return np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))


def _acceleration_p95(x: np.ndarray, fps: float) -> float:
    return float(np.percentile(np.linalg.norm(np.diff(x, 2, axis=0), axis=1) * fps * fps, 95))


@pytest.fixture(scope="module")
def saber():
    rec = recording_io.load_recording(paths.data_dir() / "real_vr" / "beat_saber" / "simsaber_sample.bsor")
    user = calibrate_user(rec)
    full = lower_body.complete(filter_recording(rec, DEFAULT_FILTER), user)
    return rec, user, full, ua.animate_user(full, user)


def test_a_hand_at_its_shoulder_turns_the_shoulder_away(saber, monkeypatch):
    """Before: the elbow folded past 150 degrees on 45 / 42 % of the frames (l / r; 180 at the p95)
    and the estimated elbows accelerated 1.8 / 1.6x the wrists (p95); now 23 / 21 % (the
    shoulder's turn stops at SHOULDER_REACH; p95 158 / 157 degrees) and 1.5 / 1.3x. The wrists
    stay on the controllers (bit for bit) and the shoulders turn about the trunk's shoulders'
    middle (as far from it as the trunk carries them)."""
    rec, user, full, pose = saber
    monkeypatch.setattr(ua.UserAnimator, "_fold_distance", lambda self, s: 0.0)  # no fold limit (before)
    shut = ua.animate_user(full, user)
    limit = math.degrees(ua.ELBOW_FLEX_MAX)
    J, R = pose.joints, shut.joints
    monkeypatch.setattr(ua, "SHOULDER_REACH", 0.0)
    rigid = ua.animate_user(full, user).joints  # the shoulders the trunk carries, unturned
    mid = 0.5 * (rigid[:, JI["shoulder_l"]] + rigid[:, JI["shoulder_r"]])
    for s in "lr":
        before, after = _flexion_deg(R, s), _flexion_deg(J, s)
        assert (before > limit + 1.0).mean() > 0.4 and np.percentile(before, 95) > 179.0, s
        assert (after > limit + 1.0).mean() < 0.25 and np.percentile(after, 95) < 160.0, s
        elbow_before, elbow_after = (_acceleration_p95(P[:, JI[f"elbow_{s}"]], rec.fps) for P in (R, J))
        assert elbow_after < 0.85 * elbow_before, (s, elbow_before, elbow_after)
        assert np.array_equal(J[:, JI[f"wrist_{s}"]], R[:, JI[f"wrist_{s}"]])
        row = JI[f"shoulder_{s}"]
        moved = ~np.all(J[:, row] == R[:, row], axis=1)
        assert moved.mean() > 0.2, s
        assert np.allclose(np.linalg.norm(J[moved, row] - mid[moved], axis=1),
                           np.linalg.norm(rigid[moved, row] - mid[moved], axis=1), atol=1e-9)
