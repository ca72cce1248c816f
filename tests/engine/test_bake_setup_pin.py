"""The egocentric bake's set-up and projection cut for speed (docs/PERFORMANCE.md "Bake"), pinned to
the code they replaced, bit for bit: `surface_correction` over every bone at once against the bone by
bone loop, Ericson's region selection with merged passes against his early returns region by region,
and the one-frame mapping plan made on the first one-frame solve (a bake never makes it)."""

from __future__ import annotations

import copy

import numpy as np
import pytest

from bodycal_addon.body.rest_frames import complete_joints
from bodycal_addon.body.skeleton import BONES
from bodycal_addon.body.surface_layout import bone_frame
from bodycal_addon.retarget import solver_methods as sm
from bodycal_addon.retarget.egocentric.one_frame import OneFrameMapping
from bodycal_addon.retarget.egocentric.projection import closest_on_triangles, ericson_terms, safe_divide
from bodycal_addon.retarget.pose_source import RecordingSource
from bodycal_addon.retarget.solver import PreparedSolver
from bodycal_dev import synthetic
from bodycal_dev.retarget_fixtures import procedural_avatar, rigid_matrix_world


@pytest.fixture(scope="module")
def take():
    perf = synthetic.make_performer(seed=2)
    rec, truth = synthetic.record_session(perf, motions=("clap", "hand_on_head"), calibration=False, seed=2,
                                          motion_seconds=0.5)
    return rec, truth.body_model(), procedural_avatar(matrix_world=rigid_matrix_world())


def _correction_bone_by_bone(model, frames0, pos):
    """The loop `surface_correction` was (one `bone_frame` and one product per bone)."""
    out = np.broadcast_to(np.eye(3), (len(BONES), 3, 3)).copy()
    for i, b in enumerate(BONES):
        info = model.bones.get(b.name)
        if info is None or info.right is None:
            continue
        cm = bone_frame(pos[b.head], pos[b.tail], np.asarray(info.right, float))
        if np.isfinite(cm).all() and abs(np.linalg.det(cm) - 1) < 1e-3:
            out[i] = frames0[i].T @ cm
    return out


def test_surface_correction_is_the_bone_by_bone_loop_s(take):
    rec, user, avatar = take
    s = PreparedSolver(RecordingSource(rec, user), avatar, "egocentric", plant_feet=False)
    for model, frames0, pos in ((s.user, s.user_frames0, s.user_pos),
                                (s.avatar, s.rig.frames0, complete_joints(s.avatar))):
        assert np.array_equal(sm.surface_correction(model, frames0, pos), _correction_bone_by_bone(model, frames0, pos))
        # rights another producer chose (any direction): every such bone corrected
        model = copy.deepcopy(model)
        rng = np.random.default_rng(1)
        for info in model.bones.values():
            if info.right is not None:
                info.right = rng.normal(size=3)
        want = _correction_bone_by_bone(model, frames0, pos)
        assert (np.abs(want - np.eye(3)).sum((1, 2)) > 0.1).sum() > 20
        assert np.array_equal(sm.surface_correction(model, frames0, pos), want)
        # a bone without its right, a bone of zero length, a joint not a number, a right along the bone
        model, pos = copy.deepcopy(model), dict(pos)
        with_right = [b for b in BONES if model.bones.get(b.name) is not None and model.bones[b.name].right is not None]
        model.bones[with_right[0].name].right = None
        pos[with_right[1].tail] = np.array(pos[with_right[1].head], float)
        pos[with_right[5].tail] = np.array([np.nan, 0.0, 0.0])
        b = with_right[9]
        model.bones[b.name].right = np.asarray(pos[b.tail], float) - pos[b.head]
        want = _correction_bone_by_bone(model, frames0, pos)
        assert np.array_equal(sm.surface_correction(model, frames0, pos), want)


def _regions_one_by_one(ap, ab, ac):
    """Ericson's early returns region by region (np.where, the last applied wins): the selection
    `closest_on_triangles` makes in fewer passes."""
    d1, d2, d3, d4, d5, d6, va, vb, vc = ericson_terms(ap, ab, ac)
    denom = va + vb + vc
    v, w = safe_divide(vb, denom), safe_divide(vc, denom)
    e_ab, e_ac = safe_divide(d1, d1 - d3), safe_divide(d2, d2 - d6)
    e_bc = safe_divide(d4 - d3, (d4 - d3) + (d5 - d6))
    for cond, cv, cw in (((va <= 0) & (d4 >= d3) & (d5 >= d6), 1 - e_bc, e_bc),  # BC
                         ((vb <= 0) & (d2 >= 0) & (d6 <= 0), 0.0, e_ac),  # AC
                         ((d6 >= 0) & (d5 <= d6), 0.0, 1.0),  # C
                         ((vc <= 0) & (d1 >= 0) & (d3 <= 0), e_ab, 0.0),  # AB
                         ((d3 >= 0) & (d4 <= d3), 1.0, 0.0),  # B
                         ((d1 <= 0) & (d2 <= 0), 0.0, 0.0)):  # A
        v, w = np.where(cond, cv, v).astype(v.dtype), np.where(cond, cw, w).astype(w.dtype)
    return v, w


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_closest_on_triangles_selects_ericson_s_regions_in_order(dtype):
    rng = np.random.default_rng(5)
    f, p, t = 4, 23, 48
    a = rng.normal(size=(3, f, 1, t))
    b, c = a + rng.normal(size=(3, f, 1, t)), a + rng.normal(size=(3, f, 1, t))
    b[..., :4] = a[..., :4]  # degenerate triangles: b on a, c on b, collinear
    c[..., 4:8] = b[..., 4:8]
    c[..., 8:12] = a[..., 8:12] + 2 * (b[..., 8:12] - a[..., 8:12])
    pts = rng.normal(size=(3, f, p, 1)) * 1.5
    pts[..., :2, :] = a[..., :1]  # on a corner
    ap, ab, ac = ((x - a).astype(dtype) for x in (pts, b, c))
    want = _regions_one_by_one(ap, ab, ac)
    got = closest_on_triangles(ap.copy(), ab.copy(), ac.copy())
    for g, w in zip(got, want):
        assert g.dtype == w.dtype and np.array_equal(g, w)
    # every region is met (the merged passes are exercised), and the corners by constants
    assert ((got[0] == 0) & (got[1] == 0)).any() and ((got[0] == 1) & (got[1] == 0)).any()
    assert ((got[0] == 0) & (got[1] == 1)).any() and ((got[0] > 0) & (got[1] > 0) & (got[0] + got[1] < 1)).any()


def test_a_bake_never_makes_the_one_frame_plan_and_a_frame_makes_it_once(take):
    rec, user, avatar = take
    s = PreparedSolver(RecordingSource(rec, user), avatar, "egocentric", plant_feet=False)
    method = s.impl
    s.solve(0, 6)  # a bake's chunk
    assert method._one_frame is sm._UNBUILT
    one = s.solve(3, 4)
    built = method._one_frame
    assert isinstance(built, OneFrameMapping)
    again = s.solve(3, 4)
    assert method._one_frame is built  # made once
    # the same frame as a solver whose plan was made at its set-up (as it was before)
    eager = PreparedSolver(RecordingSource(rec, user), avatar, "egocentric", plant_feet=False)
    assert isinstance(eager.impl.one_frame, OneFrameMapping)
    want = eager.solve(3, 4)
    for got in (one, again):
        assert np.array_equal(got.basis, want.basis) and np.array_equal(got.joints, want.joints)
        assert np.array_equal(got.root_location, want.root_location)
