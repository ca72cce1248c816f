"""The live session (retarget/live_session.py), fed by a source stand-in on this thread: the device
table (kinds, roles with the user's first, rates, frames missed), the recorder seeing every frame
while the pump takes only the newest, a follower that waits for the roles it needs and then
gives LiveSolver's poses, and followers solved in worker processes: the same poses, a worker that
ends, hangs or cannot start said in one line, none left running after Stop."""

import ast
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from processes import still_alive

from bodycal_addon.core.errors import BodyCalError
from bodycal_addon.recording.live.source import LatestSlot, LiveFrame, SourceStats
from bodycal_addon.recording.model import Device
from bodycal_addon.retarget.live import LiveSolver
from bodycal_addon.retarget.live_session import LiveSession, RigLayout, WorkerFollower, solve_in_workers
from bodycal_addon.retarget.live_worker import ENGINE_DIR
from bodycal_dev import synthetic
from bodycal_dev.retarget_fixtures import procedural_avatar


class Source:
    """A LiveSource that delivers what the test gives it, as VmcReceiver does: sinks, then the slot."""

    def __init__(self):
        self.stats, self.sinks, self.slot = SourceStats(), [], LatestSlot()

    def start(self):
        pass

    def stop(self):
        pass

    def latest(self):
        return self.slot.take()

    def wait(self, timeout):
        return self.slot.wait(timeout)

    def add_sink(self, sink):
        self.sinks.append(sink)

    def deliver(self, frame):
        for sink in self.sinks:
            sink(frame)
        self.slot.put(frame)
        self.stats.dropped = self.slot.dropped


@pytest.fixture(scope="module")
def take():
    perf = synthetic.make_performer(seed=4)
    rec, truth = synthetic.record_session(perf, motions=("clap",), calibration=["tpose"], noise_mm=0.0,
                                          wobble_mm=0.0)
    return rec, truth.body_model()


def frame_of(rec, k, *, announce=False, arrival=None, markers=False):
    v = rec.valid[k]
    events = tuple(("device", d.name, d.kind, d.role) for d in rec.devices) if announce else ()
    mv = rec.marker_valid[k] if markers else np.zeros(len(rec.marker_names), bool)
    return LiveFrame(k, float(rec.time[k]) if arrival is None else arrival, float(rec.time[k]),
                     tuple(d.name for d, ok in zip(rec.devices, v, strict=True) if ok), rec.positions[k, v],
                     rec.rotations[k, v], tuple(n for n, ok in zip(rec.marker_names, mv, strict=True) if ok),
                     rec.markers[k, mv], events=events)


def test_the_device_table_says_kinds_roles_rates_and_frames_missed(take):
    rec, _user = take
    source = Source()
    first = rec.devices[0].name
    session = LiveSession(source, roles={first: "pelvis"})  # the user's role wins over the stream's
    for k in range(90):
        frame = frame_of(rec, k, announce=k == 0, arrival=k / 90.0)
        if 30 <= k < 40:  # the last device out of view for ten frames
            frame.devices, frame.positions, frame.rotations = frame.devices[:-1], frame.positions[:-1], \
                frame.rotations[:-1]
        source.deliver(frame)
    table = {d.name: d for d in session.devices(now=89 / 90.0)}
    assert list(table) == [d.name for d in rec.devices]
    assert table[first].role == "pelvis"
    last = rec.devices[-1]
    assert table[last.name].kind == last.kind and table[last.name].role == last.role
    assert table[last.name].missed == 10 and table[last.name].frames == 80
    assert table[rec.devices[1].name].rate_hz == pytest.approx(90.0)
    assert session.frames_seen == 90


def test_the_recorder_gets_every_frame_the_pump_only_the_newest(take):
    rec, _user = take
    source = Source()
    session = LiveSession(source)
    recorder = session.start_recording("take")
    with pytest.raises(BodyCalError, match="already recording"):
        session.start_recording("again")
    for k in range(20):
        source.deliver(frame_of(rec, k, announce=k == 0))
        if k % 5 == 4:
            assert session.pump().frame.index == k  # the newest; the ones before it skipped, counted
    assert session.stop_recording() is recorder and session.recorder is None
    # Drops count from the first take (source.LatestSlot): four replaced between each later pump.
    assert recorder.frames == 20 and source.stats.dropped == 3 * 4
    again = recorder.recording()
    assert [d.role for d in again.devices] == [d.role for d in rec.devices]  # announced before Record: kept


