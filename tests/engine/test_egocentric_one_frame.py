"""One frame's egocentric mapping over flat pair arrays (`egocentric/one_frame.py`, DESIGN.md
"Prepared solver"): on motion the synthetic performer did not make (CMU 131_03, start, hop, stop,
recorded through `evaluation/`, calibrated, onto the procedural avatar at a child's size), fed the
very inputs the bake's kernels (`prepare_targets`, `PreparedTargets.map`, `project`) got in each
frame's solve, it gives their values to float32's rounding: every target of every stage and pass,
and the palms' nearest distances. The solve takes it for one frame where one frame may differ by
that rounding (mathutils on), and the bake's kernels otherwise."""

from __future__ import annotations

import numpy as np
import pytest
from outside_takes import clip_performer, outside_recording

from bodycal_addon.calibration import calibrate_user
from bodycal_addon.core import one_frame
from bodycal_addon.retarget import egocentric as ego
from bodycal_addon.retarget import pipeline as pl
from bodycal_addon.retarget.egocentric import mapping
from bodycal_addon.retarget.egocentric.one_frame import OneFrameMapping
from bodycal_dev import retarget_fixtures as rt

HOP = "131_03_start_hop_stop.bvh"
# Measured on this take (every 7th frame): at most 6.7e-7 m on a target (float32's step at 1 m is
# 6e-8; the bake's sums round in float32, these in float64), 2.5e-7 m on a palm's distance (float32's
# against `project`'s float64).
TARGET_ATOL = 1.5e-6
DISTANCE_ATOL = 5e-7


@pytest.fixture(scope="module")
def hop_solver(data_dir, tmp_path_factory):
    perf = clip_performer(data_dir, HOP, "cmu_bvh_fast_arms")
    rec, _ = outside_recording(perf, tmp_path_factory.mktemp("ego_one_frame"), "full", seed=0, up="Z")
    return pl.prepare_recording(rec, calibrate_user(rec), rt.procedural_avatar(scale=0.75), "egocentric").solver


def _bake_kernels_of(solver, f: int, monkeypatch) -> dict:
    """What the bake's kernels got and gave in frame f's solve (numpy's path): the surfaces'
    joints and frames by the posed surface they made, prepare_targets' targets and bones, and
    each map's avatar surface, target names and result."""
    seen = {"poses": {}, "maps": []}
    pose, prepare, mapped = ego.SurfacePoser.pose, ego.prepare_targets, mapping.PreparedTargets.map

    def posing(self, joints, frames, normals=True):
        out = pose(self, joints, frames, normals)
        seen["poses"][id(out)] = (joints.copy(), frames.copy(), out)  # (a pose's arrays change later)
        return out

    def preparing(pts, names, us, user_bones=None, **kw):
        seen["prepare"] = (pts.copy(), list(names), us, user_bones)
        return prepare(pts, names, us, user_bones=user_bones, **kw)

    def mapping_(self, av, avatar_bones=None, **kw):
        out = mapped(self, av, avatar_bones, **kw)
        seen["maps"].append((av, kw.get("targets"), out.copy()))  # (the chunk changes it later)
        return out

    monkeypatch.setattr(one_frame, "ENABLED", False)
    monkeypatch.setattr(ego.SurfacePoser, "pose", posing)
    monkeypatch.setattr(ego, "prepare_targets", preparing)
    monkeypatch.setattr(mapping.PreparedTargets, "map", mapping_)
    try:
        solver.solve(f, f + 1)
    finally:
        monkeypatch.undo()
    return seen


def test_one_frame_maps_every_target_as_the_bake_s_kernels_do(hop_solver, monkeypatch):
    method = hop_solver.impl
    fm = method.one_frame
    assert fm is not None  # the procedural avatar's layout takes it
    worst, maps = 0.0, 0
    no_levers = np.zeros((len(method.palm_local), 3))
    for f in range(0, hop_solver.frame_count, 7):
        seen = _bake_kernels_of(hop_solver, f, monkeypatch)
        pts, names, us, ub = seen["prepare"]
        assert names == method.mapped
        joints, frames, _ = seen["poses"][id(us)]
        # (the bake's targets have their wrists moved to the palm already: no lever here)
        user_side, _ = fm.prepare(fm.user_surface(joints[0], frames[0]), pts[0], ub[0], no_levers, np.zeros_like)
        for av, targets, want in seen["maps"]:
            a_joints, a_frames, _ = seen["poses"][id(av)]
            stage = 0 if list(targets) == method.lower else 1  # the trunk's or the arms' (as the solve maps)
            got = fm.map(user_side, a_joints[0], a_frames[0], stage)[
                [names.index(n) for n in targets]]
            assert got.shape == want[0].shape and np.isfinite(got).all()
            worst = max(worst, float(np.abs(got - want[0]).max()))
            maps += 1
    assert maps == 3 * len(range(0, hop_solver.frame_count, 7))  # the trunk's map and the arms' two
    assert worst <= TARGET_ATOL, worst


