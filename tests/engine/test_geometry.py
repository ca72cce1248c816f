"""Robust fits (bodycal_addon.core.geometry): exact on exact points, robust to outliers with the 2-sigma
pass, and a clear BodyCalError on data that cannot determine the fit."""

import numpy as np
import pytest

from bodycal_addon.core import geometry as geo
from bodycal_addon.core.errors import BodyCalError

rng = np.random.default_rng(3)


def _random_rotation():
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def _arc(n, centre, radius, axis_rot, a0=0.0, a1=2.0944):
    t = np.linspace(a0, a1, n)
    local = np.column_stack([radius * np.cos(t), radius * np.sin(t), np.zeros(n)])
    return centre + local @ axis_rot.T


def _cap(n, centre, radius, max_polar=1.0472):
    """Points on a spherical cap (a limb swinging below the horizontal)."""
    az = rng.uniform(0, 2 * np.pi, n)
    pol = rng.uniform(0, max_polar, n)
    d = np.column_stack([np.sin(pol) * np.cos(az), np.sin(pol) * np.sin(az), -np.cos(pol)])
    return centre + radius * d


def test_plane_exact_and_normal():
    rot = _random_rotation()
    pts = rng.uniform(-1, 1, (50, 2))
    p = np.column_stack([pts, np.zeros(50)]) @ rot.T + [1, 2, 3]
    fit = geo.fit_plane(p)
    assert fit.rms < 1e-12
    assert abs(abs(fit.normal @ rot[:, 2]) - 1) < 1e-12
    assert fit.distance(p).max() < 1e-12
    assert fit.kept == fit.of == 50


def test_plane_rejects_collinear_points():
    p = np.outer(np.linspace(0, 1, 20), [1, 2, 3])
    with pytest.raises(BodyCalError, match="line"):
        geo.fit_plane(p, name="palms_together")


def test_circle_exact_on_exact_points():
    rot = _random_rotation()
    c = np.array([0.1, -0.2, 1.3])
    fit = geo.fit_circle(_arc(100, c, 0.25, rot))
    np.testing.assert_allclose(fit.center, c, atol=1e-9)
    assert abs(fit.radius - 0.25) < 1e-9
    assert abs(abs(fit.normal @ rot[:, 2]) - 1) < 1e-9
    assert fit.rms < 1e-9
    assert 118 < fit.range_deg < 121


def test_circle_two_sigma_pass_removes_outliers():
    rot = _random_rotation()
    c = np.array([0.0, 0.0, 1.0])
    p = _arc(300, c, 0.25, rot) + rng.normal(0, 0.001, (300, 3))
    bad = rng.choice(300, 30, replace=False)
    p[bad] += rng.normal(0, 0.08, (30, 3))
    robust = geo.fit_circle(p)
    plain = geo.fit_circle(p, robust=False)
    err_robust = np.linalg.norm(robust.center - c)
    err_plain = np.linalg.norm(plain.center - c)
    assert robust.kept < robust.of == 300
    assert not robust.inliers[bad].all()
    assert err_robust < 0.003
    assert err_robust < err_plain


def test_circle_too_little_motion_says_how_much():
    rot = _random_rotation()
    p = _arc(100, np.zeros(3), 0.25, rot, 0, np.radians(12))
    with pytest.raises(BodyCalError, match=r"flex_elbow_l: only 12 degrees of motion recorded, at least 40"):
        geo.fit_circle(p, name="flex_elbow_l")


def test_circle_collinear_points():
    p = np.outer(np.linspace(0, 1, 30), [0, 0, 1])
    with pytest.raises(BodyCalError, match="line"):
        geo.fit_circle(p, name="flex_knee_r")


def test_sphere_exact_and_four_point_sphere():
    c = np.array([0.2, 0.1, 1.4])
    fit = geo.fit_sphere(_cap(200, c, 0.3))
    np.testing.assert_allclose(fit.center, c, atol=1e-9)
    assert abs(fit.radius - 0.3) < 1e-9 and fit.rms < 1e-9
    assert fit.range_deg > 90
    four = c + 0.09 * np.array([[0, 0, 1], [1, 0, 0], [-1, 0, 0], [0, -1, 0.2]]) / \
        np.linalg.norm([[0, 0, 1], [1, 0, 0], [-1, 0, 0], [0, -1, 0.2]], axis=1)[:, None]
    f4 = geo.fit_sphere(four, name="skull")
    np.testing.assert_allclose(f4.center, c, atol=1e-9)
    assert abs(f4.radius - 0.09) < 1e-9


def test_sphere_two_sigma_pass_beats_plain_fit_with_outliers():
    c = np.array([0.0, 0.0, 1.4])
    errs = []
    for _ in range(5):
        p = _cap(400, c, 0.3) + rng.normal(0, 0.001, (400, 3))
        bad = rng.choice(400, 40, replace=False)
        p[bad] += rng.normal(0, 0.05, (40, 3))
        robust = geo.fit_sphere(p)
        plain = geo.fit_sphere(p, robust=False)
        errs.append((np.linalg.norm(robust.center - c), np.linalg.norm(plain.center - c)))
    errs = np.array(errs)
    assert np.median(errs[:, 0]) < 0.003
    assert np.median(errs[:, 0]) < np.median(errs[:, 1])