def test_a_follower_waits_for_its_roles_then_gives_live_solvers_poses(take):
    rec, user = take
    avatar = procedural_avatar()
    source = Source()
    session = LiveSession(source)
    follower = session.follow("avatar", user, avatar, "egocentric")
    source.deliver(frame_of(rec, 0))  # nothing announced: no role yet
    assert session.pump().poses["avatar"] is None and "head" in follower.waiting_for
    session.user_roles.update({d.name: d.role for d in rec.devices if d.role})
    ref = None
    for k in range(1, 30):
        source.deliver(frame_of(rec, k))
        update = session.pump()
        solved = update.poses["avatar"]
        if ref is None:
            ref = LiveSolver(user, avatar, "egocentric", devices=follower.solver.recording.devices)
        v = rec.valid[k]
        order = [i for i, d in enumerate(rec.devices) if d.name in follower.order]
        want = ref.push(rec.time[k], rec.positions[k, order], rec.rotations[k, order], v[order])
        session.posed(update, "avatar")
    assert follower.waiting_for == [] and follower.stats.frames == 29
    np.testing.assert_array_equal(solved.basis, want.basis)
    assert len(follower.stats.latency_ms) == 29 and "latency" in follower.stats.line()


def test_a_follower_poses_the_fingers_from_the_streams_markers(take):
    """LED glove markers in the stream pose the avatar's fingers as they do in a bake: the follower
    gives what a LiveSolver fed the same markers gives, and not what one without them gives."""
    rec, user = take
    assert rec.marker_names  # the full profile's gloves
    avatar = procedural_avatar()
    source = Source()
    session = LiveSession(source, roles={d.name: d.role for d in rec.devices if d.role})
    follower = session.follow("avatar", user, avatar, "egocentric")
    order = [i for i, d in enumerate(rec.devices) if d.role]
    devices = [rec.devices[i] for i in order]
    with_markers = LiveSolver(user, avatar, "egocentric", devices=devices, marker_names=list(rec.marker_names))
    without = LiveSolver(user, avatar, "egocentric", devices=devices)
    for k in range(20):
        source.deliver(frame_of(rec, k, markers=True))
        solved = session.pump().poses["avatar"]
        f = slice(k, k + 1)
        want = with_markers.push(rec.time[f], rec.positions[f][:, order], rec.rotations[f][:, order],
                                 rec.valid[f][:, order], rec.markers[f], rec.marker_valid[f])
        bare = without.push(rec.time[f], rec.positions[f][:, order], rec.rotations[f][:, order],
                            rec.valid[f][:, order])
    assert list(follower.marker_order) == list(rec.marker_names)
    np.testing.assert_array_equal(solved.basis, want.basis)
    fingers = [i for i, n in enumerate(follower.bone_names) if "index" in n.lower() or "thumb" in n.lower()]
    assert fingers and np.abs(solved.basis[:, fingers] - bare.basis[:, fingers]).max() > 1e-3