def test_one_frame_s_palm_distances_are_project_s(hop_solver, monkeypatch):
    # Each palm's nearest element not on its own arm and hand, against the bake's `project` over
    # every element: the frames' wrists and fingertips taken as palm centres, and each moved 3 cm
    # along every axis (on, near and off the body).
    method = hop_solver.impl
    fm = method.one_frame
    sides = list(method.palm_local)
    own = np.array([[eid in ego.own_chain_elements(f"wrist_{s}") for eid in method.ids] for s in sides])
    worst = 0.0
    for f in range(0, hop_solver.frame_count, 23):
        seen = _bake_kernels_of(hop_solver, f, monkeypatch)
        pts, names, us, ub = seen["prepare"]
        ub = ub[0]
        joints, frames, _ = seen["poses"][id(us)]
        flat = fm.user_surface(joints[0], frames[0])
        wrists = np.stack([pts[0, names.index(f"wrist_{s}")] for s in sides])
        for row in ("wrist", "tip_index", "tip_thumb"):
            base = np.stack([pts[0, names.index(f"{row}_{s}")] for s in sides])
            for shift in np.vstack([np.zeros(3), 0.03 * np.eye(3), -0.03 * np.eye(3)]):
                palms = base + shift
                want = np.where(own, np.inf, ego.project(palms[None], us).dist[0]).min(axis=-1)
                near = []  # what prepare's palm weight is given: the palms' nearest distances
                fm.prepare(flat, pts[0], ub, palms - wrists, lambda d, seen=near: seen.append(d) or np.zeros_like(d))
                worst = max(worst, float(np.abs(near[0] - want).max()))
    assert worst <= DISTANCE_ATOL, worst


def test_a_hand_on_its_palm_maps_as_its_palm_centre_alone_would(hop_solver, monkeypatch):
    # The palms projected in the targets' pass (OneFrameMapping's Decision): a palm weight of 1
    # maps the wrist target as the palm centre given as that target does, bit for bit (the wrist's
    # own pairs weigh 0); of 0, as the wrist; between them (the pass again), as the point between.
    method = hop_solver.impl
    fm = method.one_frame
    sides = list(method.palm_local)
    rows = [method.mapped.index(f"wrist_{s}") for s in sides]
    for f in range(0, hop_solver.frame_count, 41):
        seen = _bake_kernels_of(hop_solver, f, monkeypatch)
        pts, names, us, ub = seen["prepare"]
        joints, frames, _ = seen["poses"][id(us)]
        flat = fm.user_surface(joints[0], frames[0])
        a_joints, a_frames, _ = seen["poses"][id(seen["maps"][-1][0])]
        levers = np.array([[0.02, -0.07, 0.01], [-0.03, -0.06, 0.02]])[:len(sides)]
        for w in ((1.0, 1.0), (0.0, 1.0), (1.0, 0.0), (0.0, 0.0), (0.5, 1.0), (0.25, 0.75)):
            w = np.array(w[:len(sides)])
            got_side, got_w = fm.prepare(flat, pts[0], ub[0], levers, lambda d, w=w: w)
            moved = pts[0].copy()
            moved[rows] += w[:, None] * levers
            want_side, _ = fm.prepare(flat, moved, ub[0], np.zeros_like(levers), np.zeros_like)
            np.testing.assert_array_equal(got_w, w)
            np.testing.assert_array_equal(got_side.pts, want_side.pts)
            np.testing.assert_array_equal(fm.map(got_side, a_joints[0], a_frames[0], 1),
                                          fm.map(want_side, a_joints[0], a_frames[0], 1))


def test_the_solve_takes_it_for_one_frame_where_mathutils_is_on(hop_solver, monkeypatch):
    calls = []
    mapped = OneFrameMapping.map
    monkeypatch.setattr(OneFrameMapping, "map", lambda self, u, *a: calls.append(1) or mapped(self, u, *a))
    for enabled, frames, want in ((True, 1, 3), (False, 1, 0), (True, 2, 0)):
        monkeypatch.setattr(one_frame, "ENABLED", enabled)
        calls.clear()
        hop_solver.solve(40, 40 + frames)
        assert len(calls) == want, (enabled, frames)


def test_a_layout_it_does_not_fit_takes_the_bake_s_kernels(hop_solver):
    method = hop_solver.impl
    user, avatar = method.posers["user"], method.posers["avatar"]
    assert OneFrameMapping.build(method.mapped, user, avatar, method.trunk_exclude, ("l", "r")) is not None
    # the two bodies' elements differ
    assert OneFrameMapping.build(method.mapped, user, method.posers["avatar_trunk"]) is None
    # a target with no element to map onto (the bake's kernels keep its user's position)
    every = tuple(frozenset(method.ids) if n == "skull_base" else frozenset() for n in method.mapped)
    assert OneFrameMapping.build(method.mapped, user, avatar, every) is None


