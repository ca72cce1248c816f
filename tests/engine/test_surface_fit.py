"""The avatar calibration's small fits (bodycal_addon/avatar/surface_fit.py) on exact data."""

import numpy as np
import pytest

from bodycal_addon.avatar import surface_fit as sf


def _ring(centre, radius, n=12):
    a = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return np.asarray(centre) + radius * np.stack([np.cos(a), np.sin(a)], -1)


def test_cross_section_finds_an_off_bone_centre_and_rejects_a_stray_hit():
    pts = _ring([0.0, -0.022], 0.08)
    pts[3] *= 1.6  # a ray that went through a gap and hit the other leg
    (c,), (r,), (keep,) = sf.cross_sections(pts[None])
    np.testing.assert_allclose(c, [0.0, -0.022], atol=1e-9)
    assert abs(r - 0.08) < 1e-9 and not keep[3] and keep.sum() == 11


def test_a_thigh_whose_front_bulges_keeps_its_front_in_the_fit():
    # The shared child avatar's left thigh at half its length (rest pose): round within 1 mm but its front
    # (the quadriceps, 270-300 deg) 5-8 mm beyond the circle through the rest, its inner front 4 mm
    # under it. The MAD of a ring that round dropped the front, and a palm on the thigh sank ~8 mm
    # into the skin; all of it is the thigh's skin, and the circle is every hit's.
    bulge = np.array([-1.0, -0.6, 0.5, 0.9, -0.3, 0.6, 0.0, -3.7, 1.6, 7.8, 7.7, 2.9]) / 1000
    a = np.linspace(0, 2 * np.pi, 12, endpoint=False)
    pts = np.array([0.002, -0.012]) + (0.056 + bulge)[:, None] * np.stack([np.cos(a), np.sin(a)], -1)
    (c,), (r,), (keep,) = sf.cross_sections(pts[None])
    assert keep.all()
    (c_all,), _ = sf._weighted_circles(pts[None], np.ones((1, 12)))
    np.testing.assert_allclose(c, c_all, atol=1e-12)
    assert r == pytest.approx(np.linalg.norm(pts - c_all, axis=1).mean(), abs=1e-12)
    front = c + r * np.array([0.0, -1.0])  # the circle's front, against the skin hit there
    assert np.linalg.norm(pts[9] - front) < 0.005


def test_cross_section_keeps_the_bone_inside_its_capsule():
    (c,), (r,), _ = sf.cross_sections(_ring([0.05, 0.0], 0.04)[None])  # a fit that would leave the bone outside
    assert np.linalg.norm(c) <= sf.MAX_AXIS_OFFSET * 0.04 + 1e-12 and r > 0.04


def test_line_ends_carry_a_taper_to_the_joints_but_not_a_wild_slope():
    t = np.array([0.3, 0.5, 0.7])
    centres = np.array([[0.0, -0.01], [0.0, -0.02], [0.0, -0.03]])
    head, tail = sf.linear_offsets(t, centres, extend=1.0)
    np.testing.assert_allclose(head, [0.0, 0.005], atol=1e-12)  # the line, at the joints
    np.testing.assert_allclose(tail, [0.0, -0.045], atol=1e-12)
    rh, rt = sf.linear_radii(t, np.array([0.082, 0.077, 0.065]), extend=1.0)  # a thigh tapering to the knee
    assert rh > 0.082 and rt < 0.065
    # two close stations a few mm apart would extrapolate to a huge slope: bounded by their spread
    rh, rt = sf.linear_radii(np.array([0.45, 0.55]), np.array([0.010, 0.012]), extend=1.0)
    assert rh == 0.008 and rt == 0.014
    assert sf.linear_radii(np.array([0.3, 0.7]), np.array([0.01, 0.03]), extend=1.0)[0] >= 0.005  # never under half
    # a phalanx (extend 0): clamped to the stations' range
    assert sf.linear_radii(t, np.array([0.012, 0.010, 0.008])) == (0.012, 0.008)