def test_each_follower_here_solves_the_newest_frame_when_its_turn_comes(take):
    """Followers solved in this process one after the other: a frame that comes while the first
    solves is what the next one solves (its pose one solve behind the stream, not two), and the
    first, left behind, solves it in the next pump, due at once; each pose what a LiveSolver fed the
    frames that follower got, its latency counted from its own frame."""
    rec, user = take
    avatar = procedural_avatar()
    source = Source()
    session = LiveSession(source, roles={d.name: d.role for d in rec.devices if d.role})
    names = ("first", "second", "third")
    for name in names:
        session.follow(name, user, avatar, "egocentric")
    arrivals = {}

    def deliver(k):
        arrivals[k] = time.perf_counter()
        source.deliver(frame_of(rec, k, arrival=arrivals[k]))

    def on_pose(update, name):
        session.posed(update, name)
        if name == "first" and update.frame.index % 4 == 0:  # a frame comes while the first one solves
            deliver(update.frame.index + 1)

    def pump():
        update = session.pump(on_pose)
        for name in update.pushed:
            got[name].append(update.frame_of(name).index)
            last[name] = update.poses[name]
            assert update.frame_of(name).arrival <= update.taken_at[name] <= update.solved_at[name] \
                <= update.posed_at[name]
        return update

    got, last = {name: [] for name in names}, {}
    k = 0
    for _ in range(8):
        deliver(k)
        update = pump()
        assert update.frame.index == update.frame_of("third").index  # the newest the pump took
        k = update.frame.index + 1
        assert session.behind() == (update.frame_of("first").index < k - 1)
        if session.behind():
            assert session.next_delay() == 0.0 and session.wait(0.0)
            assert pump().pushed == {"first"}  # no new frame: the one behind catches up
        assert not session.behind() and session.pump() is None
    # The frames delivered mid-pump (after 0, 4, 8) went to the second and third, the pump's own to
    # the first, which then caught up.
    assert got["first"] == list(range(11))
    assert got["second"] == got["third"] == [1, 2, 3, 5, 6, 7, 9, 10]
    assert source.stats.dropped == 0  # every frame taken by one follower or another
    order = [i for i, d in enumerate(rec.devices) if d.role]
    devices = [rec.devices[i] for i in order]
    for name in names:
        ref = LiveSolver(user, avatar, "egocentric", devices=devices, marker_names=list(rec.marker_names))
        follower = session.followers[name]
        for j in got[name]:
            f = slice(j, j + 1)
            want = ref.push(rec.time[f], rec.positions[f][:, order], rec.rotations[f][:, order],
                            rec.valid[f][:, order], rec.markers[f], np.zeros((1, len(rec.marker_names)), bool))
        assert follower.stats.frames == len(got[name]) and len(follower.stats.latency_ms) == len(got[name])
        np.testing.assert_array_equal(last[name].basis, want.basis)


def test_the_pump_learns_the_streams_beat_and_says_when_to_look_again(take):
    rec, _user = take
    source = Source()
    session = LiveSession(source)
    for k in range(10):  # frames arriving every 1/90 s (the arrival clock is the test's), each pumped
        source.deliver(frame_of(rec, k, arrival=1.0 + k / 90.0))
        assert session.next_delay(now=1.0 + k / 90.0) == 0.0  # a frame waits: at once
        update = session.pump()
        assert update.frame.index == k and update.solved_at == {}
        assert session.pump() is None  # never the same frame twice
    assert session.clock.period == pytest.approx(1 / 90.0)
    now = 1.0 + 9 / 90.0 + 0.004  # 4 ms after the last frame: the next is due 1/90 s after it
    assert session.next_delay(now) == pytest.approx(1 / 90.0 - 0.004 + session.clock.margin_s)


# --- followers in worker processes (retarget/live_worker.py) ------------------------------------------


def _start_workers(session, names, deadline):
    """Until every worker process is up (the follower then waits for devices)."""
    while any(session.followers[n].state == "starting" for n in names):
        assert time.monotonic() < deadline, [session.followers[n].process.error for n in names]
        time.sleep(0.01)


def _stream_until_solving(session, source, rec, names, solved: int, deadline, k=0):
    """Frames delivered and pumped until each named follower has given `solved` poses; the
    updates. While a worker prepares, the frames it is not sent are skipped, so the test waits a
    little between frames then (a guard only: nothing is timed)."""
    updates = []
    while min(sum(u.poses.get(n) is not None for u in updates) for n in names) < solved:
        assert time.monotonic() < deadline and k < rec.frame_count, [session.followers[n].state for n in names]
        source.deliver(frame_of(rec, k, markers=True))
        updates.append(session.pump())
        k += 1
        if any(session.followers[n].state != "running" for n in names):
            time.sleep(0.005)
    return updates, k


