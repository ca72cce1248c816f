"""Reader resources benchmark: the peak memory of loading a long-format CSV recording as a
multiple of the file's size (tracemalloc in a fresh subprocess, so nothing else is counted), and the
time to load a JSON recording with 10k and with 40k devices and the ratio of the two (a linear
parser gives about 4; the quadratic one gave about 16), and the three-point kits' own files (the real
takes of sample_data/real_vr: an A-Frame motion capture, a Beat Saber replay): the time to read each
against the same take saved as a .bcrec.json, read in the same run. Only ratios within one run are
compared. Prints ONE JSON line, with `targets` for the three-point readers (the replay, binary, at
most half the JSON reader's time; the A-Frame JSON, 2.4 times the bytes with its key names, at most
4 times).

Run from the repository root: `.venv/bin/python benchmarks/bench_readers.py [--csv-mb 40]`.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import subprocess
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from bodycal_addon.recording import io as recording_io  # noqa: E402
from bodycal_addon.recording.model import Device, Recording  # noqa: E402

_MEASURE = """
import sys, resource


def peak_rss():
    # VmHWM: this process's own high-water mark (ru_maxrss carries the parent's across fork / exec).
    try:
        with open("/proc/self/status") as fh:
            return next(int(ln.split()[1]) for ln in fh if ln.startswith("VmHWM:"))
    except (OSError, StopIteration):
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss


sys.path.insert(0, {root!r})
from bodycal_addon.recording import io as recording_io
traced = {traced!r}
if traced:
    import tracemalloc
    tracemalloc.start()
rss0 = peak_rss()
rec = recording_io.load_recording({path!r})
rss1 = peak_rss()
peak = tracemalloc.get_traced_memory()[1] if traced else 0
print(peak, (rss1 - rss0) * 1024, rec.frame_count, len(rec.devices))
"""


def write_csv(path: pathlib.Path, megabytes: float, n_dev: int = 16, fps: float = 90.0) -> pathlib.Path:
    """A CSV + sidecar of about `megabytes`: `n_dev` trackers walking about the room, every
    50th frame of one tracker untracked (empty cells)."""
    row_bytes = 95  # measured: time, name and seven rounded floats
    frames = max(10, int(megabytes * 1e6 / row_bytes / n_dev))
    rng = np.random.default_rng(0)
    pos = 1.0 + np.cumsum(rng.normal(0, 0.002, (frames, n_dev, 3)), axis=0)
    q = rng.normal(0, 1, (frames, n_dev, 4))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    valid = np.ones((frames, n_dev), bool)
    valid[::50, 0] = False
    rec = Recording(name="bench", time=np.arange(frames) / fps,
                    devices=[Device(name=f"LHR-{k:04d}", kind="tracker", role=None) for k in range(n_dev)],
                    positions=pos, rotations=q, valid=valid, marker_names=[], markers=np.zeros((frames, 0, 3)),
                    marker_valid=np.zeros((frames, 0), bool), segments=[])
    recording_io.save_recording(rec, path)
    return path


def _measure(path: pathlib.Path, traced: bool) -> list[int]:
    code = _MEASURE.format(root=str(ROOT), path=str(path), traced=traced)
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout
    return [int(x) for x in out.split()]


def csv_memory(path: pathlib.Path) -> dict:
    """Peak of the allocations made while loading (tracemalloc: Python objects and numpy arrays), and
    separately, without tracemalloc's own overhead, the growth of the process's peak resident size."""
    peak, _, frames, devices = _measure(path, traced=True)
    _, rss, _, _ = _measure(path, traced=False)
    size = path.stat().st_size
    return {"csv_mb": round(size / 1e6, 1), "csv_frames": frames, "csv_devices": devices,
            "csv_peak_traced_mb": round(peak / 1e6, 1), "csv_peak_over_file": round(peak / size, 2),
            "csv_peak_rss_growth_over_file": round(rss / size, 2)}


def device_doc(n: int) -> dict:
    return {"format": "bodycal-recording", "version": 1, "coords": {"up": "Z", "handedness": "right", "units": "m"},
            "devices": [{"name": f"LHR-{k:06d}", "kind": "tracker", "role": None} for k in range(n)],
            "time": [0.0, 0.011],
            "poses": {f"LHR-{k:06d}": [[0.001 * (k % 1000), 1.0, 1.0, 1, 0, 0, 0], None] for k in range(n)}}


def device_seconds(tmp: pathlib.Path, n: int, repeat: int = 2) -> float:
    path = tmp / f"devices{n}.bcrec.json"
    path.write_text(json.dumps(device_doc(n)))
    best = float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        rec = recording_io.load_recording(path)
        best = min(best, time.perf_counter() - t)
        assert len(rec.devices) == n
    return best


def _best_seconds(path: pathlib.Path, repeat: int = 5) -> float:
    best = float("inf")
    for _ in range(repeat):
        t = time.perf_counter()
        recording_io.load_recording(path, raw=True)
        best = min(best, time.perf_counter() - t)
    return best


def three_point(tmp: pathlib.Path) -> tuple[dict, dict]:
    """Each real three-point take read by its reader, and saved as a .bcrec.json read by BodyCal's
    JSON reader: the times (raw reads: the readers alone, no post-processing) and their ratio."""
    data = ROOT / "sample_data" / "real_vr"
    out, ratios = {}, {}
    for key, path in (("aframe", data / "aframe_vive" / "tracked-recording.json"),
                      ("bsor", data / "beat_saber" / "xror_sample2.bsor")):
        rec = recording_io.load_recording(path, raw=True)
        same = tmp / f"{key}.bcrec.json"
        recording_io.save_recording(rec, same)
        own, as_json = _best_seconds(path), _best_seconds(same)
        ratios[key] = own / as_json
        out.update({f"{key}_frames": rec.frame_count, f"{key}_file_mb": round(path.stat().st_size / 1e6, 2),
                    f"{key}_ms": round(own * 1e3, 1), f"{key}_as_bcrec_json_ms": round(as_json * 1e3, 1),
                    f"{key}_over_bcrec_json": round(ratios[key], 2)})
    return out, {"bsor_at_most_half_the_json_readers_time": ratios["bsor"] <= 0.5,
                 "aframe_at_most_4x_the_json_readers_time": ratios["aframe"] <= 4.0}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--csv-mb", type=float, default=40.0, help="size of the CSV recording to read")
    ap.add_argument("--devices", type=int, nargs=2, default=(10_000, 40_000), metavar=("SMALL", "LARGE"))
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="bodycal-bench-readers-") as d:
        tmp = pathlib.Path(d)
        out = {"bench": "readers"}
        out.update(csv_memory(write_csv(tmp / "big.csv", args.csv_mb)))
        small, large = args.devices
        t_small, t_large = device_seconds(tmp, small), device_seconds(tmp, large)
        out.update({f"devices_{small}_s": round(t_small, 3), f"devices_{large}_s": round(t_large, 3),
                    "devices_time_ratio": round(t_large / t_small, 2), "devices_count_ratio": large / small})
        figures, targets = three_point(tmp)
        out.update(figures)
        out["targets"] = targets
    print(json.dumps(out))


if __name__ == "__main__":
    main()