def test_sphere_too_little_motion_and_planar_swing():
    c = np.zeros(3)
    with pytest.raises(BodyCalError, match=r"swing_shoulder_l: only \d+ degrees of motion recorded"):
        geo.fit_sphere(_cap(200, c, 0.3, np.radians(8)) + rng.normal(0, 1e-4, (200, 3)), name="swing_shoulder_l")
    rot = _random_rotation()
    arc = _arc(200, c, 0.3, rot)  # a swing in one plane leaves the centre free along the plane's normal
    with pytest.raises(BodyCalError, match="plane"):
        geo.fit_sphere(arc, name="swing_hip_r")


def test_nan_points_are_ignored_and_too_few_reported():
    p = np.full((10, 3), np.nan)
    with pytest.raises(BodyCalError, match="only 0 usable points"):
        geo.fit_sphere(p, name="swing_hip_l")
    rot = _random_rotation()
    q = _arc(50, np.zeros(3), 0.2, rot)
    q[::5] = np.nan
    assert geo.fit_circle(q).of == 40


def test_robust_mean_ignores_a_far_point():
    p = rng.normal(0, 0.001, (40, 3))
    p[3] = [0.2, 0, 0]
    m, keep = geo.robust_mean(p)
    assert not keep[3]
    assert np.linalg.norm(m) < 0.001


def test_repeated_two_sigma_passes_beat_a_single_pass():
    """DESIGN.md §3 decision: repeat the 2-sigma pass until nothing is dropped."""
    c = np.array([0.0, 0.0, 1.4])
    errs = []
    for _ in range(6):
        p = _cap(400, c, 0.3) + rng.normal(0, 0.001, (400, 3))
        bad = rng.choice(400, 40, replace=False)
        p[bad] += rng.normal(0, 0.05, (40, 3))
        errs.append((np.linalg.norm(geo.fit_sphere(p).center - c),
                     np.linalg.norm(geo.fit_sphere(p, passes=1).center - c)))
    errs = np.array(errs)
    assert np.median(errs[:, 0]) < np.median(errs[:, 1])


def _rigid_pair(n, swing=1.0, noise=0.0, b_swing=0.2):
    """Frame B fixed-ish, frame A swinging about a joint J: J = R_a a + p_a = R_b b + p_b."""
    from bodycal_addon.core import transforms as tf

    j = np.array([0.1, 0.2, 1.3])
    a, b = np.array([0.02, -0.12, 0.03]), np.array([0.15, 0.05, -0.1])
    t = np.linspace(0, 6, n)
    qa = tf.quat_mul(tf.axis_angle_to_quat(np.array([1.0, 0, 0]), swing * np.sin(1.3 * t)),
                     tf.axis_angle_to_quat(np.array([0, 1.0, 0]), swing * np.sin(0.7 * t + 1)))
    qb = tf.axis_angle_to_quat(np.array([0, 0, 1.0]), b_swing * np.sin(0.5 * t))
    ra, rb = tf.quat_to_matrix(qa), tf.quat_to_matrix(qb)
    pa = j - ra @ a + rng.normal(0, noise, (n, 3))
    pb = j - rb @ b + rng.normal(0, noise, (n, 3))
    return ra, pa, rb, pb, a, b


def test_rigid_point_exact_and_robust():
    ra, pa, rb, pb, a, b = _rigid_pair(300)
    fit = geo.fit_rigid_point(ra, pa, rb, pb)
    np.testing.assert_allclose(fit.local_a, a, atol=1e-9)
    np.testing.assert_allclose(fit.local_b, b, atol=1e-9)
    assert fit.rms < 1e-9 and fit.range_deg > 40
    ra, pa, rb, pb, a, b = _rigid_pair(300, noise=0.001)
    bad = rng.choice(300, 30, replace=False)
    pa[bad] += rng.normal(0, 0.05, (30, 3))
    robust = geo.fit_rigid_point(ra, pa, rb, pb)
    plain = geo.fit_rigid_point(ra, pa, rb, pb, robust=False)
    assert robust.kept < 300
    assert np.linalg.norm(robust.local_a - a) < 0.003
    assert np.linalg.norm(robust.local_a - a) < np.linalg.norm(plain.local_a - a)


def test_rigid_point_without_relative_motion_is_actionable():
    ra, pa, rb, pb, _, _ = _rigid_pair(100, swing=0.02, b_swing=0.0)
    with pytest.raises(BodyCalError, match=r"swing_hip_l: only \d+ degrees of motion recorded between"):
        geo.fit_rigid_point(ra, pa, rb, pb, name="swing_hip_l")


def test_rotation_axis_exact():
    from bodycal_addon.core import transforms as tf

    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    base = tf.quat_to_matrix(_random_quat_g())
    rel = tf.quat_to_matrix(tf.axis_angle_to_quat(axis, np.linspace(0, 2.0, 50))) @ base
    found, swept = geo.fit_rotation_axis(rel)
    assert abs(abs(found @ axis) - 1) < 1e-9
    assert 110 < swept < 120


