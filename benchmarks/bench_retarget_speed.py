"""Retargeting speed (DESIGN.md §7, "Throughput"): frames per second of the full per-frame pipeline,
steps 1-4 (user animation, FK, egocentric mapping, IK; full body with fingers), as a ratio to a
90 Hz capture, on one core; and the peak memory of a 10-minute capture (54,000 frames) retargeted
in chunks.

One core: BLAS threads are pinned to 1 before numpy is imported. Peak memory is the process's
maximum resident set (resource.getrusage, no tracing overhead on the timing) after the 10-minute
run. Target: >= 20x real time, steady state: each method first runs the whole recording once
(its time is reported as `<method>_cold_x_realtime`: a fresh process pays for growing its heap,
the C library maps and unmaps the big temporaries until its thresholds adapt, 10-30 % here), then
the best of three runs is taken.

Prints ONE JSON line. Run: .venv/bin/python benchmarks/bench_retarget_speed.py [--quick]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import json  # noqa: E402
import resource  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import numpy as np  # noqa: E402

from bodycal_addon.recording.model import Recording  # noqa: E402
from bodycal_addon.retarget import pipeline as pl  # noqa: E402
from bodycal_dev import synthetic  # noqa: E402
from bodycal_dev.retarget_fixtures import procedural_avatar  # noqa: E402

CAPTURE_HZ = 90.0


def _tile(rec: Recording, frames: int) -> Recording:
    """A long capture made of the recording repeated (time kept strictly increasing)."""
    reps = -(-frames // rec.frame_count)
    idx = np.tile(np.arange(rec.frame_count), reps)[:frames]
    time_ = np.arange(frames) / CAPTURE_HZ
    return Recording(rec.name + "-long", time_, rec.devices, rec.positions[idx], rec.rotations[idx], rec.valid[idx],
                     list(rec.marker_names), rec.markers[idx], rec.marker_valid[idx], [], rec.source)


def main(quick: bool = False):
    perf = synthetic.make_performer(seed=0)
    rec, truth = synthetic.record_session(perf, motions=("clap", "hand_on_belly", "hand_on_head", "walk_in_place"),
                                          calibration=False, seed=0)
    user = truth.body_model()
    avatar = procedural_avatar()
    out = {"bench": "retarget_speed", "threads": 1, "capture_hz": CAPTURE_HZ}
    # Warm-up (imports, caches); then per method a cold full run and the timed runs on the same recording.
    pl.retarget(rec.__class__(rec.name, rec.time[:200], rec.devices, rec.positions[:200], rec.rotations[:200],
                              rec.valid[:200], rec.marker_names, rec.markers[:200], rec.marker_valid[:200]),
                user, avatar, "egocentric")
    for method in pl.METHODS:
        t = time.perf_counter()
        pl.retarget(rec, user, avatar, method)
        out[f"{method}_cold_x_realtime"] = round(rec.frame_count / (time.perf_counter() - t) / CAPTURE_HZ, 2)
        best = np.inf
        for _ in range(1 if quick else 3):
            t = time.perf_counter()
            pl.retarget(rec, user, avatar, method)
            best = min(best, time.perf_counter() - t)
        fps = rec.frame_count / best
        out[f"{method}_fps"] = round(fps, 1)
        out[f"{method}_x_realtime"] = round(fps / CAPTURE_HZ, 2)
    out["frames_timed"] = rec.frame_count
    long_frames = int((60 if quick else 600) * CAPTURE_HZ)
    long = _tile(rec, long_frames)
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    t = time.perf_counter()
    anim = pl.retarget(long, user, avatar, "egocentric")
    elapsed = time.perf_counter() - t
    rss1 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    out.update({
        "long_capture_minutes": round(long_frames / CAPTURE_HZ / 60, 1),
        "long_capture_seconds": round(elapsed, 1),
        "long_capture_x_realtime": round(long_frames / CAPTURE_HZ / elapsed, 2),
        "peak_rss_mb": round(rss1 / 1024, 1),
        "rss_growth_mb": round((rss1 - rss0) / 1024, 1),
        "output_arrays_mb": round((anim.rotations.nbytes + anim.root_location.nbytes
                                   + sum(v.nbytes for v in anim.joints_world.values())
                                   + sum(v.nbytes for v in anim.targets.values())) / 2**20, 1),
        "target_20x": out["egocentric_x_realtime"] >= 20.0,
    })
    print(json.dumps(out))
    return out


if __name__ == "__main__":
    main(quick="--quick" in sys.argv)
