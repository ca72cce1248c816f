"""Live benchmark: one JSON line, a dict of sections (each built by its function in SECTIONS; more
sections join it later).

`stream`: a take of 10 devices (an HMD, two controllers, seven trackers) and 10 finger markers at
90 Hz is sent over loopback by `bodycal stream` in its own process, in real time, and received by
`VmcReceiver` + `LiveRecorder` here. Targets: no frame lost by the receiver, the recording equal to
the sent take (within OSC's float32), the receiver thread's CPU at most 10 % of one core
(`time.thread_time` of that thread over the take's length). Ten minutes by default; `--quick`
streams 30 s.

Run from the repository root: `.venv/bin/python benchmarks/bench_live.py [--quick] [--seconds S]`.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import resource
import subprocess
import sys
import tempfile
import time

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from bodycal_addon.core import transforms as tf  # noqa: E402
from bodycal_addon.recording.io import load_recording, save_recording  # noqa: E402
from bodycal_addon.recording.live.receiver import VmcReceiver  # noqa: E402
from bodycal_addon.recording.live.recorder import LiveRecorder  # noqa: E402
from bodycal_addon.recording.model import Device, Recording  # noqa: E402

FPS = 90.0
F32 = 2.0 ** -23
KINDS = ["hmd", "controller", "controller"] + ["tracker"] * 7
FINGERS = [f"{f}_tip_{s}" for s in ("l", "r") for f in ("thumb", "index", "middle", "ring", "pinky")]


def make_take(seconds: float) -> Recording:
    """Devices and markers swaying about the room (a few dropouts), quaternions turning smoothly."""
    n = int(round(seconds * FPS))
    t = np.arange(n) / FPS
    rng = np.random.default_rng(0)
    d = len(KINDS)
    base = rng.uniform([-0.5, -0.5, 0.1], [0.5, 0.5, 1.7], (d, 3))
    pos = base + 0.2 * np.sin(t[:, None, None] * rng.uniform(0.5, 2.0, (d, 3)) + rng.uniform(0, 6, (d, 3)))
    axis = rng.normal(size=(d, 3))
    rot = tf.axis_angle_to_quat(np.broadcast_to(axis, (n, d, 3)), np.sin(t[:, None] * rng.uniform(0.3, 1.0, d)))
    valid = rng.random((n, d)) > 0.001
    m = len(FINGERS)
    sway = 0.05 * np.sin(t[:, None, None] * 3.0 + np.arange(m)[:, None])
    pts = rng.uniform([-0.6, -0.6, 0.8], [0.6, 0.6, 1.5], (m, 3)) + sway
    devices = [Device(f"LHR-{k:08X}", kind) for k, kind in enumerate(KINDS)]
    return Recording("bench_live", t, devices, pos, rot, valid, list(FINGERS), pts, rng.random((n, m)) > 0.002)


def compare(again: Recording, take: Recording) -> dict:
    """Whether the recording equals the take within float32, and the worst differences."""
    same_shape = again.frame_count == take.frame_count and [d.name for d in again.devices] == \
        [d.name for d in take.devices] and again.marker_names == take.marker_names
    if not same_shape:
        return {"equal": False, "frames_recorded": again.frame_count}
    v, mv = take.valid, take.marker_valid
    dt = np.abs(again.time - take.time) - F32 * np.abs(take.time)
    dp = np.abs(again.positions[v] - take.positions[v]) - F32 * np.abs(take.positions[v])
    dq = np.abs(again.rotations[v] - take.rotations[v])
    dm = np.abs(again.markers[mv] - take.markers[mv]) - F32 * np.abs(take.markers[mv])
    masks = bool((again.valid == v).all() and (again.marker_valid == mv).all())
    worst = {"time_s": float(dt.max()), "position_m": float(dp.max()), "quaternion": float(dq.max()),
             "marker_m": float(dm.max())}
    equal = masks and worst["time_s"] <= 1e-9 and worst["position_m"] <= 2e-7 and worst["quaternion"] <= 3e-7 \
        and worst["marker_m"] <= 2e-7
    return {"equal": equal, "tracked_masks_equal": masks,
            "worst_beyond_float32": {k: float(f"{x:.3g}") for k, x in worst.items()}}


def stream_section(args) -> dict:
    take = make_take(args.seconds or (30.0 if args.quick else 600.0))
    folder = pathlib.Path(tempfile.mkdtemp(prefix="bodycal-bench-live-"))
    path = folder / "take.bcrec.json"
    save_recording(take, path, up="Z")
    take = load_recording(path, raw=True)  # what the sender reads
    receiver = VmcReceiver(port=0)
    recorder = LiveRecorder("again")
    receiver.add_sink(recorder)
    receiver.start()
    usage0 = resource.getrusage(resource.RUSAGE_SELF)
    t0 = time.perf_counter()
    sender = subprocess.run([sys.executable, "-m", "bodycal_addon", "stream", str(path), "--port", str(receiver.port)],
                            cwd=ROOT, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    time.sleep(0.5)
    receiver.stop()
    usage1 = resource.getrusage(resource.RUSAGE_SELF)
    again = recorder.recording()
    sent = int(sender.stdout.rsplit("sent ", 1)[1].split()[0]) if "sent " in sender.stdout else 0
    cpu = receiver.stats.cpu_seconds
    duration = float(take.time[-1] - take.time[0])
    return {
        "seconds": round(duration, 2), "fps": FPS, "devices": len(take.devices), "markers": len(take.marker_names),
        "frames_sent": sent, "frames_received": again.frame_count, "frames_lost": sent - again.frame_count,
        "frames_lost_target": 0, **compare(again, take),
        "receiver_cpu_percent": round(100 * cpu / duration, 2), "receiver_cpu_target_percent": 10,
        "receiver_process_cpu_percent": round(100 * ((usage1.ru_utime + usage1.ru_stime)
                                                     - (usage0.ru_utime + usage0.ru_stime)) / wall, 2),
        "datagrams": receiver.stats.datagrams, "bad": receiver.stats.bad_datagrams + receiver.stats.bad_messages,
        "sender_exit": sender.returncode, "sender_last_line": sender.stdout.strip().splitlines()[-1:],
    }


# name -> function(parsed arguments) -> the section's dict
SECTIONS = {"stream": stream_section}


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="a short run while iterating (stream: 30 s, not 10 minutes)")
    p.add_argument("--seconds", type=float, default=None, help="the stream's length (overrides --quick)")
    p.add_argument("--sections", nargs="*", default=list(SECTIONS), choices=list(SECTIONS))
    args = p.parse_args()
    print(json.dumps({name: SECTIONS[name](args) for name in args.sections}))


if __name__ == "__main__":
    main()