def _random_quat_g():
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


def _hinge_pair(n, point_a, axis, angles):
    """Frames A and B joined by a hinge about `axis` (A's frame) through `point_a`: B turns by
    `angles` about it; both move together by random rigid motions."""
    Rab = _axis_rot(axis, angles)  # B in A
    pb_local = point_a - np.einsum("fij,j->fi", Rab, point_a)  # keeps the hinge point fixed
    ra = np.stack([_random_rotation() for _ in range(n)])
    pa = rng.normal(size=(n, 3))
    rb = ra @ Rab
    pb = pa + np.einsum("fij,fj->fi", ra, pb_local)
    return ra, pa, rb, pb


def _axis_rot(axis, angles):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    x, y, z = axis
    c, s = np.cos(angles), np.sin(angles)
    t = 1 - c
    return np.stack([np.stack([c + x * x * t, x * y * t - z * s, x * z * t + y * s], -1),
                     np.stack([y * x * t + z * s, c + y * y * t, y * z * t - x * s], -1),
                     np.stack([z * x * t - y * s, z * y * t + x * s, c + z * z * t], -1)], -2)


def test_rigid_point_on_a_hinge_takes_the_given_coordinate_along_its_axis():
    """An ankle that only flexes leaves its centre free along the hinge axis; the fit puts it at
    the coordinate of a given point (the knee) along the axis, and elsewhere exactly."""
    point, axis = np.array([0.02, -0.4, 0.05]), np.array([1.0, 0.1, 0.0])
    ra, pa, rb, pb = _hinge_pair(200, point, axis, np.linspace(-0.4, 0.5, 200))
    u = axis / np.linalg.norm(axis)
    knee = point + 0.07 * u + np.array([0.0, 0.3, 0.0]) - (np.array([0.0, 0.3, 0.0]) @ u) * u  # same axial coord
    knee = knee - 0.07 * u  # ... and exactly the hinge point's coordinate along the axis
    fit = geo.fit_rigid_point(ra, pa, rb, pb, along_axis_as=knee)
    assert fit.weak_axis
    np.testing.assert_allclose(fit.local_a, point, atol=1e-6)
    # a joint that turns about two axes is determined by the motion itself, the hint unused
    ra, pa, rb, pb, a, _ = _rigid_pair(300)
    fit = geo.fit_rigid_point(ra, pa, rb, pb, along_axis_as=a + np.array([0.1, 0.1, 0.1]))
    assert not fit.weak_axis
    np.testing.assert_allclose(fit.local_a, a, atol=1e-9)


def test_geometric_fit_removes_the_algebraic_short_arc_bias():
    """Kåsa's algebraic circle shrinks a short noisy arc (and its centre follows toward the points);
    the geometric refinement does not."""
    radius, kasa, geometric = 0.45, [], []
    for _ in range(60):
        pts = _arc(150, np.zeros(3), radius, np.eye(3), 0.0, np.radians(60)) + rng.normal(0, 0.005, (150, 3)) \
            * np.array([1, 1, 0])
        kasa.append(geo._kasa_2d(pts[:, :2])[1])
        geometric.append(geo.fit_circle(pts, robust=False, min_arc_deg=30).radius)
    assert abs(np.mean(kasa) - radius) > 0.01  # the bias this guards against
    assert abs(np.mean(geometric) - radius) < 0.003


def test_moving_point_sphere_sees_through_a_wandering_joint():
    """A foot tracker 7 cm in front of an ankle that wanders a few degrees while the straight leg
    swings about the hip: the tracker's own sphere is off by centimetres, the sphere of the point
    that keeps its distance is not."""
    n, hip, leg = 600, np.array([0.1, 0.05, -0.08]), 0.8
    t = np.linspace(0, 6, n)
    theta = np.radians(25 + 15 * np.sin(2 * np.pi * 0.5 * t))
    alpha = np.radians(60 + 100 * np.sin(2 * np.pi * 0.33 * t + 0.5))
    d = np.column_stack([np.sin(theta) * np.cos(alpha), np.sin(theta) * np.sin(alpha), -np.cos(theta)])
    ankle = hip + leg * d
    wander = _axis_rot(np.array([1.0, 0.0, 0.0]), np.radians(6) * np.sin(2 * np.pi * 0.7 * t)) @ \
        _axis_rot(np.array([0.0, 1.0, 0.0]), np.radians(5) * np.sin(2 * np.pi * 0.45 * t + 1))
    mount = _random_rotation()  # the tracker's axes on the foot
    rot = wander @ mount
    device = ankle + np.einsum("fij,j->fi", rot, mount.T @ np.array([0.0, 0.07, 0.02]))
    plain = geo.fit_sphere(device)
    moving = geo.fit_sphere_moving_point(device, rot)
    assert np.linalg.norm(plain.center - hip) > 0.01
    assert np.linalg.norm(moving.center - hip) < 0.003
