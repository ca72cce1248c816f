"""The prepared solver's outputs pinned before its per-frame overheads were removed (DESIGN.md
"Prepared solver", issue 27's speed targets): the speed-ups restructure how each frame is computed
(prepared index arrays, batched small products, fewer temporaries), never what. The values of a
fixed take, every method, planting off and on, solved one frame at a time and as one chunk (the
pose-bone values, the root and every target; the joints are their FK), stay those the code gave
before: `tests/engine/data/solver_before_speedup.npz`, written by
`PYTHONPATH=. .venv/bin/python tests/engine/test_solver_speedup_pin.py --write` on commit 064090a
for the speed-ups; again on 32c8438 (the lost-device bridging, merged beside them: the take's
dropouts are bridged by Hermite curves now), the commit before the two were merged; and again on
32c8438 with the rolling feet merged onto it (the feet branch at 8305613) and nothing of the speed-ups,
since the feet change the legs, the pelvis and the soles on purpose: the speed-ups merged with
both still give those values within 1e-9. Written again by the commit that brought the egocentric
hand's point (issue 40, `solver_methods.PALM_NEAR`), which moves the egocentric wrists, fingertips
and arms on purpose where a palm is away from the body; every other value within 1e-9 of before. One frame solved in
mathutils (float32, DESIGN.md "Prepared solver"): within the measured tolerance of
`retarget_fixtures.ONE_FRAME_ATOL` (the numpy path: 1e-9)."""

from __future__ import annotations

import pathlib
import sys

import numpy as np
import pytest

from bodycal_addon.core import one_frame
from bodycal_addon.retarget import pipeline as pl
from bodycal_addon.retarget.pose_source import RecordingSource
from bodycal_addon.retarget.solver import PreparedSolver
from bodycal_dev import synthetic
from bodycal_dev.retarget_fixtures import one_frame_atol, procedural_avatar

REFERENCE = pathlib.Path(__file__).parent / "data" / "solver_before_speedup.npz"
SINGLE = tuple(range(30, 1400, 120))  # frames solved one at a time (the live loop's and a preview's solve)
CHUNK = (600, 624)  # a block solved at once (the bake's)


def _take():
    # Contacts (hands on the body, the other hand, the head, the thighs), a walk (stances), with
    # finger markers (the full profile) and a few dropouts.
    rec, truth = synthetic.record_session(synthetic.make_performer(seed=1),
                                          motions=("clap", "hand_on_head", "hands_on_thighs", "walk_in_place"),
                                          calibration=False, seed=1, dropout_rate=0.02)
    return rec, truth.body_model(), procedural_avatar()


def _solve_all(rec, user, avatar) -> dict:
    out = {}
    for method in pl.METHODS:
        for plant in (False, True):
            solver = PreparedSolver(RecordingSource(rec, user), avatar, method, plant_feet=plant)
            for how, parts in (("single", [solver.solve(f, f + 1) for f in SINGLE]),
                               ("chunk", [solver.solve(*CHUNK)])):
                key = f"{method}_{'plant' if plant else 'free'}_{how}"
                out[f"{key}_basis"] = np.concatenate([p.basis for p in parts])
                out[f"{key}_root"] = np.concatenate([p.root_location for p in parts])
                for name in parts[0].targets:
                    out[f"{key}_target_{name}"] = np.concatenate([p.targets[name] for p in parts])
    return out


@pytest.fixture(scope="module", params=["numpy", "mathutils"])
def solved(request):
    """(the solved values, the path: one frame's solve in numpy's or mathutils' kernels)."""
    before = one_frame.ENABLED
    one_frame.ENABLED = request.param == "mathutils"
    try:
        return _solve_all(*_take()), request.param
    finally:
        one_frame.ENABLED = before


@pytest.mark.parametrize("method", pl.METHODS)
def test_the_solver_gives_the_values_it_gave_before_the_speed_ups(solved, method):
    # the chunks and numpy's one-frame path within 1e-9; mathutils' one frame (float32) within
    # retarget_fixtures.ONE_FRAME_ATOL
    solved, path = solved
    ref = np.load(REFERENCE)
    keys = sorted(k for k in ref.files if k.startswith(method + "_"))
    assert keys and keys == sorted(k for k in solved if k.startswith(method + "_"))  # the same targets aimed at
    for k in keys:
        atol = one_frame_atol(k) if path == "mathutils" and "_single_" in k else 1e-9
        np.testing.assert_allclose(solved[k], ref[k], rtol=0, atol=atol, err_msg=k)


if __name__ == "__main__" and "--write" in sys.argv:
    one_frame.ENABLED = False  # the reference is numpy's path
    np.savez_compressed(REFERENCE, **_solve_all(*_take()))
