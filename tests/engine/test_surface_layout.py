"""The shared surface topology: every triangle faces out of the body."""

import numpy as np

from bodycal_addon.body import surface_layout as sl

# A performer facing -Y, left at +X (Blender's front view), points roughly where touches land.
TORSO = {
    "sternum": (0, -0.12, 1.35), "chest_l": (0.10, -0.11, 1.30), "chest_r": (-0.10, -0.11, 1.30),
    "belly_ul": (0.10, -0.12, 1.10), "belly_ur": (-0.10, -0.12, 1.10),
    "belly_ll": (0.09, -0.11, 0.95), "belly_lr": (-0.09, -0.11, 0.95),
    "back_ul": (0.10, 0.10, 1.30), "back_ur": (-0.10, 0.10, 1.30), "back_low": (0.0, 0.10, 1.00),
}
JAW = {"ear_l": (0.07, 0.0, 1.62), "ear_r": (-0.07, 0.0, 1.62), "upper_lip": (0.0, -0.10, 1.58),
       "chin": (0.0, -0.09, 1.50), "jaw_l": (0.05, -0.05, 1.53), "jaw_r": (-0.05, -0.05, 1.53)}


def _normal(points, tri):
    a, b, c = (np.array(points[n], float) for n in tri)
    return np.cross(b - a, c - a)


def test_torso_and_jaw_triangles_face_outward():
    pts = dict(TORSO)
    pts.update(sl.belly_centre_points(*(np.array(TORSO[k]) for k in ("belly_ul", "belly_ur", "belly_ll",
                                                                       "belly_lr"))))
    for tri in sl.TORSO_TRIANGLES:
        n = _normal(pts, tri)
        outward = 1 if tri[0].startswith("back") else -1  # back faces +Y, front faces -Y
        assert n[1] * outward > 0, tri
    for tri in sl.JAW_TRIANGLES:
        assert _normal(JAW, tri)[1] < 0, tri


def test_belly_centre_points_interpolate_the_corners():
    c = sl.belly_centre_points(np.zeros(3), np.array([3.0, 0, 0]), np.array([0, 0, -3.0]), np.array([3.0, 0, -3]))
    np.testing.assert_allclose(c["belly_c1"], [1, 0, -1])
    np.testing.assert_allclose(c["belly_c4"], [2, 0, -2])
    assert len(sl.element_ids()) == len(set(sl.element_ids())) == 8 + 30 + 3 + 4
