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
at 90 Hz in its own process, pumped in the loops `--modes` names: `timer`, the UI timer's loop
(`live.pump_for(wake_on_arrival=False)`: the session's clock, live/pump_clock.py, says when to
look, the loop sleeps until then), `event`, a headless station's loop (`pump_for`'s default: the
sleep cut short by a frame or a pose), and `fixed`, a pump every 1/90 s whatever the stream does
(the loop before the clock); each mode's time is taken in `--rounds` turns in rotation, so the
load's drift falls on every mode alike. `no_avatar`: nobody follows, so a frame's wait from its
arrival to the pump taking it is the loop's scheduling alone. The rows (`--rows`): `one_avatar` and
`three_avatars`, procedural avatars following with the egocentric method, feet planted, root motion
on the root bone, each solved in a worker process of its own (the default); `one_avatar_thread` and
`three_avatars_thread`, the same solved on the session's solving thread in Blender's process (the
design measured against). Per row and mode, against the stream's own rate (`stream_hz`, the frames
it made over the run), ratios that hold on any machine:
- `poses_ratio`: the fewest poses an avatar got a second over the stream's frames a second (targets
  0.95 for one avatar, 0.9 for three);
- `latency_p95_over_bound`: the slowest avatar's latency p95 (a frame's arrival, the receiver's
  clock, to its pose set with `foreach_set`) over its solve's p95 (where it ran: a worker's own
  push, else the thread's solve, wall) plus one stream frame (target <= 1);
- `main_thread_share_per_avatar`: the main thread's CPU time (the pumps: the poses' writes, the
  empties, the wizard; this bench's own bookkeeping taken out) over the wall time, per avatar
  (target <= 0.15), and `main_thread_ms_per_frame`;