def test_followers_in_worker_processes_give_live_solvers_poses_bit_for_bit(take):
    """Two avatars solved in worker processes: every pose (bone values, root, joints, targets) is
    what a LiveSolver of this process gives for the frames each worker was sent, to the last bit
    (the models cross as exact JSON), and the rig's names and root the worker reports are the
    solver's."""
    rec, user = take
    models = {"a": procedural_avatar(), "b": procedural_avatar(name="tall", scale=1.1)}
    source = Source()
    session = LiveSession(source, roles={d.name: d.role for d in rec.devices if d.role})
    followers = {n: session.follow(n, user, m, "egocentric", worker=True) for n, m in models.items()}
    try:
        deadline = time.monotonic() + 120.0
        _start_workers(session, list(models), deadline)
        updates, _k = _stream_until_solving(session, source, rec, list(models), 12, deadline)
        assert all(f.in_worker and not f.note for f in followers.values())
        kinds, roles = session.kinds, session.roles
        for name, follower in followers.items():
            devices = [Device(n, kinds[n], roles[n]) for n in follower.order]
            ref = LiveSolver(user, models[name], "egocentric", devices=devices,
                             marker_names=list(follower.marker_order))
            compared = 0
            for update in updates:
                if name not in update.pushed:
                    continue
                want, got = ref.push_newer(*follower.arrays(update.frame_of(name))), update.poses[name]
                if got is None:
                    continue
                for x, y in ((got.basis, want.basis), (got.root_location, want.root_location),
                             (got.joints, want.joints)):
                    np.testing.assert_array_equal(x, y)
                assert got.targets.keys() == want.targets.keys()
                for key in want.targets:
                    np.testing.assert_array_equal(got.targets[key], want.targets[key])
                compared += 1
            assert compared >= 12 and follower.stats.frames == compared
            rig = ref.solver.rig
            assert follower.layout == RigLayout(rig.armature, tuple(rig.names), rig.root)
            assert follower.bone_names == list(rig.names)
    finally:
        session.stop()


def test_a_worker_that_ends_or_hangs_is_one_line_and_its_avatar_goes_on_here(take, monkeypatch):
    """One worker killed, one stopped (it gives no answer) mid-session: each is said once, the
    stopped one is killed, and both avatars go on being solved in this process."""
    from bodycal_addon.retarget import live_session

    monkeypatch.setattr(live_session, "ANSWER_S", 0.5)
    rec, user = take
    source = Source()
    session = LiveSession(source, roles={d.name: d.role for d in rec.devices if d.role})
    followers = {n: session.follow(n, user, procedural_avatar(), "egocentric", worker=True) for n in ("a", "b")}
    try:
        deadline = time.monotonic() + 120.0
        _start_workers(session, ["a", "b"], deadline)
        _updates, first = _stream_until_solving(session, source, rec, ["a", "b"], 2, deadline)
        pids = {n: f.process.pid for n, f in followers.items()}
        os.kill(pids["a"], signal.SIGKILL)
        os.kill(pids["b"], signal.SIGSTOP)
        notes = []
        for k in range(first, first + 10):
            source.deliver(frame_of(rec, k, markers=True))
            update = session.pump()
            notes += update.notes
        assert len(notes) == 2, notes
        assert any(line.startswith("a: its worker process ended") for line in notes)
        assert any(line.startswith("b: its worker process gave no answer in 0.5 s") for line in notes)
        assert all("solving it in this process" in line for line in notes)
        assert not followers["a"].in_worker and not followers["b"].in_worker
        assert update.poses["a"] is not None and update.poses["b"] is not None  # solved here now
        assert still_alive(pids.values()) == []  # the stopped one killed and reaped
    finally:
        session.stop()


def test_stop_and_unfollow_end_the_worker_processes_even_while_they_start(take):
    rec, user = take
    session = LiveSession(Source())
    a = session.follow("a", user, procedural_avatar(), worker=True)
    _start_workers(session, ["a"], time.monotonic() + 120.0)
    starting = session.follow("b", user, procedural_avatar(), worker=True)  # stopped before it is up
    replaced = session.follow("c", user, procedural_avatar(), worker=True)
    session.follow("c", user, procedural_avatar(), worker=False)  # a follower replaced ends its worker
    assert replaced.process.connection is None and not replaced.process.alive()
    session.unfollow("a")
    assert not a.process.alive()
    session.stop()
    assert still_alive([p for p in (a.process.pid, starting.process.pid, replaced.process.pid) if p]) == []


