"""Root motion in numpy (retarget/root_motion.py): on a chain root -> pelvis -> child with turned
rest frames under a turned and scaled armature object, moving the travel onto the root keeps every
bone where Blender's pose rule put it, puts the root on its floor under the pelvis, turned with
the hip line; in place holds the pelvis's floor position."""

from __future__ import annotations

import copy

import numpy as np

from bodycal_addon.body.animation import AvatarAnimation
from bodycal_addon.core.transforms import matrix_to_quat, quat_to_matrix
from bodycal_addon.output.root_motion import RootRest, apply_root_motion


def _rot(axis, angle):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * k + (1 - np.cos(angle)) * k @ k


def _fk(rest, anim, bone_locs):
    """World (armature-space) pose (F, 3, 3) and heads (F, 3) of root, pelvis, child: Blender's rule."""
    (Mr, hr), (Mp, hp), (Mc, hc) = rest
    q = {n: quat_to_matrix(anim.rotations[:, i]) for i, n in enumerate(anim.bone_names)}
    loc_r = bone_locs.get("root", np.zeros((anim.frame_count, 3)))
    Pr = Mr @ q["root"]
    Hr = hr + loc_r @ Mr.T
    rel = Mr.T @ Mp
    Pp = Pr @ rel @ q["pelvis"]
    Hp = Hr + (Pr @ (Mr.T @ (hp - hr))) + ((Pr @ rel) @ anim.root_location[..., None])[..., 0]
    Pc = Pp @ (Mp.T @ Mc) @ q["child"]
    Hc = Hp + (Pp @ (Mp.T @ (hc - hp)))
    return Pr, Hr, Pp, Hp, Pc, Hc


def test_the_root_carries_the_travel_and_the_body_stays():
    rng = np.random.default_rng(4)
    lin = _rot([1, 0, 0], np.pi / 2) * 0.01  # FBX-style: Y-up bones in centimetres
    up = np.linalg.solve(lin, [0, 0, 1.0])
    up /= np.linalg.norm(up)
    Mr = _rot([0.3, 1, 0.2], 0.7)
    Mp = _rot([1, 0.2, 0.1], -1.1)
    Mc = _rot([0.1, 0.4, 1], 0.4)
    hr, hp, hc = np.zeros(3), np.array([3.0, 95.0, 1.0]), np.array([2.0, 120.0, -4.0])
    f = 50
    t = np.linspace(0, 2 * np.pi, f)
    turn = np.stack([_rot(up, a) for a in 0.8 * np.sin(t)])  # the walker turns about the vertical
    bow = np.stack([_rot(np.cross(up, [1.0, 0, 0]), a) for a in 0.3 * np.sin(2 * t)])  # and bows
    Pp = turn @ bow @ Mp
    travel = np.stack([300 * t, 40 * np.sin(t), 5 * np.cos(3 * t)], axis=1)  # armature units (cm)
    basis_p = Mp.T @ Pp
    names = ["root", "pelvis", "child"]
    rot = np.zeros((f, 3, 4))
    rot[..., 0] = 1.0
    rot[:, 1] = matrix_to_quat(basis_p)
    rot[:, 2] = matrix_to_quat(np.stack([_rot(rng.normal(size=3), 0.3) for _ in range(f)]))
    anim = AvatarAnimation("arm", names, rot, "pelvis", travel @ Mp, t, "egocentric")  # location in rest frame
    rest = ((Mr, hr), (Mp, hp), (Mc, hc))
    lateral = np.cross(up, np.array([0.0, 0.0, 1.0]))  # any level direction: the rest hip line
    rr = RootRest("root", Mr, hr, Mp, hp, up, lateral, lin)
    before = _fk(rest, anim, {})
    out = apply_root_motion(anim, rr, "root")
    after = _fk(rest, out, out.bone_locations)
    for a, b in zip(before[2:], after[2:]):  # pelvis and child: the same pose, the same place
        np.testing.assert_allclose(a, b, atol=1e-9)
    Hr, Hp = after[1], after[3]
    d = Hp - Hr
    np.testing.assert_allclose(d - (d @ up)[:, None] * up, 0.0, atol=1e-9)  # under the pelvis
    np.testing.assert_allclose(Hr @ up, hr @ up, atol=1e-9)  # on its floor
    # turned with the hip line: the root's turn carries the rest hip line onto the pelvis's
    lat_root = after[0] @ (Mr.T @ lateral)
    lat_pel = after[2] @ (Mp.T @ lateral)
    flat = lat_pel - (lat_pel @ up)[:, None] * up
    np.testing.assert_allclose(np.cross(lat_root, flat / np.linalg.norm(flat, axis=1)[:, None]) @ up, 0.0,
                               atol=1e-9)
    assert np.all(np.einsum("fi,fi->f", lat_root, flat) > 0)

    still = apply_root_motion(anim, rr, "in-place")
    Hs = _fk(rest, still, still.bone_locations)[3]
    drift = Hs - Hs[0]
    np.testing.assert_allclose(drift - (drift @ up)[:, None] * up, 0.0, atol=1e-9)
    np.testing.assert_allclose(Hs @ up, before[3] @ up, atol=1e-9)  # heights kept
    assert apply_root_motion(anim, rr, "pelvis") is anim
    given = copy.deepcopy(anim)  # given away: changed in place, the same keys
    again = apply_root_motion(given, rr, "root", own=True)
    assert again is given
    np.testing.assert_array_equal(again.rotations, out.rotations)
    np.testing.assert_array_equal(again.bone_locations["root"], out.bone_locations["root"])
