"""The live session (live/session.py), fed by a source stand-in on this thread: the device
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

from bodycal_addon.core import one_frame
from bodycal_addon.core.errors import BodyCalError
from bodycal_addon.live.followers import RigLayout
from bodycal_addon.live.session import LiveSession
from bodycal_addon.live.solver import LiveSolver
from bodycal_addon.live.worker import ENGINE_DIR, blender_command, python_command
from bodycal_addon.recording.live.source import LatestSlot, LiveFrame, SourceStats
from bodycal_addon.recording.model import Device
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
            assert session.pump() is None  # never the same frame twice
    assert session.stop_recording() is recorder and session.recorder is None
    # Skips count from the first frame taken: four between each later pump.
    assert recorder.frames == 20 and session.frames_not_taken == 3 * 4
    again = recorder.recording()
    assert [d.role for d in again.devices] == [d.role for d in rec.devices]  # announced before Record: kept


def _results(session, names, index, deadline, updates=None):
    """Pump (waking on the session's results) until every one of `names` has handed back its result
    of the frame `index`; the merged updates. A guard against a broken thread, not a timing."""
    got = {}
    while not all(n in got and got[n].frame_of(n).index >= index for n in names):
        assert time.monotonic() < deadline, {n: session.followers[n].state for n in names}
        session.wait(0.05)
        update = session.pump()
        if update is None:
            continue
        if updates is not None:
            updates.append(update)
        for name in update.pushed:
            got[name] = update
    return got


def _reference(user, avatar, follower, rec, indices, markers=True):
    """A LiveSolver of this process pushed the frames (by index) `follower` was handed: its last pose."""
    order = [i for i, d in enumerate(rec.devices) if d.name in follower.order]
    ref = LiveSolver(user, avatar, "egocentric", devices=[rec.devices[i] for i in order],
                     marker_names=list(rec.marker_names) if markers else None)
    want = None
    for j in indices:
        f = slice(j, j + 1)
        want = ref.push(rec.time[f], rec.positions[f][:, order], rec.rotations[f][:, order], rec.valid[f][:, order],
                        rec.markers[f] if markers else None, rec.marker_valid[f] if markers else None)
    return want


def test_a_follower_waits_for_its_roles_then_gives_live_solvers_poses(take):
    """A follower solves on the session's solving thread, never in the pump: the pump hands back
    the pose of each frame, the one a LiveSolver pushed the same frames gives."""
    rec, user = take
    avatar = procedural_avatar()
    source = Source()
    session = LiveSession(source)
    follower = session.follow("avatar", user, avatar, "egocentric")
    try:
        source.deliver(frame_of(rec, 0))  # nothing announced: no role yet
        time.sleep(0.2)  # the solving thread looked at it
        update = session.pump()
        assert "avatar" not in update.pushed and "head" in follower.waiting_for and follower.last_index == -1
        session.user_roles.update({d.name: d.role for d in rec.devices if d.role})
        deadline = time.monotonic() + 60.0
        c0 = time.thread_time()
        for k in range(1, 30):
            source.deliver(frame_of(rec, k, markers=False))
            got = _results(session, ["avatar"], k, deadline)
            solved = got["avatar"].poses["avatar"]
            assert got["avatar"].frame_of("avatar").index == k  # every frame: the test waits for each
            session.posed(got["avatar"], "avatar")
        assert time.thread_time() - c0 < sum(follower.stats.solve_cpu_ms) / 1000.0  # the solves ran elsewhere
        want = _reference(user, avatar, follower, rec, range(1, 30), markers=False)
        assert follower.waiting_for == [] and follower.stats.frames == 29 and follower.stats.not_shown == 0
        np.testing.assert_array_equal(solved.basis, want.basis)
        assert len(follower.stats.latency_ms) == 29 and "latency" in follower.stats.line()
    finally:
        session.stop()


def test_a_follower_poses_the_fingers_from_the_streams_markers(take):
    """LED glove markers in the stream pose the avatar's fingers as they do in a bake: the follower
    gives what a LiveSolver fed the same markers gives, and not what one without them gives."""
    rec, user = take
    assert rec.marker_names  # the full profile's gloves
    avatar = procedural_avatar()
    source = Source()
    session = LiveSession(source, roles={d.name: d.role for d in rec.devices if d.role})
    follower = session.follow("avatar", user, avatar, "egocentric")
    try:
        deadline = time.monotonic() + 60.0
        for k in range(20):
            source.deliver(frame_of(rec, k, markers=True))
            solved = _results(session, ["avatar"], k, deadline)["avatar"].poses["avatar"]
        want = _reference(user, avatar, follower, rec, range(20))
        bare = _reference(user, avatar, follower, rec, range(20), markers=False)
        assert list(follower.marker_order) == list(rec.marker_names)
        np.testing.assert_array_equal(solved.basis, want.basis)
        fingers = [i for i, n in enumerate(follower.bone_names) if "index" in n.lower() or "thumb" in n.lower()]
        assert fingers and np.abs(solved.basis[:, fingers] - bare.basis[:, fingers]).max() > 1e-3
    finally:
        session.stop()


def test_frames_come_faster_than_the_solves_latest_wins_and_every_skip_is_counted(take):
    """Three followers on the solving thread, the stream far faster than their solves (a burst of
    frames): no frame waits for the one before it: each follower is handed the newest frame there is
    whenever it is free, ends on the last, and every frame it did not show is counted (skipped while
    it solved, or its pose replaced before the pump set it); each pose is what a LiveSolver pushed
    that follower's frames gives; the pump's thread solves nothing."""
    rec, user = take
    avatar = procedural_avatar()
    source = Source()
    session = LiveSession(source, roles={d.name: d.role for d in rec.devices if d.role})
    names = ("first", "second", "third")
    followers = {n: session.follow(n, user, avatar, "egocentric") for n in names}
    try:
        deadline = time.monotonic() + 120.0
        updates, last = [], 40
        source.deliver(frame_of(rec, 0, markers=True))
        _results(session, names, 0, deadline, updates)  # prepared: every solver has solved its first frame
        c0 = time.thread_time()
        for k in range(1, last + 1):  # a burst: 40 frames while a solve or two runs
            source.deliver(frame_of(rec, k, arrival=time.perf_counter(), markers=True))
        got = _results(session, names, last, deadline, updates)
        pump_cpu = time.thread_time() - c0
        for name in names:
            stats = followers[name].stats
            indices = list(stats.indices)
            assert indices[0] == 0 and indices[-1] == last and indices == sorted(set(indices))  # newest, in order
            assert stats.handed < last and stats.handed + stats.skipped == last + 1  # skipped: never handed
            shown = sum(name in u.pushed for u in updates)
            assert stats.handed == stats.frames == shown + stats.unshown  # every result shown or counted
            assert stats.not_shown == last + 1 - shown
            want = _reference(user, avatar, followers[name], rec, indices)
            np.testing.assert_array_equal(got[name].poses[name].basis, want.basis)
        solve_cpu = sum(sum(followers[n].stats.solve_cpu_ms) for n in names) / 1000.0
        assert pump_cpu < 0.5 * solve_cpu  # the solves' CPU time is not the pump thread's
    finally:
        session.stop()


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


# --- followers in worker processes (live/worker.py) ------------------------------------------


def _start_workers(session, names, deadline):
    """Until every worker process is up (the follower then waits for devices)."""
    while any(session.followers[n].state == "starting" for n in names):
        assert time.monotonic() < deadline, [session.followers[n].process.error for n in names]
        time.sleep(0.01)


def _stream_until_posed(session, source, rec, name, deadline):
    """Frames delivered (a little apart: a guard only, nothing is timed) until follower `name`'s
    newest pose is a pose; the updates' notes and that follower's poses."""
    notes, poses, k = [], [], 0
    while not poses or poses[-1] is None:
        assert time.monotonic() < deadline, notes
        source.deliver(frame_of(rec, k))
        k += 1
        time.sleep(0.02)
        update = session.pump()
        if update is not None:
            notes += update.notes
            poses += [update.poses[name]] if name in update.pushed else []
    return notes, poses


def _stream_until_solving(session, source, rec, names, solved: int, deadline, k=0):
    """Frames delivered until the updates carry `solved` poses of each named follower; the updates.
    Each frame's results are waited for from the followers solving already, so every frame is
    handed to them; while a worker starts or prepares, the test waits a little between frames (a
    guard only: nothing is timed). Counted in the updates, not in the follower's solved frames: a
    pose solved while a worker prepares may be replaced in its slot before a pump takes it (latest
    wins, `FollowerStats.unshown`), and under load one was, leaving 11 poses to compare of 12 solved."""
    updates = []
    shown = dict.fromkeys(names, 0)
    while min(shown.values()) < solved:
        assert time.monotonic() < deadline and k < rec.frame_count, [session.followers[n].state for n in names]
        source.deliver(frame_of(rec, k, markers=True))
        seen = len(updates)
        running = [n for n in names if session.followers[n].state == "running"]
        if running:
            _results(session, running, k, deadline, updates)
        else:
            time.sleep(0.005)
            update = session.pump()
            if update is not None:
                updates.append(update)
        for update in updates[seen:]:
            for n in names:
                shown[n] += update.poses.get(n) is not None
        k += 1
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
            wanted = {j: ref.push_newer(*follower.arrays(frame_of(rec, j, markers=True)))
                      for j in follower.stats.indices}  # every frame its worker was sent
            compared = 0
            for update in updates:
                got = update.poses.get(name)
                if got is None:
                    continue
                want = wanted[update.frame_of(name).index]
                for x, y in ((got.basis, want.basis), (got.root_location, want.root_location),
                             (got.joints, want.joints)):
                    np.testing.assert_array_equal(x, y)
                assert got.targets.keys() == want.targets.keys()
                for key in want.targets:
                    np.testing.assert_array_equal(got.targets[key], want.targets[key])
                compared += 1
            assert compared >= 12 and follower.stats.frames == compared + follower.stats.unshown
            rig = ref.solver.rig
            assert follower.layout == RigLayout(rig.armature, tuple(rig.names), rig.root)
            assert follower.bone_names == list(rig.names)
    finally:
        session.stop()


def test_a_worker_that_ends_or_hangs_is_one_line_and_its_avatar_goes_on_here(take, monkeypatch):
    """One worker killed, one stopped (it gives no answer) mid-session: each is said once, the
    stopped one is killed, and both avatars go on being solved in this process."""
    from bodycal_addon.live import followers as live_followers

    monkeypatch.setattr(live_followers, "ANSWER_S", 0.5)
    rec, user = take
    source = Source()
    session = LiveSession(source, roles={d.name: d.role for d in rec.devices if d.role})
    followers = {n: session.follow(n, user, procedural_avatar(), "egocentric", worker=True) for n in ("a", "b")}
    try:
        deadline = time.monotonic() + 120.0
        _start_workers(session, ["a", "b"], deadline)
        _updates, k = _stream_until_solving(session, source, rec, ["a", "b"], 2, deadline)
        pids = {n: f.process.pid for n, f in followers.items()}
        os.kill(pids["a"], signal.SIGKILL)
        os.kill(pids["b"], signal.SIGSTOP)
        notes, posed = [], set()
        while len(notes) < 2 or posed != {"a", "b"}:  # frames at about 50 Hz until both are solved here
            assert time.monotonic() < deadline, notes
            source.deliver(frame_of(rec, k, markers=True))
            k += 1
            time.sleep(0.02)
            update = session.pump()
            if update is not None:
                notes += update.notes
                posed |= {n for n in update.pushed if update.poses[n] is not None} if len(notes) == 2 else set()
        assert len(notes) == 2, notes
        assert any(line.startswith("a: its worker process ended") for line in notes)
        assert any(line.startswith("b: its worker process gave no answer in 0.5 s") for line in notes)
        assert all("solving it in this process" in line for line in notes)
        assert not followers["a"].in_worker and not followers["b"].in_worker  # solved here now
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
            "from bodycal_addon.live.worker import SolverProcess\n"
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
    follower = session.follow("a", user, procedural_avatar(), worker=True,
                              command=python_command(str(tmp_path / "no-python")))
    try:  # the start fails on its thread; the avatar is then solved here
        notes, poses = _stream_until_posed(session, source, rec, "a", time.monotonic() + 60.0)
    finally:
        session.stop()
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
        deadline = time.monotonic() + 120.0
        _start_workers(session, ["a"], deadline)
        notes, poses = _stream_until_posed(session, source, rec, "a", deadline)
        assert len(notes) == 1 and notes[0].startswith("a: its models could not be sent to its worker"), notes
        assert not follower.in_worker
    finally:
        session.stop()


FAKE_BLENDER = """\
import sys
print("Blender 4.5.15 LTS (hash 0000000 built 2025-01-01 00:00:00)")  # Blender's banner, first on stdout
print("Read prefs: none (factory settings)", flush=True)
argv = sys.argv
assert {"--background", "--factory-startup"} <= set(argv) and argv[-2] == "--", argv
expr = argv[argv.index("--python-expr") + 1]
exec(compile(expr, "<python-expr>", "exec"), {"__name__": "__main__"})  # sys.argv: the whole command line
"""


def _blender_posed(take, command, deadline_s=120.0):
    """A follower whose worker `command` runs: its first pose and this process's LiveSolver's."""
    rec, user = take
    avatar = procedural_avatar()
    source = Source()
    session = LiveSession(source, roles={d.name: d.role for d in rec.devices if d.role})
    follower = session.follow("a", user, avatar, "egocentric", worker=True, command=command)
    try:
        deadline = time.monotonic() + deadline_s
        _start_workers(session, ["a"], deadline)
        updates, _k = _stream_until_solving(session, source, rec, ["a"], 3, deadline)
    finally:
        session.stop()
    posed = [u for u in updates if u.poses.get("a") is not None]
    assert posed and follower.in_worker and not follower.note, follower.note
    devices = [Device(n, session.kinds[n], session.roles[n]) for n in follower.order]
    ref = LiveSolver(user, avatar, "egocentric", devices=devices, marker_names=list(follower.marker_order))
    last = posed[-1].frame_of("a").index
    for j in follower.stats.indices:  # every frame its worker was sent, up to the last posed
        want = ref.push_newer(*follower.arrays(frame_of(rec, j, markers=True)))
        if j == last:
            return follower, posed[-1].poses["a"], want
    raise AssertionError(f"frame {last} was not sent to the worker")


def test_a_worker_run_by_blenders_program_reads_past_its_banner(take, tmp_path):
    """Inside Blender the worker is Blender itself in the background (`blender_command`: its own
    Python has no mathutils): Blender prints its banner on stdout before the worker says where it
    listens, and its Python's `sys.argv` is Blender's whole command line, the engine folder last.
    A stand-in program that behaves so (the banner, the command line) gives the poses a Python
    worker gives, and the worker says which kernels it solves with."""
    fake = tmp_path / "blender"
    fake.write_text(f"#!{sys.executable}\n" + FAKE_BLENDER)
    fake.chmod(0o755)
    follower, got, want = _blender_posed(take, blender_command(str(fake)))
    np.testing.assert_array_equal(got.basis, want.basis)
    np.testing.assert_array_equal(got.joints, want.joints)
    assert follower.kernels == ("mathutils" if one_frame.ENABLED else "numpy")


def test_the_worker_imports_numpy_and_the_engine_only():
    """What the child process imports (live/worker.py as a top-level `bodycal_addon`, as BOOTSTRAP
    does): no bpy (it runs outside Blender), no python-osc (not on its path in Blender)."""
    code = ("import sys; sys.path.insert(0, sys.argv[1]); import bodycal_addon.live.worker; "
            "print(sorted({m.split('.')[0] for m in sys.modules}))")
    out = subprocess.run([sys.executable, "-I", "-c", code, str(ENGINE_DIR)], capture_output=True, text=True,
                         check=True)
    top = set(ast.literal_eval(out.stdout.strip()))
    assert {"numpy", "bodycal_addon"} <= top
    # mathutils when the interpreter has it (one frame's kernels, core/one_frame.py; Blender's own
    # Python has none outside Blender: the worker then solves with numpy's paths)
    assert not top & {"bpy", "pythonosc", "bodycal_dev", "tqdm", "dask"}


@pytest.fixture(scope="module")
def three_point_take(take):
    """The synthetic take reduced to the HMD and both controllers, and its three-point user model."""
    from dataclasses import replace

    from bodycal_addon.calibration import calibrate_user

    rec, _ = take
    keep = [i for i, d in enumerate(rec.devices) if d.role in ("head", "hand_l", "hand_r")]
    three = replace(rec, devices=[rec.devices[i] for i in keep], positions=rec.positions[:, keep],
                    rotations=rec.rotations[:, keep], valid=rec.valid[:, keep], marker_names=[],
                    markers=rec.markers[:, :0], marker_valid=rec.marker_valid[:, :0])
    return three, calibrate_user(three)


@pytest.mark.parametrize("worker", [False, True])
def test_a_three_point_stream_is_followed_seated_with_its_estimated_devices(three_point_take, worker):
    """A stream of the HMD and two controllers only: the follower waits for those three roles alone
    (the user's calibration estimates the pelvis and feet), solves in its worker as here, and a
    seated performer's pelvis stays on the seat: the poses are a LiveSolver's given that seat."""
    rec, user = three_point_take
    assert set(user.extra["estimated_devices"]) >= {"pelvis", "foot_l", "foot_r"}
    avatar = procedural_avatar()
    source = Source()
    session = LiveSession(source, roles={d.name: d.role for d in rec.devices})
    follower = session.follow("a", user, avatar, "egocentric", seat_height=0.45, worker=worker)
    try:
        assert follower.waiting_for == ["hand_l", "hand_r", "head"]
        deadline = time.monotonic() + 120.0
        _start_workers(session, ["a"], deadline)
        updates, _k = _stream_until_solving(session, source, rec, ["a"], 12, deadline)
        assert follower.waiting_for == [] and follower.in_worker == worker and not follower.note
        devices = [Device(n, session.kinds[n], session.roles[n]) for n in follower.order]
        seated = LiveSolver(user, avatar, "egocentric", devices=devices, seat_height=0.45)
        standing = LiveSolver(user, avatar, "egocentric", devices=devices)
        want, compared = {}, 0
        for j in follower.stats.indices:  # every frame the follower was handed
            arrays = follower.arrays(frame_of(rec, j))
            want[j] = seated.push_newer(*arrays)
            other = standing.push_newer(*arrays)
        for update in updates:
            got = update.poses.get("a")
            if got is None:
                continue
            np.testing.assert_array_equal(got.joints, want[update.frame_of("a").index].joints)
            compared += 1
        assert compared >= 12
        assert not np.allclose(other.joints, want[follower.stats.indices[-1]].joints, atol=0.01)  # seated, not standing
    finally:
        session.stop()
