"""Live benchmark: one JSON line, a dict of sections (each built by its function in SECTIONS; more
sections join it later).

`stream`: a take of 10 devices (an HMD, two controllers, seven trackers) and 10 finger markers at
90 Hz is sent over loopback by `bodycal stream` in its own process, in real time, and received by
`VmcReceiver` + `LiveRecorder` here. Targets: no frame lost by the receiver, the recording equal to
the sent take (within OSC's float32), the receiver thread's CPU at most 10 % of one core
(`time.thread_time` of that thread over the take's length). Ten minutes by default; `--quick`
streams 30 s.

`blender`: the Live panel's session in background Blender (bodycal_addon/blender/live.py) while
`bodycal stream --loop` sends a synthetic full-profile take (15 devices with their roles, 16 markers)
at 90 Hz in its own process, pumped in three modes (`--modes`): `fixed`, a pump every 1/90 s
whatever the stream does (the loop before the pump's clock); `timer`, the UI timer's loop
(`live.pump_for(wake_on_arrival=False)`: the pump's clock, live/pump_clock.py, says when to
look, the loop sleeps until then); `event`, a headless station's loop (`pump_for`'s default: the
same clock, the sleep cut short by a frame's arrival); each mode's time is taken in `--rounds`
turns in rotation, so the load's drift falls on every mode alike. `no_avatar`: nobody follows, so a frame's
wait from its arrival to the pump taking it is the loop's scheduling alone. `one_avatar` and
`three_avatars`: procedural avatars following with the egocentric method, feet planted, root motion
on the root bone, solved in the pump's process; `three_avatars_processes`: the same three, each
solved in a worker process of its own (live/worker.py; `--rows` picks the rows). Latency:
every pose set, from the arrival (`LiveFrame.arrival`, the receiver's clock) of the frame the
avatar was solved from (the pump's own, or for an avatar solved in the pump's process after
another, the newest there was when its turn came, or the one a pump catching up gave it:
`LiveUpdate.frame_of`) to its pose set (`foreach_set` done): per avatar (`latency_ms_by_avatar`, in
the order they follow), `latency_ms` the slowest avatar's median and p95 (what the targets read),
`poses_per_s_per_avatar` the fewest poses an avatar got a second; over the pumps that set every
avatar, the slowest avatar's (`latency_ms_pumps_setting_every_avatar`) and the stages: arrival ->
taken by the pump (the pump's first frame; also over the frames that found the pump idle, and the
share of those), taken -> the last avatar solved (from when its frame was taken; the earlier
avatars' writes included: each is set as soon as it is solved), solved -> posed; per
avatar the solve and the write (wall and the main thread's CPU time; a worker's solve: wall from
the frame sent to its answer, CPU the worker's, and `worker_wall` its own push); the CPU time on
the path (the solves and writes, whichever process did them), the pump thread's own CPU (solves
here, hand-overs to the workers, writes) and the critical path (the pump thread's plus the longest
worker solve: the workers side by side on cores of their own); and how far behind the sender's
beat the receiver stamped the arrival (`arrival - sender time`, less its least value: the
receiver's thread waits for the GIL while a solve runs in its process, and that wait is before the
arrival stamp, so outside the latency measured).
`summary`: the p95s, and what a machine with the cores free would see (`_summary`). Targets: p95 <=
11.1 ms (one frame) with one avatar, <= 22.2 ms with three; write <= 1 ms per avatar. `memory`:
`--minutes` (default 3; the issue's figure is 10) of one avatar following while the take is
recorded: the process's resident memory growth from the end of a 10 s warm-up to the end, with
what the recorder and the solver's frame buffer hold (both grow with the take: "the recording
itself"), and frames lost to the recording (sent by the stream, not in the recorder). Target:
growth besides those <= 50 MB, no frame lost. Wall-clock figures on a shared machine carry the
other processes' time: the CPU figures and the scheduling wait with no solve are what hold.

Run from the repository root: `.venv/bin/python benchmarks/bench_live.py [--quick] [--seconds S]
[--sections stream blender] [--modes fixed timer event] [--rounds N] [--minutes M]
[--rows one_avatar three_avatars three_avatars_processes]`.
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):  # one core per solve, as measured
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import pathlib  # noqa: E402
import resource  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402

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


def _rss_mb() -> float:
    for line in pathlib.Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def _pct(values, q) -> float:
    return round(float(np.percentile(values, q)), 2) if len(values) else float("nan")


def _stage(values) -> dict:
    return {"median": _pct(values, 50), "p95": _pct(values, 95)}


PUMP_MODES = ("fixed", "timer", "event")  # how the loop decides when to pump (module docstring)
ROWS = ("one_avatar", "three_avatars", "three_avatars_processes")  # who follows (module docstring)


def _run(live, seconds: float, mode: str, note) -> None:
    """The pump's loop for `seconds` in `mode`, `note(update)` after each frame pumped."""
    if mode == "fixed":  # the loop before the clock: a pump every 1/90 s whatever the stream does
        tick, end = 1.0 / FPS, time.perf_counter() + seconds
        due = time.perf_counter()
        while time.perf_counter() < end:
            update = live.pump_once()
            if update is not None:
                note(update)
            due += tick
            time.sleep(max(0.0, due - time.perf_counter()))
    else:
        live.pump_for(seconds, wake_on_arrival=mode == "event", on_update=note)


