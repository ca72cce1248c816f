"""Import benchmark: a 10-minute, 90 Hz, full-profile recording of the synthetic performer,
written as JSON and as CSV + sidecar; seconds to load each into arrays and to import into the
scene, with the ratio to real time (600 s / seconds). Prints ONE JSON line.

Run from the repository root: `.venv/bin/python benchmarks/bench_import.py [--seconds 600]`.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import bpy  # noqa: E402
import numpy as np  # noqa: E402

from bodycal_addon.blender import recording_scene  # noqa: E402
from bodycal_addon.recording import io as recording_io  # noqa: E402
from bodycal_dev import synthetic  # noqa: E402


def make_recording(seconds: float, fps: float):
    """The whole calibration protocol and the motions, repeated to fill `seconds`, cut to length."""
    perf = synthetic.make_performer(height=1.75, build="average", seed=0)
    rec, _truth = synthetic.record_session(perf, profile="full", fps=fps, seed=0, dropout_rate=0.01,
                                           motion_seconds=seconds)
    n = int(round(seconds * fps))
    if rec.frame_count < n:
        raise SystemExit(f"synthetic session has {rec.frame_count} frames, {n} needed")
    rec.time, rec.positions, rec.rotations = rec.time[:n], rec.positions[:n], rec.rotations[:n]
    rec.valid = rec.valid[:n]
    rec.markers, rec.marker_valid = rec.markers[:n], rec.marker_valid[:n]
    rec.segments = [s for s in rec.segments if s.end <= rec.time[-1]]
    return rec


def timed(fn, repeat: int = 1):
    best, out = float("inf"), None
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=600.0)
    ap.add_argument("--fps", type=float, default=90.0)
    args = ap.parse_args()
    t = time.perf_counter()
    rec = make_recording(args.seconds, args.fps)
    generate_s = time.perf_counter() - t
    out = {"bench": "import", "recording_seconds": args.seconds, "fps": args.fps, "frames": rec.frame_count,
           "devices": len(rec.devices), "markers": len(rec.marker_names), "generate_s": round(generate_s, 2)}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = pathlib.Path(tmp)
        for fmt, name in (("json", "bench.bcrec.json"), ("csv", "bench.csv")):
            path = tmp / name
            write_s, _ = timed(lambda p=path: recording_io.save_recording(rec, p))
            load_s, loaded = timed(lambda p=path: recording_io.load_recording(p), repeat=2)
            assert loaded.frame_count == rec.frame_count
            assert np.allclose(loaded.positions[:, :len(rec.devices)][rec.valid],
                               rec.positions[rec.valid], atol=1e-5)
            out[f"{fmt}_mb"] = round(path.stat().st_size / 1e6, 1)
            out[f"{fmt}_write_s"] = round(write_s, 2)
            out[f"{fmt}_load_s"] = round(load_s, 3)
            out[f"{fmt}_realtime_ratio"] = round(args.seconds / load_s, 1)
        bpy.ops.wm.read_homefile(use_empty=True)
        scene_s, coll = timed(lambda: recording_scene.import_recording_to_scene(loaded, bpy.context.scene))
        keys = rec.frame_count * (8 * len(loaded.devices) + 4 * len(loaded.marker_names))
        out["scene_import_s"] = round(scene_s, 3)
        out["scene_keys"] = keys
        out["scene_keys_per_s"] = round(keys / scene_s)
        out["scene_realtime_ratio"] = round(args.seconds / scene_s, 1)
        rebuild_s, back = timed(lambda: recording_scene.recording_from_scene(bpy.context.scene))
        assert back.frame_count == rec.frame_count
        out["scene_rebuild_s"] = round(rebuild_s, 3)
    print(json.dumps(out))


if __name__ == "__main__":
    main()
