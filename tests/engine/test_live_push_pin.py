"""`LiveSolver.push`'s outputs pinned before the work around the solve was cut (DESIGN.md "Prepared
solver", issue 28's arrival -> pose budget): the speed-ups change how the frame is appended, filtered,
read and planted (no per-frame Python loops, nothing recomputed that changes only with the roles),
never what. A fixed take (fingers from markers, a walk for the stances, a few dropouts) pushed
frame by frame, every method, planting on, the forward One Euro on (as `bodycal live --filter`
runs it): every frame's pose-bone values, root, joints and targets stay bit for bit those the code
gave before, within 1e-9 (each frame's sum over every value of each array; every SAMPLE-th frame's
values kept too, to show where a difference is: sums rather than digests of the bytes, which a
machine whose numpy picks other SIMD kernels could change in the last bit),
`tests/engine/data/live_push_before_speedup.npz`, written by
`PYTHONPATH=. .venv/bin/python tests/engine/test_live_push_pin.py --write` on commit f2e7cad; again by
the commit that brought the egocentric hand's point (issue 40, `solver_methods.PALM_NEAR`), which
moves the egocentric wrists, fingertips and arms on purpose; every other value within 1e-9 of before. A
one-frame push solved with mathutils' kernels (float32, DESIGN.md "Prepared solver") is held within
the measured tolerance of `retarget_fixtures.ONE_FRAME_ATOL` instead; numpy's path still within 1e-9."""

from __future__ import annotations

import pathlib
import sys

import numpy as np
import pytest

from bodycal_addon.core import one_frame
from bodycal_addon.live.session import forward_filter
from bodycal_addon.live.solver import LiveSolver
from bodycal_addon.recording.filters import OneEuro
from bodycal_addon.retarget import pipeline as pl
from bodycal_dev import synthetic
from bodycal_dev.retarget_fixtures import one_frame_atol, procedural_avatar

REFERENCE = pathlib.Path(__file__).parent / "data" / "live_push_before_speedup.npz"
FRAMES = slice(0, 700)  # the take's first frames: the stances of the walk, a clap
PAIRS = 2  # frames pushed two at a time at the end (a late burst: a block of frames in one push)
SAMPLE = 25  # every SAMPLE-th frame's values kept in the reference (the frames' sums cover every frame)


def _frame_sums(a: np.ndarray) -> np.ndarray:
    return a.reshape(len(a), -1).sum(axis=1) if a.ndim else a


def _take():
    rec, truth = synthetic.record_session(synthetic.make_performer(seed=3), motions=("walk_in_place", "clap"),
                                          calibration=False, seed=3, dropout_rate=0.02)
    return rec, truth.body_model(), procedural_avatar()


def _push_all(rec, user, avatar) -> dict:
    out = {}
    idx = np.arange(rec.frame_count)[FRAMES]
    for method in pl.METHODS:
        live = LiveSolver(user, avatar, method, devices=rec.devices, marker_names=rec.marker_names, rate=rec.fps,
                          smooth=forward_filter(OneEuro()), plant_feet=True)
        parts = []
        blocks = [idx[i:i + 1] for i in idx[:-20]] + [idx[i:i + PAIRS] for i in range(len(idx) - 20, len(idx), PAIRS)]
        for b in blocks:
            f = slice(b[0], b[-1] + 1)
            got = live.push(rec.time[f], rec.positions[f], rec.rotations[f], rec.valid[f], rec.markers[f],
                            rec.marker_valid[f])
            if got is not None:
                parts.append(got)
        out[f"{method}_first"] = np.array(live.first_solved)
        out[f"{method}_basis"] = np.concatenate([p.basis for p in parts])
        out[f"{method}_root"] = np.concatenate([p.root_location for p in parts])
        out[f"{method}_joints"] = np.concatenate([p.joints for p in parts])
        for name in parts[0].targets:
            out[f"{method}_target_{name}"] = np.concatenate([p.targets[name] for p in parts])
    return out


def _reference(out: dict) -> dict:
    ref = {}
    for k, v in out.items():
        ref[f"{k}.frame_sums"] = _frame_sums(v)
        ref[f"{k}.sampled"] = v[::SAMPLE] if v.ndim else v
    return ref


@pytest.fixture(scope="module", params=["numpy", "mathutils"])
def pushed(request):
    """(the pushed values, the path: a one-frame push's solve in numpy's or mathutils' kernels)."""
    before = one_frame.ENABLED
    one_frame.ENABLED = request.param == "mathutils"
    try:
        return _push_all(*_take()), request.param
    finally:
        one_frame.ENABLED = before


@pytest.mark.parametrize("method", pl.METHODS)
def test_a_pushed_frame_gives_the_values_it_gave_before_the_speed_ups(pushed, method):
    # numpy's path: bit for bit as before (1e-9); mathutils' (one frame in float32): within
    # retarget_fixtures.ONE_FRAME_ATOL, each frame's sum within it times the values summed
    pushed, path = pushed
    ref = np.load(REFERENCE)
    keys = sorted(k for k in pushed if k.startswith(method + "_"))
    assert keys and sorted(f"{k}.frame_sums" for k in keys) == sorted(
        k for k in ref.files if k.startswith(method + "_") and k.endswith(".frame_sums"))  # the same targets aimed at
    for k in keys:
        v = pushed[k]
        atol = 1e-9 if path == "numpy" or k.endswith("_first") else one_frame_atol(k)
        np.testing.assert_allclose(v[::SAMPLE] if v.ndim else v, ref[f"{k}.sampled"], rtol=0, atol=atol, err_msg=k)
        per_frame = v[0].size if v.ndim else 1
        np.testing.assert_allclose(_frame_sums(v), ref[f"{k}.frame_sums"], rtol=0, atol=atol * per_frame,
                                   err_msg=f"{k}: a frame differs from before")


if __name__ == "__main__" and "--write" in sys.argv:
    one_frame.ENABLED = False  # the reference is numpy's path
    np.savez_compressed(REFERENCE, **_reference(_push_all(*_take())))


def test_a_push_copies_nothing_that_grows_with_the_session():
    # The fill indices and the feet plan's rows were copied whole on every push (a cost that grew
    # with the session's length): they live in buffers that double when full, so between two
    # doublings a push writes its frame into the same arrays.
    rec, user, avatar = _take()
    live = LiveSolver(user, avatar, "rotations", devices=rec.devices, marker_names=rec.marker_names, rate=rec.fps,
                      smooth=forward_filter(OneEuro()), plant_feet=True)

    def buffers():
        reader, plan = live.solver.src.reader, live.solver.feet
        return [reader._fill._buf, reader._marker_fill._buf] + [b for bufs in plan._rows.values() for b in bufs]

    for f in range(300):
        live.push(rec.time[f], rec.positions[f], rec.rotations[f], rec.valid[f], rec.markers[f], rec.marker_valid[f])
    before = buffers()
    assert live.solver.feet and len(before) == 2 + 4 * len(live.solver.feet.sides)
    for f in range(300, 400):  # within one doubling (512 rows after 256)
        live.push(rec.time[f], rec.positions[f], rec.rotations[f], rec.valid[f], rec.markers[f], rec.marker_valid[f])
    assert all(a is b for a, b in zip(before, buffers()))
    assert len(live.solver.feet.weight["l"]) == 400  # every frame planned, none twice