class _Frames:
    """The frames one mode pumped, over one or more runs: per frame with every avatar posed,
    arrival -> the last avatar's pose set (ms) and its stages, each avatar's solve and write (wall
    and CPU ms). With no avatar (`names` empty) only arrival -> taken: the loop's scheduling alone
    (no solve in progress for a frame to wait for)."""

    def __init__(self, live, names: list[str]):
        self.live, self.names = live, names
        self.rows = {k: [] for k in ("latency", "wait", "solve", "write", "cpu_path", "cpu_pump", "cpu_critical",
                                     "wait_idle", "stamp")}
        self.per_avatar = {k: [] for k in ("solve", "solve_cpu", "write", "write_cpu", "worker_wall")}
        self.by_avatar = {n: [] for n in names}  # every pose set: its frame's arrival -> set (ms)
        self.cpu = self.wall = 0.0
        self.loads = []
        self.last_done = -np.inf  # when the previous pump ended: a frame arriving after it found the pump idle

    def run(self, seconds: float, mode: str) -> None:
        c0, w0, self.last_done = time.thread_time(), time.perf_counter(), -np.inf
        _run(self.live, seconds, mode, self.note)
        self.cpu += time.thread_time() - c0
        self.wall += time.perf_counter() - w0
        self.loads.append(os.getloadavg()[0])

    def note(self, update) -> None:
        rows, names = self.rows, self.names
        if not names:
            rows["wait"].append((update.taken - update.frame.arrival) * 1000.0)
            return
        for n in names:  # every pose set, whether the pump set the others' or not (catching up)
            if n in update.posed_at:
                self.by_avatar[n].append((update.posed_at[n] - update.frame_of(n).arrival) * 1000.0)
        if not all(update.poses.get(n) is not None for n in names):
            return  # the stages below: pumps that set every avatar's pose
        session, following = self.live.session(), self.live.following()
        order = sorted(names, key=update.posed_at.get)  # as solved and set
        rows["latency"].append(max((update.posed_at[n] - update.frame_of(n).arrival) * 1000.0 for n in names))
        first = update.frame_of(order[0])  # the pump's own frame (a later avatar may have a newer one)
        arrival = first.arrival
        rows["wait"].append((update.taken - arrival) * 1000.0)
        if arrival >= self.last_done:  # the scheduling's own wait, not the rest of a solve in progress
            rows["wait_idle"].append((update.taken - arrival) * 1000.0)
        self.last_done = time.perf_counter()
        if first.sender_time is not None:
            rows["stamp"].append((arrival - first.sender_time) * 1000.0)
        rows["solve"].append((update.solved_at[order[-1]] - update.taken_at[order[-1]]) * 1000.0)
        rows["write"].append((update.posed_at[order[-1]] - update.solved_at[order[-1]]) * 1000.0)
        solve_cpu = [session.followers[n].stats.solve_cpu_ms[-1] for n in names]
        write_cpu = [following[n].write_cpu_ms[-1] for n in names]
        rows["cpu_path"].append(sum(solve_cpu) + sum(write_cpu))  # all the work, whichever process did it
        rows["cpu_pump"].append(update.cpu_ms)  # the pump's thread: solves here, hand-overs, writes
        in_workers = [c for n, c in zip(names, solve_cpu, strict=True) if session.followers[n].in_worker]
        rows["cpu_critical"].append(update.cpu_ms + max(in_workers, default=0.0))  # the workers side by side
        self.per_avatar["worker_wall"] += [session.followers[n].stats.worker_ms[-1] for n in names
                                           if session.followers[n].in_worker]
        self.per_avatar["solve"] += [session.followers[n].stats.solve_ms[-1] for n in names]
        self.per_avatar["solve_cpu"] += solve_cpu
        self.per_avatar["write"] += [following[n].write_ms[-1] for n in names]
        self.per_avatar["write_cpu"] += write_cpu

    def report(self) -> dict:
        rows, n = self.rows, len(self.rows["wait"])
        load = round(float(np.mean(self.loads)), 2) if self.loads else float("nan")
        if not self.names:
            return {"frames": n, "arrival_to_taken_ms": _stage(rows["wait"]), "load_average": load}
        stamp = np.asarray(rows["stamp"]) - (min(rows["stamp"]) if rows["stamp"] else 0.0)
        by_avatar = [_stage(self.by_avatar[name]) for name in self.names]
        poses = min(len(v) for v in self.by_avatar.values())
        return {"frames": n, "poses_per_s_per_avatar": round(poses / max(self.wall, 1e-9), 1),
                "latency_ms": {"median": max(b["median"] for b in by_avatar), "p95": max(b["p95"] for b in by_avatar)},
                "latency_ms_by_avatar": by_avatar,
                "latency_ms_pumps_setting_every_avatar": _stage(rows["latency"]),
                "stages_ms": {"arrival_to_taken": _stage(rows["wait"]), "taken_to_solved": _stage(rows["solve"]),
                              "solved_to_posed": _stage(rows["write"]),
                              "arrival_to_taken_pump_idle": _stage(rows["wait_idle"]),
                              "frames_arriving_pump_idle_percent": round(100.0 * len(rows["wait_idle"]) / max(n, 1), 1),
                              "arrival_behind_sender_beat": _stage(stamp)},
                "cpu_ms_on_the_path": _stage(rows["cpu_path"]),
                "cpu_ms_pump_thread": _stage(rows["cpu_pump"]),
                "cpu_ms_critical_path": _stage(rows["cpu_critical"]),
                "per_avatar_ms": {k: _stage(v) for k, v in self.per_avatar.items() if v},
                "pump_thread_cpu_percent": round(100.0 * self.cpu / max(self.wall, 1e-9), 1),
                "load_average": load}