def test_a_worker_ends_when_the_process_that_started_it_dies():
    """No orphan: a process killed while its worker runs (a crash) takes the worker with it (the
    worker sees its stdin close)."""
    code = ("import os, signal, sys, time; sys.path.insert(0, sys.argv[1])\n"
            "from bodycal_addon.retarget.live_worker import SolverProcess\n"
            "p = SolverProcess('x')\n"
            "while p.starting: time.sleep(0.01)\n"
            "print(p.pid, p.alive(), flush=True)\n"
            "os.kill(os.getpid(), signal.SIGKILL)\n")
    out = subprocess.run([sys.executable, "-c", code, str(ENGINE_DIR)], capture_output=True, text=True, timeout=120)
    pid, alive = out.stdout.split()
    assert alive == "True" and out.returncode == -signal.SIGKILL, out.stderr
    assert still_alive([int(pid)]) == []


def test_a_worker_that_cannot_start_is_one_line_and_the_avatar_is_solved_here(take, tmp_path):
    rec, user = take
    source = Source()
    session = LiveSession(source, roles={d.name: d.role for d in rec.devices if d.role})
    follower = WorkerFollower("a", user, procedural_avatar(), executable=str(tmp_path / "no-python"))
    session.followers["a"] = follower
    notes, poses = [], []
    for k in range(5):
        time.sleep(0.02)  # the start fails on its thread
        source.deliver(frame_of(rec, k))
        update = session.pump()
        notes += update.notes
        poses.append(update.poses["a"])
    assert len(notes) == 1 and notes[0].startswith("a: no worker process (FileNotFoundError") and \
        notes[0].endswith("solving it in this process from now on"), notes
    assert follower.note == notes[0] and not follower.in_worker and poses[-1] is not None


def test_a_model_json_cannot_carry_is_one_line_and_the_avatar_is_solved_here(take):
    rec, user = take
    avatar = procedural_avatar()
    avatar.extra["note_from_a_tool"] = float("nan")  # kept in a model, refused by JSON
    source = Source()
    session = LiveSession(source, roles={d.name: d.role for d in rec.devices if d.role})
    follower = session.follow("a", user, avatar, worker=True)
    try:
        _start_workers(session, ["a"], time.monotonic() + 120.0)
        notes = []
        for k in range(3):
            source.deliver(frame_of(rec, k))
            update = session.pump()
            notes += update.notes
        assert len(notes) == 1 and notes[0].startswith("a: its models could not be sent to its worker"), notes
        assert not follower.in_worker and update.poses["a"] is not None
    finally:
        session.stop()


def test_the_worker_imports_numpy_and_the_engine_only():
    """What the child process imports (live_worker.py as a top-level `bodycal_addon`, as BOOTSTRAP
    does): no bpy (it runs outside Blender), no python-osc (not on its path in Blender)."""
    code = ("import sys; sys.path.insert(0, sys.argv[1]); import bodycal_addon.retarget.live_worker; "
            "print(sorted({m.split('.')[0] for m in sys.modules}))")
    out = subprocess.run([sys.executable, "-I", "-c", code, str(ENGINE_DIR)], capture_output=True, text=True,
                         check=True)
    top = set(ast.literal_eval(out.stdout.strip()))
    assert {"numpy", "bodycal_addon"} <= top
    # mathutils when the interpreter has it (one frame's kernels, core/one_frame.py; Blender's own
    # Python has none outside Blender: the worker then solves with numpy's paths)
    assert not top & {"bpy", "pythonosc", "bodycal_dev", "tqdm", "dask"}


def test_followers_solve_in_workers_only_with_a_core_for_each():
    """Workers when asked, for more than one avatar, with a core each (DESIGN.md §9 "When"): three
    avatars on two cores are solved in the pump's process, where each takes the newest frame."""
    assert solve_in_workers(True, 2, cores=2) and solve_in_workers(True, 3, cores=4)
    assert not solve_in_workers(True, 3, cores=2)
    assert not solve_in_workers(True, 1, cores=8) and not solve_in_workers(False, 3, cores=8)
