"""Quality metrics (DESIGN.md §7) on bodies whose geometry is known."""

import numpy as np
import pytest
import retarget_bodies as rb

from bodycal_addon.output import metrics
from bodycal_addon.retarget import egocentric as eg


@pytest.fixture(scope="module")
def posed():
    model = rb.make_body_model()
    rest = {k: v.world[None] for k, v in model.joints.items()}
    rights = {b: i.right[None] for b, i in model.bones.items()}
    return model, eg.pose_surface(model, rest, rb.bone_frames(rest, rights))


def test_signed_distances_of_known_points(posed):
    model, surf = posed
    ids = surf.element_ids
    thigh = ids.index("capsule:thigh_l")
    hip, knee = model.world("hip_l"), model.world("knee_l")
    mid = 0.5 * (hip + knee)
    r_mid = 0.5 * sum(rb.RADII["thigh"])
    side = np.cross(knee - hip, [0.0, 1.0, 0.0])
    side /= np.linalg.norm(side)
    torso = ids.index("mesh:torso")
    tri = surf.tri[0, surf.mesh_slices[0][0] + 4]
    n = surf.tri_normal[0, surf.mesh_slices[0][0] + 4]
    c = tri.mean(axis=0)
    skull = ids.index("sphere:skull")
    pts = np.stack([mid + (r_mid + 0.02) * side, mid + (r_mid - 0.01) * side, c + 0.03 * n, c - 0.005 * n,
                    surf.sph_center[0, 0] + [0.0, 0.0, 0.09 + 0.04]])[None]
    d = metrics.signed_distances(pts, surf)
    assert d[0, 0, thigh] == pytest.approx(0.02, abs=1e-9)
    assert d[0, 1, thigh] == pytest.approx(-0.01, abs=1e-9)
    assert d[0, 2, torso] == pytest.approx(0.03, abs=1e-9)
    assert d[0, 3, torso] == pytest.approx(-0.005, abs=1e-9)
    assert d[0, 4, skull] == pytest.approx(0.04, abs=1e-9)
    # Far behind an open crude mesh is not inside the body: the knee above its own sole.
    sole = ids.index("mesh:sole_l")
    above = metrics.signed_distances(model.world("knee_l")[None, None], surf)[0, 0, sole]
    assert above > 0.3


def test_contact_gap_ignores_the_target_own_chain(posed):
    model, surf = posed
    wrist = model.world("wrist_l")[None, None]
    # The wrist sits inside its own forearm capsule: without the own-chain exclusion the gap < 0.
    assert metrics.contact_gap(wrist, surf)[0, 0] < 0
    gap = metrics.contact_gap(wrist, surf, ["wrist_l"])[0, 0]
    d = metrics.signed_distances(wrist, surf)[0, 0]
    ids = surf.element_ids
    allowed = [i for i, e in enumerate(ids) if e not in eg.own_chain_elements("wrist_l")]
    assert gap == pytest.approx(d[allowed].min())
    assert gap > 0  # the arm hangs beside the thigh, not in it


def test_floor_sliding_reach_and_stats():
    planted = np.array([True, True, False, True, True])
    foot = np.zeros((5, 2, 3))
    foot[:, 0, 2] = [0.01, 0.0, 0.2, -0.004, 0.002]
    foot[:, 1, 2] = 0.05
    np.testing.assert_allclose(metrics.floor_error(foot, planted), [0.01, 0.0, np.nan, -0.004, 0.002])
    point = np.zeros((5, 3))
    point[:, 0] = [0.0, 0.003, 0.5, 0.5, 0.501]
    np.testing.assert_allclose(metrics.foot_sliding(point, planted), [0.003, np.nan, np.nan, 0.001], atol=1e-12)
    s = metrics.stats_mm(metrics.foot_sliding(point, planted))
    assert s["count"] == 2 and s["max"] == pytest.approx(3.0) and s["median"] == pytest.approx(2.0)
    assert metrics.stats_mm([np.nan])["count"] == 0
    np.testing.assert_allclose(metrics.reach_error(np.zeros((2, 3)), [[0, 0.003, 0.004], [0, 0, 0]]), [0.005, 0])
    err = metrics.joint_centre_error({"knee_l": [0, 0, 0.01], "hip_l": [0, 0, 0]}, {"knee_l": [0, 0, 0]})
    assert err == {"knee_l": pytest.approx(0.01)}


def test_floor_travel_is_the_longest_skate_in_one_stay_on_the_floor():
    """Held on the floor (2.5 mm up, within ON_FLOOR of the lowest) while moving 10 cm: 100 mm; the
    same move lifted 2 cm counts nothing; two stays are not added; a point never down twice: 0."""
    point = np.zeros((40, 3))
    point[10:20, 0] = np.linspace(0.0, 0.1, 10)  # skates 10 cm in its first stay
    point[20:, 0] = 0.1
    point[10:20, 2] = 0.0025
    point[25:30, 2] = 0.02  # lifted
    point[25:30, 0] = np.linspace(0.1, 0.4, 5)  # moves 30 cm in the air
    point[30:, 0] = 0.4
    point[33:36, 0] = [0.41, 0.42, 0.43]  # a second, shorter skate: 3 cm there and 3 back
    assert metrics.floor_travel_mm(point) == pytest.approx(100.0)
    point[10:20, 2] = 0.02
    assert metrics.floor_travel_mm(point) == pytest.approx(60.0)
    assert metrics.floor_travel_mm(np.c_[np.arange(5.0), np.zeros(5), np.arange(5.0)]) == 0.0


def test_planted_frames_need_a_low_and_slow_foot():
    t = np.arange(10)
    point = np.zeros((10, 3))
    point[5:, 0] = (t[5:] - 5) * 0.01  # 0.9 m/s at 90 Hz from frame 5 on
    point[:2, 2] = 0.3  # lifted at first
    planted = metrics.planted_frames(point)
    assert list(planted) == [False, False, True, True, True, True, False, False, False, False]