def _pump_for(live, seconds: float, names: list[str], mode: str = "event") -> dict:
    frames = _Frames(live, names)
    frames.run(seconds, mode)
    return frames.report()


def _alternated(live, seconds: float, names: list[str], modes, rounds: int) -> dict:
    """Each mode for `seconds` in all, in `rounds` turns taken in rotation, so that the load's
    drift over the run falls on every mode alike."""
    frames = {m: _Frames(live, names) for m in modes}
    for r in range(rounds):
        for m in modes[r % len(modes):] + modes[:r % len(modes)]:
            frames[m].run(seconds / rounds, m)
    return {m: frames[m].report() for m in modes}


def _summary(out: dict) -> dict:
    """The headline figures: arrival -> pose p95 as measured (each mode), and what a machine with
    the cores free would see: the loop's scheduling wait with no solve in the way (`no_avatar`)
    plus the CPU time on the critical path (the pump's thread, and the longest worker's solve when
    the avatars solve in worker processes side by side, one core each), plus a period when that
    path is longer than a period (the pump then cannot keep up: the newest frame, taken when it is
    free, came up to a period before). For avatars solved one after the other in the pump's process
    it is a bound, not an estimate: each after the first takes the newest frame when its turn comes."""
    summary = {}
    for key in ("one_avatar", "three_avatars", "three_avatars_processes"):
        for mode, r in out.get(key, {}).items():
            summary[f"{key}_p95_ms_{mode}"] = r["latency_ms"]["p95"]
            sched = out["no_avatar"][mode]["arrival_to_taken_ms"]
            cpu = r["cpu_ms_critical_path"]
            behind = 1000.0 / FPS if cpu["median"] > 1000.0 / FPS else 0.0
            summary[f"{key}_p95_ms_{mode}_cores_free_estimate"] = round(sched["p95"] + cpu["p95"] + behind, 1)
        if out.get(key):
            summary[f"{key}_write_cpu_ms_per_avatar_p95"] = max(r["per_avatar_ms"]["write_cpu"]["p95"]
                                                                for r in out[key].values())
    return summary


