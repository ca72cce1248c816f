"""The default hand of a user whose kit does not measure it (no palm touches; DESIGN.md §3
"The default hand"): `defaults.hand_axes` gives the hand's direction, its palm's normal and its
thumb's side, from which the finger joints and the palm surface are laid out. Whatever way the hand
pointed at the reference moment, they are a left or a right hand, never its mirror image: on a
mirrored hand the palm mesh lies on the back of the hand, and the egocentric method maps a
touching palm through a point on the wrong side of the hand (the real Beat Saber replay's two
hands and the A-Frame grabRight take's left hand were mirrored)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from bodycal_addon.calibration import calibrate_user, defaults
from bodycal_addon.recording import io as rio
from bodycal_addon.retarget import pipeline as pl
from bodycal_dev import retarget_fixtures as rt

UP = np.array([0.0, 0.0, 1.0])
LEFT = np.array([0.0, 1.0, 0.0])
FORWARD = np.cross(LEFT, UP)  # the body frame's forward = left x up
REAL_TAKES = ("aframe_vive/tracked-recording.json", "aframe_vive/dev-recording.json", "aframe_vive/grabLeft.json",
              "aframe_vive/grabRight.json", "beat_saber/simsaber_sample.bsor", "beat_saber/xror_sample2.bsor")


def _handedness(along, n, thumb) -> float:
    """+1 for a left hand's (along, palm normal out of the palm, thumb side), -1 for a right's: a
    left hand palm down with its fingers pointing left has its thumb forward, left x down = forward."""
    return float(np.sign(np.dot(np.cross(n, along), thumb)))


@pytest.mark.parametrize("s", ["l", "r"])
def test_the_default_hand_is_a_hand_whichever_way_it_points(s):
    """The reference moment without a T-pose (three-point kits: a standing moment), the hand
    pointing anywhere (the wrist to the controller's grip): the triad keeps its side's handedness.
    Before, a thumb computed to point backward was turned forward alone, mirroring the hand (the
    palm's normal kept), for every hand pointing up, and forward with the palm toward the body."""
    session = SimpleNamespace(reference_step="standing moment", has=lambda role: True,
                              ref_pose=lambda role: (w[f"grip_{s}"], None))
    state = SimpleNamespace(palm_planes={})
    body = SimpleNamespace(left=LEFT, forward=FORWARD)
    sign = 1.0 if s == "l" else -1.0
    rng = np.random.default_rng(4)
    directions = [UP, -UP, FORWARD, -FORWARD, LEFT, -LEFT] + list(rng.normal(size=(60, 3)))
    for d in directions:
        d = np.asarray(d, float) / np.linalg.norm(d)
        if abs(d @ LEFT) > 0.999:  # along the palm's assumed normal (the body's left): no palm
            continue
        w = {f"wrist_{s}": np.zeros(3), f"grip_{s}": 0.08 * d}
        along, n, thumb = defaults.hand_axes(session, state, body, s, w)
        assert _handedness(along, n, thumb) == sign, (s, d.round(2))


@pytest.mark.parametrize("take", REAL_TAKES)
def test_a_real_takes_default_palm_is_on_the_palm_side_of_the_hand(data_dir, take):
    """Calibrated from the real three-point takes: each hand's palm centre (the egocentric hand's
    point, `Egocentric.palm_local`, in the canonical hand frame) lies on the same side of the hand
    as the avatar's, which comes from the avatar's own mesh."""
    rec = rio.load_recording(data_dir / "real_vr" / take)
    prepared = pl.prepare_recording(rec.window(0, 40), calibrate_user(rec), rt.procedural_avatar(scale=1.0),
                                    "egocentric")
    method = prepared.solver.impl
    for s, (user_palm, avatar_palm) in method.palm_local.items():
        assert np.sign(user_palm[2]) == np.sign(avatar_palm[2]), (take, s, user_palm, avatar_palm)
