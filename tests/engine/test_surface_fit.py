"""The avatar calibration's small fits (bodycal_addon/avatar/surface_fit.py) on exact data."""

import numpy as np

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