def test_one_frame_s_closest_points_on_triangles_are_ericson_s_bit_for_bit():
    # One frame's Ericson kernel (its regions' tests in one comparison, the first that holds by
    # an argmax, the triangles' dot products made once a triangle): the same barycentric
    # coordinates as the bake's `projection.closest_on_triangles`, every bit, over points near and
    # far from triangles of every shape (flattened to a line or a point, a point on an edge's
    # line, corners), so every region and its ties (a term exactly 0, two terms equal) are met.
    from bodycal_addon.retarget.egocentric import one_frame as of
    from bodycal_addon.retarget.egocentric.projection import closest_on_triangles

    rng = np.random.default_rng(41)
    regions = set()
    for trial in range(60):
        n = 400
        ap = (rng.standard_normal((3, n)) * rng.uniform(0.01, 2.0)).astype(np.float32)
        ab = (rng.standard_normal((3, n)) * 0.1).astype(np.float32)
        ac = (rng.standard_normal((3, n)) * 0.1).astype(np.float32)
        if trial % 3 == 0:
            ac = 2 * ab  # a degenerate triangle
        if trial % 11 == 0:
            ab = ac = np.zeros_like(ab)  # a triangle shrunk to a point
        if trial % 5 == 0:
            ap = ab * rng.uniform(-1.0, 2.0, n).astype(np.float32)  # on the line of AB
        if trial % 7 == 0:
            ap = np.where(rng.random(n) < 0.5, ab, ac)  # on a corner
        edges = np.stack([ab, ac])
        dots = [of.dot3(x, y) for x, y in ((ab, ab), (ac, ac), (ab, ac))]
        want, got = closest_on_triangles(ap, ab, ac), of._closest_on_triangles(ap, edges, *dots)
        for w, g in zip(want, got):
            np.testing.assert_array_equal(g, w)
        regions |= set(zip(want[0].tolist(), want[1].tolist())) & {(0.0, 0.0), (1.0, 0.0), (0.0, 1.0)}
        regions.add("inside" if ((want[0] > 0) & (want[1] > 0) & (want[0] + want[1] < 1)).any() else "none")
    assert regions >= {(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), "inside"}


def test_an_avatar_whose_capsules_sit_off_the_bone_line_maps_as_the_bake_s_kernels_do(hop_solver, monkeypatch):
    # The avatar's side is gathered from its pose (`_avatar_points`: each x' a sum of joints and
    # bone-frame columns); a capsule's axis offsets (FORMATS.md axis_head / axis_tail) are part of
    # the sum. The procedural avatar has none: here its capsules are moved off their bones by up to
    # 4 cm, and one frame's targets are compared with the bake's kernels on that surface.
    import copy

    method = hop_solver.impl
    user, avatar = method.posers["user"], method.posers["avatar"]
    moved = copy.copy(avatar)
    moved.cap_off = np.random.default_rng(3).uniform(-0.04, 0.04, avatar.cap_off.shape)
    moved.cap_offset = True
    fm = OneFrameMapping.build(method.mapped, user, moved, method.trunk_exclude, tuple(method.palm_local),
                               len(method.lower))
    assert fm is not None
    no_levers = np.zeros((len(method.palm_local), 3))
    worst, maps = 0.0, 0
    for f in range(0, hop_solver.frame_count, 29):
        seen = _bake_kernels_of(hop_solver, f, monkeypatch)
        pts, names, us, ub = seen["prepare"]
        joints, frames, _ = seen["poses"][id(us)]
        user_side, _ = fm.prepare(fm.user_surface(joints[0], frames[0]), pts[0], ub[0], no_levers, np.zeros_like)
        want_side = ego.prepare_targets(pts, names, us, user_bones=ub, dtype=np.float32, exclude=method.trunk_exclude)
        for av, targets, _ in seen["maps"]:
            a_joints, a_frames, _ = seen["poses"][id(av)]
            want = want_side.map(moved.pose(a_joints, a_frames, normals=False), targets=targets)[0]
            stage = 0 if list(targets) == method.lower else 1
            got = fm.map(user_side, a_joints[0], a_frames[0], stage)[[names.index(n) for n in targets]]
            worst = max(worst, float(np.abs(got - want).max()))
            maps += 1
    assert maps == 3 * len(range(0, hop_solver.frame_count, 29))
    # moved capsules map elsewhere than the unmoved ones (the offsets are read) ...
    assert not np.allclose(fm.map(user_side, a_joints[0], a_frames[0], 1),
                           method.one_frame.map(method.one_frame.prepare(
                               method.one_frame.user_surface(joints[0], frames[0]), pts[0], ub[0], no_levers,
                               np.zeros_like)[0], a_joints[0], a_frames[0], 1), atol=1e-3)
    # ... and as the bake's kernels map them, to float32's rounding
    assert worst <= TARGET_ATOL, worst