def blender_section(args) -> dict:
    import signal

    import bpy

    from bodycal_addon.blender import live
    from bodycal_dev import synthetic
    from sample_rigs import build_procedural_avatar

    seconds = args.seconds or (10.0 if args.quick else 30.0)
    performer = synthetic.make_performer(seed=1)
    take, truth = synthetic.record_session(performer, profile="full", motions=("walk_in_place", "clap"),
                                           calibration=["tpose"], seed=1)
    folder = pathlib.Path(tempfile.mkdtemp(prefix="bodycal-bench-live-blender-"))
    save_recording(take, folder / "take.bcrec.json", up="Z")
    user = truth.body_model()
    bpy.ops.wm.read_homefile(use_empty=True)
    arms = [build_procedural_avatar(name=f"avatar{k}", scale=s)[0] for k, s in enumerate((1.0, 0.9, 1.1))]
    for k, arm in enumerate(arms):
        arm.location.x = 1.5 * k
    live.connect(0, timer=False)
    sender = subprocess.Popen([sys.executable, "-m", "bodycal_addon", "stream", str(folder / "take.bcrec.json"),
                               "--port", str(live.port()), "--loop"], cwd=ROOT, stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
    out = {"seconds_each": seconds, "devices": len(take.devices), "markers": len(take.marker_names),
           "stream_hz": round(take.fps, 1)}
    try:
        _pump_for(live, 2.0, [])  # warm-up: the empties made
        out["no_avatar"] = _alternated(live, seconds, [], args.modes, args.rounds)
        rows = (("one_avatar", arms[:1], False), ("three_avatars", arms, False),
                ("three_avatars_processes", arms, True))
        for key, avatars, worker in rows:
            if key not in args.rows:
                continue
            for arm in avatars:
                follower = live.session().followers.get(arm.name)
                if follower is None or follower.in_worker != worker:
                    live.follow(arm, user, "egocentric", worker=worker)
            names = [a.name for a in avatars]
            deadline = time.perf_counter() + 60.0
            while any(live.session().followers[n].state != "running" for n in names):  # the workers started
                assert time.perf_counter() < deadline, [live.session().followers[n].state for n in names]
                live.pump_for(0.1)
            _pump_for(live, 3.0, names)  # warm-up: the solvers prepared, the stances found
            out[key] = _alternated(live, seconds, names, args.modes, args.rounds)
        out["targets"] = {"one_avatar_p95_ms": 11.1, "three_avatars_p95_ms": 22.2, "write_ms_per_avatar": 1.0}
        out["cores"] = os.cpu_count()
        out["summary"] = _summary(out)
        live.stop_following()
        if args.minutes:
            live.follow(arms[0], user, "egocentric")
            recorder = live.start_recording("bench")
            _pump_for(live, 10.0, [arms[0].name])
            rss0, buf0, rec0 = _rss_mb(), live.session().followers[arms[0].name].solver.recording.nbytes, \
                recorder.nbytes
            _pump_for(live, args.minutes * 60.0, [arms[0].name])
            sender.send_signal(signal.SIGINT)
            sent_out, _ = sender.communicate(timeout=30)
            for _ in range(50):  # what is still in flight
                live.pump_once()
                time.sleep(0.01)
            rss1 = _rss_mb()
            buf1 = live.session().followers[arms[0].name].solver.recording.nbytes
            grown_recordings = (buf1 - buf0 + recorder.nbytes - rec0) / 2 ** 20
            sent = int(sent_out.rsplit("sent ", 1)[1].split()[0]) if "sent " in sent_out else -1
            session = live.session()
            while_recording = session.frames_seen - session.recording_from
            out["memory"] = {"minutes": args.minutes, "rss_growth_mb": round(rss1 - rss0, 1),
                             "recorder_and_solver_buffer_growth_mb": round(grown_recordings, 1),
                             "growth_besides_recordings_mb": round(rss1 - rss0 - grown_recordings, 1),
                             "target_mb": 50, "frames_received_while_recording": while_recording,
                             "frames_recorded": recorder.frames,
                             "frames_lost_to_recording": while_recording - recorder.frames,
                             "frames_sent_whole_run": sent, "frames_lost_by_receiver": sent - session.frames_seen,
                             "frames_the_pump_skipped": session.stats.dropped}
    finally:
        if sender.poll() is None:
            sender.send_signal(signal.SIGINT)
            sender.communicate(timeout=30)
        live.disconnect()
    return out


# name -> function(parsed arguments) -> the section's dict
SECTIONS = {"stream": stream_section, "blender": blender_section}


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="a short run while iterating (stream: 30 s, not 10 minutes)")
    p.add_argument("--seconds", type=float, default=None, help="the stream's length (overrides --quick)")
    p.add_argument("--sections", nargs="*", default=list(SECTIONS), choices=list(SECTIONS))
    p.add_argument("--modes", nargs="*", default=list(PUMP_MODES), choices=PUMP_MODES,
                   help="blender: the pump loops measured (fixed 90 Hz, the timer's clock, woken by arrivals)")
    p.add_argument("--rounds", type=int, default=4, help="blender: each mode's time in this many turns, in rotation")
    p.add_argument("--rows", nargs="*", default=list(ROWS), choices=ROWS,
                   help="blender: the avatar rows measured (no_avatar always, for the scheduling wait)")
    p.add_argument("--minutes", type=float, default=3.0,
                   help="blender: the memory run's length (the issue's figure is 10 minutes; 0 skips it)")
    args = p.parse_args()
    print(json.dumps({name: SECTIONS[name](args) for name in args.sections}))


if __name__ == "__main__":
    main()
