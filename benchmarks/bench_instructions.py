"""The prepared solver's cost in instructions (DESIGN.md "Prepared solver"; the figures and how they
are read: PERFORMANCE.md "How speed is measured"): a figure that does not
move with the machine, for comparing code across sessions whose machines differ in speed (the same
code measured 4.7 ms a frame on one and 10.7 on another: bench_live_solver.py's milliseconds are
that machine's).

valgrind's callgrind counts the instructions a child process runs (`--child`, this file) on the
quick contact take of bench_live_solver.py (1458 frames at 90 Hz, the procedural avatar, fingers,
planting off for the one-frame solves). Each figure is the difference of two children that differ
only by the work counted, so the imports, the synthetic take and the set-up cancel exactly:
- `per_frame_instructions`: per method, `PreparedSolver.solve(f, f + 1)` over frames 100-299
  against frames 100-199 (after ten warm frames), divided by 100;
- `bake_instructions`: the egocentric bake of the take (`pipeline.retarget`) run twice against
  once (the second bake is a warm one), and per frame.
Counts are exact for the same code, numpy and inputs: an instruction is not a fixed time (a BLAS
kernel runs several per cycle, a pass over memory that leaves the caches fewer), so a change is
also timed (bench_live_solver.py, alternated runs) before it is called faster.

Prints ONE JSON line with `targets` (a third of 9440a21's instructions) and which kernels one frame
took (mathutils, or numpy where it cannot be imported) (about 10 minutes here: eight children under
callgrind; the take is made once, outside it, and pickled for them). Run:
.venv/bin/python benchmarks/bench_instructions.py [--methods egocentric offsets rotations]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import pickle  # noqa: E402
import re  # noqa: E402
import shutil  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from bodycal_addon.core import one_frame  # noqa: E402

METHODS = ("egocentric", "offsets", "rotations")
FIRST, COUNTED = 100, 100  # one-frame solves from frame FIRST; the difference counts COUNTED of them
# Issue 41's: a third of 9440a21's (20.6 M, 7.9 M, 4.8 M a frame; the bake 2.75 G)
FRAME_TARGETS = {"egocentric": 7.0e6, "offsets": 3.0e6, "rotations": 2.0e6}
BAKE_TARGET = 2.2e9


def make_inputs(path: Path) -> None:
    """The take, the user and the avatar, pickled for the children (made once, outside callgrind)."""
    from bench_live_solver import CONTACT_MOTIONS

    from bodycal_dev import synthetic
    from bodycal_dev.retarget_fixtures import procedural_avatar

    rec, truth = synthetic.record_session(synthetic.make_performer(seed=1), motions=CONTACT_MOTIONS,
                                          calibration=False, seed=1, motion_seconds=8.0)
    path.write_bytes(pickle.dumps((rec, truth.body_model(), procedural_avatar())))


def child(inputs: str, work: str, method: str, amount: int) -> None:
    """The work callgrind counts: `amount` one-frame solves or bakes."""
    from bodycal_addon.retarget import pipeline as pl
    from bodycal_addon.retarget.pose_source import RecordingSource
    from bodycal_addon.retarget.solver import PreparedSolver

    rec, user, avatar = pickle.loads(Path(inputs).read_bytes())
    if work == "frames":
        solver = PreparedSolver(RecordingSource(rec, user), avatar, method, plant_feet=False)
        for f in range(FIRST - 10, FIRST):  # warm: the plans made on a first solve
            solver.solve(f, f + 1)
        for f in range(FIRST, FIRST + amount):
            solver.solve(f, f + 1)
    else:
        for _ in range(amount):
            pl.retarget(rec, user, avatar, method)
    print(rec.frame_count)


def count(inputs: Path, work: str, method: str, amount: int) -> tuple[int, int]:
    """(instructions of a child doing `amount` of `work`, the take's frames)."""
    # One hash seed for every child: with a random one the same code's per-frame figure moved by up
    # to 1.5 M (measured on the offsets' frames 200-299: 1.9 M against 3.4 M with the seed fixed)
    out = subprocess.run(["valgrind", "--tool=callgrind", f"--callgrind-out-file={inputs.parent}/cg.out",
                          sys.executable, __file__, "--child", str(inputs), work, method, str(amount)],
                         capture_output=True, text=True, cwd=REPO, check=True,
                         env={**os.environ, "PYTHONHASHSEED": "0"})
    found = re.search(r"Collected : (\d+)", out.stderr)
    if found is None:
        raise SystemExit(f"callgrind gave no count: {out.stderr[-500:]}")
    return int(found.group(1)), int(out.stdout.split()[-1])


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--methods", nargs="*", default=list(METHODS), choices=METHODS)
    args = p.parse_args()
    if shutil.which("valgrind") is None:  # `make bench` goes on to the next benchmark
        print(json.dumps({"bench": "instructions", "skipped": "valgrind is not installed (apt-get install valgrind)"}))
        return
    t0 = time.time()
    out = {"bench": "instructions", "take": "bench_live_solver --quick's", "per_frame_instructions": {}}
    with tempfile.TemporaryDirectory(prefix="bodycal-callgrind-") as tmp:
        inputs = Path(tmp) / "inputs.pickle"
        make_inputs(inputs)
        for method in args.methods:
            one, _ = count(inputs, "frames", method, COUNTED)
            two, _ = count(inputs, "frames", method, 2 * COUNTED)
            out["per_frame_instructions"][method] = round((two - one) / COUNTED)
        one, frames = count(inputs, "bake", "egocentric", 1)
        two, _ = count(inputs, "bake", "egocentric", 2)
    out["bake_instructions"] = {"egocentric": two - one, "per_frame": round((two - one) / frames), "frames": frames}
    out["one_frame_kernels"] = "mathutils" if one_frame.ENABLED else "numpy (no mathutils here)"
    out["targets"] = {f"{m}_frame_<=_{FRAME_TARGETS[m] / 1e6:g}M": out["per_frame_instructions"][m] <= FRAME_TARGETS[m]
                      for m in args.methods}
    out["targets"][f"egocentric_bake_<=_{BAKE_TARGET / 1e9:g}G"] = two - one <= BAKE_TARGET
    out["seconds"] = round(time.time() - t0, 1)
    print(json.dumps(out))


if __name__ == "__main__":
    if sys.argv[1:2] == ["--child"]:
        child(sys.argv[2], sys.argv[3], sys.argv[4], int(sys.argv[5]))
    else:
        sys.path.insert(0, str(REPO / "benchmarks"))
        main()