and beside them this machine's milliseconds per avatar: the latency's stages (arrival -> handed to
its solver -> solved -> set), the solve (wall, CPU where it ran, a worker's own push), the write
(wall and CPU), the frames it did not show (`frames_skipped` of `frames_offered`). `memory`:
`--minutes` (default 3; the issue's figure is 10) of one avatar following in its worker while the
take is recorded: resident memory growth of this process and the worker's, besides the frames the
recorder and the worker's solver keep (both grow with the take), and the frames lost (target:
growth <= 50 MB, none lost). `targets` says each met or not. Wall-clock figures on a shared machine
carry the other processes' time: run when `uptime` is low, and read `load_average`.

Run from the repository root: `.venv/bin/python benchmarks/bench_live.py [--quick] [--seconds S]
[--sections stream blender] [--modes fixed timer event] [--rounds N] [--minutes M]
[--rows one_avatar three_avatars one_avatar_thread three_avatars_thread]`.
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
    equal = compare(again, take)
    return {
        "targets": {"no_frame_lost": sent == again.frame_count, "recording_equals_take": equal["equal"],
                    "receiver_cpu_within_10_percent": 100 * cpu / duration <= 10},
        "seconds": round(duration, 2), "fps": FPS, "devices": len(take.devices), "markers": len(take.marker_names),
        "frames_sent": sent, "frames_received": again.frame_count, "frames_lost": sent - again.frame_count,
        "frames_lost_target": 0, **equal,
        "receiver_cpu_percent": round(100 * cpu / duration, 2), "receiver_cpu_target_percent": 10,
        "receiver_process_cpu_percent": round(100 * ((usage1.ru_utime + usage1.ru_stime)
                                                     - (usage0.ru_utime + usage0.ru_stime)) / wall, 2),
        "datagrams": receiver.stats.datagrams, "bad": receiver.stats.bad_datagrams + receiver.stats.bad_messages,
        "sender_exit": sender.returncode, "sender_last_line": sender.stdout.strip().splitlines()[-1:],
    }


def _rss_mb(pid: int | str = "self") -> float:
    for line in pathlib.Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0
    return float("nan")


def _pct(values, q) -> float:
    return round(float(np.percentile(values, q)), 2) if len(values) else float("nan")


def _stage(values) -> dict:
    return {"median": _pct(values, 50), "p95": _pct(values, 95)}


PUMP_MODES = ("fixed", "timer", "event")  # how the loop decides when to pump (module docstring)
TARGET_MODES = ("timer", "event")  # the loops the targets read (the Live panel's timer, a headless station's)
# who follows: (avatars, solved in worker processes)
ROWS = {"one_avatar": (1, True), "three_avatars": (3, True), "one_avatar_thread": (1, False),
        "three_avatars_thread": (3, False)}
TARGETS = {"poses_ratio_one": 0.95, "poses_ratio_three": 0.9, "latency_over_bound": 1.0,
           "main_thread_share_per_avatar": 0.15, "memory_growth_besides_recordings_mb": 50.0}


def _run(live, seconds: float, mode: str, note) -> None:
    """The pump's loop for `seconds` in `mode`, `note(update)` after each update pumped."""
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
    """What one mode's pumps brought, over one or more runs: per avatar, every pose set with its
    stages (arrival -> handed to its solver -> solved -> set), the solve (wall and CPU where it ran;
    a worker's own push), the write (wall and the main thread's CPU); the frames the stream made
    and the ones each avatar did not show; the main thread's CPU time besides this bench's own
    bookkeeping. With no avatar (`names` empty) only arrival -> taken: the loop's scheduling alone."""

    def __init__(self, live, names: list[str]):
        self.live, self.names = live, names
        self.wait = []  # no avatar: arrival -> taken by the pump
        self.by_avatar = {n: {k: [] for k in ("latency", "to_handed", "handed_to_solved", "solved_to_posed", "solve",
                                              "solve_cpu", "worker_wall", "write", "write_cpu")} for n in names}
        self.cpu = self.wall = self.note_cpu = 0.0
        self.frames = 0  # frames the stream made while this mode ran
        self.counts = {n: [0, 0] for n in names}  # frames offered, frames not shown
        self.loads = []

    def run(self, seconds: float, mode: str) -> None:
        session = self.live.session()
        seen0 = session.frames_seen
        before = {n: self._counts(n) for n in self.names}
        c0, w0 = time.thread_time(), time.perf_counter()
        _run(self.live, seconds, mode, self.note)
        self.cpu += time.thread_time() - c0
        self.wall += time.perf_counter() - w0
        self.frames += session.frames_seen - seen0
        for n in self.names:
            after = self._counts(n)
            self.counts[n] = [c + a - b for c, a, b in zip(self.counts[n], after, before[n], strict=True)]
        self.loads.append(os.getloadavg()[0])

    def _counts(self, name: str) -> tuple[int, int]:
        stats = self.live.session().followers[name].stats
        return stats.handed + stats.skipped, stats.not_shown

    def note(self, update) -> None:
        c0 = time.thread_time()
        if not self.names:
            if update.frame is not None:
                self.wait.append((update.taken - update.frame.arrival) * 1000.0)
        else:
            session, following = self.live.session(), self.live.following()
            for n in self.names:
                if n not in update.posed_at:
                    continue
                rows, stats, frame = self.by_avatar[n], session.followers[n].stats, update.frame_of(n)
                rows["latency"].append((update.posed_at[n] - frame.arrival) * 1000.0)
                rows["to_handed"].append((update.taken_at[n] - frame.arrival) * 1000.0)
                rows["handed_to_solved"].append((update.solved_at[n] - update.taken_at[n]) * 1000.0)
                rows["solved_to_posed"].append((update.posed_at[n] - update.solved_at[n]) * 1000.0)
                rows["solve"].append(stats.solve_ms[-1])
                rows["solve_cpu"].append(stats.solve_cpu_ms[-1])
                if session.followers[n].in_worker:
                    rows["worker_wall"].append(stats.worker_ms[-1])
                rows["write"].append(following[n].write_ms[-1])
                rows["write_cpu"].append(following[n].write_cpu_ms[-1])
        self.note_cpu += time.thread_time() - c0

    def report(self) -> dict:
        load = round(float(np.mean(self.loads)), 2) if self.loads else float("nan")
        wall = max(self.wall, 1e-9)
        if not self.names:
            return {"frames": len(self.wait), "arrival_to_taken_ms": _stage(self.wait), "load_average": load}
        stream_hz = self.frames / wall
        period_ms = 1000.0 / stream_hz if stream_hz else float("nan")
        per = []
        for n in self.names:
            rows = self.by_avatar[n]
            solve_where = rows["worker_wall"] or rows["solve"]  # the solve where it runs (a worker's own push)
            bound = _pct(solve_where, 95) + period_ms
            offered, not_shown = self.counts[n]
            per.append({"poses_per_s": round(len(rows["latency"]) / wall, 1),
                        "latency_ms": _stage(rows["latency"]), "solve_p95_plus_frame_ms": round(bound, 2),
                        "latency_p95_over_bound": round(_pct(rows["latency"], 95) / bound, 3),
                        "frames_skipped": not_shown, "frames_offered": offered,
                        **{k: _stage(v) for k, v in rows.items() if k != "latency" and v}})
        main_cpu = self.cpu - self.note_cpu
        return {"frames": self.frames, "stream_hz": round(stream_hz, 2),
                "poses_ratio": round(min(p["poses_per_s"] for p in per) / stream_hz, 3) if stream_hz else 0.0,
                "latency_p95_over_bound": max(p["latency_p95_over_bound"] for p in per),
                "latency_ms": {"median": max(p["latency_ms"]["median"] for p in per),
                               "p95": max(p["latency_ms"]["p95"] for p in per)},
                "main_thread_share": round(main_cpu / wall, 3),
                "main_thread_share_per_avatar": round(main_cpu / wall / len(self.names), 3),
                "main_thread_ms_per_frame": round(1000.0 * main_cpu / max(self.frames, 1), 3),
                "by_avatar": per, "load_average": load}


def _alternated(live, seconds: float, names: list[str], modes, rounds: int) -> dict:
    """Each mode for `seconds` in all, in `rounds` turns taken in rotation, so that the load's
    drift over the run falls on every mode alike."""
    frames = {m: _Frames(live, names) for m in modes}
    for r in range(rounds):
        for m in modes[r % len(modes):] + modes[:r % len(modes)]:
            frames[m].run(seconds / rounds, m)
    return {m: frames[m].report() for m in modes}


def _targets(out: dict) -> dict:
    """Each target met or not, over the loops the targets read (every one measured must meet it)."""
    targets = {}
    for row, key, limit in (("one_avatar", "poses_ratio", TARGETS["poses_ratio_one"]),
                            ("three_avatars", "poses_ratio", TARGETS["poses_ratio_three"])):
        modes = [r for m, r in out.get(row, {}).items() if m in TARGET_MODES]
        if modes:
            targets[f"{row}_poses_ratio"] = all(r[key] >= limit for r in modes)
    for row in ("one_avatar", "three_avatars"):
        modes = [r for m, r in out.get(row, {}).items() if m in TARGET_MODES]
        if modes:
            targets[f"{row}_latency_p95_within_solve_p95_plus_frame"] = all(
                r["latency_p95_over_bound"] <= TARGETS["latency_over_bound"] for r in modes)
            targets[f"{row}_main_thread_share_per_avatar"] = all(
                r["main_thread_share_per_avatar"] <= TARGETS["main_thread_share_per_avatar"] for r in modes)
    memory = out.get("memory")
    if memory:
        targets["memory_growth_besides_recordings"] = memory["growth_besides_recordings_mb"] <= \
            TARGETS["memory_growth_besides_recordings_mb"]
        targets["memory_no_frame_lost"] = memory["frames_lost_to_recording"] == 0 and \
            memory["frames_lost_by_receiver"] == 0
    return targets


def _recorded_mb(recorder) -> float:
    """What the recorder's arrays hold: grown by doubling and filled when grown (np.full, np.resize),
    so all of it is resident (the worker's solver grows its arrays with np.zeros, whose pages are
    resident once written: the bytes of its frames, `FollowerStats.worker_memory`)."""
    return recorder.nbytes / 2 ** 20


def _memory(live, arm, user, sender, minutes: float) -> dict:
    """`minutes` of one avatar following (in its worker process) while the take is recorded: the
    resident memory's growth, this process's and the worker's, besides what the recorder and the
    worker's solver keep (both grow with the take: `_recorded_mb`), and the frames lost."""
    import signal

    live.follow(arm, user, "egocentric")
    follower = live.session().followers[arm.name]
    deadline = time.perf_counter() + 60.0
    while follower.state != "running":
        assert time.perf_counter() < deadline, follower.state
        live.pump_for(0.1)
    recorder = live.start_recording("bench")
    live.pump_for(10.0)
    pid = follower.process.pid
    rss0, worker0, rec0, kept0 = _rss_mb(), _rss_mb(pid), _recorded_mb(recorder), follower.stats.worker_memory[0]
    live.pump_for(minutes * 60.0)
    rss1, worker1, rec1, kept1 = _rss_mb(), _rss_mb(pid), _recorded_mb(recorder), follower.stats.worker_memory[0]
    sender.send_signal(signal.SIGINT)
    sent_out, _ = sender.communicate(timeout=30)
    live.pump_for(0.5)  # what is still in flight
    grown_recordings = rec1 - rec0 + (kept1 - kept0) / 2 ** 20
    sent = int(sent_out.rsplit("sent ", 1)[1].split()[0]) if "sent " in sent_out else -1
    session = live.session()
    while_recording = session.frames_seen - session.recording_from
    grown = rss1 - rss0 + worker1 - worker0
    return {"minutes": minutes, "rss_growth_mb": round(rss1 - rss0, 1),
            "worker_rss_growth_mb": round(worker1 - worker0, 1),
            "recorded_frames_growth_mb": round(grown_recordings, 1),
            "growth_besides_recordings_mb": round(grown - grown_recordings, 1),
            "target_mb": TARGETS["memory_growth_besides_recordings_mb"],
            "frames_received_while_recording": while_recording, "frames_recorded": recorder.frames,
            "frames_lost_to_recording": while_recording - recorder.frames,
            "frames_sent_whole_run": sent, "frames_lost_by_receiver": sent - session.frames_seen,
            "frames_the_avatar_skipped": follower.stats.not_shown,
            "frames_offered_to_the_avatar": follower.stats.handed + follower.stats.skipped}


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
           "take_hz": round(take.fps, 1), "cores": os.cpu_count(), "load_average_start": round(os.getloadavg()[0], 2)}
    try:
        _alternated(live, 2.0, [], args.modes, 1)  # warm-up: the empties made
        out["no_avatar"] = _alternated(live, seconds, [], args.modes, args.rounds)
        for key in args.rows:
            count, worker = ROWS[key]
            live.stop_following()
            for arm in arms[:count]:
                live.follow(arm, user, "egocentric", worker=worker)
            names = [a.name for a in arms[:count]]
            deadline = time.perf_counter() + 60.0
            while any(live.session().followers[n].state != "running" for n in names):  # the workers started
                assert time.perf_counter() < deadline, [live.session().followers[n].state for n in names]
                live.pump_for(0.1)
            _alternated(live, 3.0, names, args.modes, 1)  # warm-up: the solvers prepared, the stances found
            out[key] = _alternated(live, seconds, names, args.modes, args.rounds)
        live.stop_following()
        if args.minutes:
            out["memory"] = _memory(live, arms[0], user, sender, args.minutes)
        out["target_values"] = TARGETS
        out["targets"] = _targets(out)
        out["load_average_end"] = round(os.getloadavg()[0], 2)
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
    p.add_argument("--modes", nargs="*", default=list(TARGET_MODES), choices=PUMP_MODES,
                   help="blender: the pump loops measured (fixed 90 Hz, the timer's clock, woken by arrivals)")
    p.add_argument("--rounds", type=int, default=4, help="blender: each mode's time in this many turns, in rotation")
    p.add_argument("--rows", nargs="*", default=["one_avatar", "three_avatars"], choices=list(ROWS),
                   help="blender: the avatar rows measured (no_avatar always, for the scheduling wait)")
    p.add_argument("--minutes", type=float, default=3.0,
                   help="blender: the memory run's length (the issue's figure is 10 minutes; 0 skips it)")
    args = p.parse_args()
    out = {name: SECTIONS[name](args) for name in args.sections}
    out["targets"] = {f"{name}_{k}": v for name, section in out.items() for k, v in section.get("targets", {}).items()}
    print(json.dumps(out))


if __name__ == "__main__":
    main()
