"""`LiveSession`: a live source, what it records and the avatars that follow it, pumped by whoever
runs the loop (DESIGN.md "Live session"): the command line's `bodycal live`, Blender's timer or a
headless station's explicit pump (bodycal_addon/blender/live.py). No bpy.

    session = LiveSession(VmcReceiver(port, bind))
    session.start()
    session.follow("avatar", user_model, avatar_model, "egocentric")
    update = session.pump()          # the newest frame, its device poses, each follower's solved pose
    delay = session.next_delay()     # when to look again (pump_clock.PumpClock, locked onto the stream)
    session.start_recording("take"); ...; recorder = session.stop_recording()
    session.stop()

The source's thread gives every frame to the session's sink (`_on_frame`), which counts each
device's frames (its rate), keeps the kinds and roles the stream announces and hands the frame on
to the recorder when one runs; it copies, it does not compute. `pump` takes the latest frame (a
consumer that falls behind gets the newest one: the source counts those it missed) and solves it
for each follower with its `LiveSolver` (live/solver.py): the causal stance and the forward One
Euro, from the frames so far only. A follower made with `worker=True` (`WorkerFollower`) solves in a
process of its own (live/worker.py), so several avatars use several cores: the pump sends
the frame to every worker first, solves the followers of this process meanwhile, then sets each
worker's pose as its answer comes. Each follower of this process after the first solves the newest
frame there is when its turn comes (a frame that came during the solves before it): its pose is
then one solve behind the stream, not the sum of the solves before it; the avatars of one pump
show moments at most a few frames apart (`LiveUpdate.frames`). A follower left behind that way
(solved before the newer frame came) is `behind`: the next pump is due at once and, if no newer
frame has come by then, gives it the newest taken, so every avatar is still solved once a round of
the others. The session's `clock`
(pump_clock.PumpClock) learns the stream's beat from the frames taken and says when the next pump
should look (`next_delay`); `wait` blocks until a frame is there, for a loop that may block.

It imports the recorder, hence python-osc (recording/live/__init__.py): only what runs a live
session imports it.
"""

from __future__ import annotations

import os
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from multiprocessing.connection import wait as wait_for_connections

import numpy as np

from ..body.bodymodel import BodyModel
from ..calibration.coverage import ANIMATED_ROLES
from ..core.errors import BodyCalError
from ..recording.filters import OneEuro
from ..recording.live.recorder import LiveRecorder
from ..recording.live.source import LiveFrame, LiveSource
from ..recording.model import Device
from ..retarget.solver import SolvedFrames
from .pump_clock import PumpClock
from .solver import LiveSolver
from .worker import SolverProcess, frame_message, pickled, prepare_message, solved_from

RATE_WINDOW_S = 1.0  # a device's rate: its frames over the last second
STATS_WINDOW = 512  # solve times and latencies kept per follower (the figures shown are over these)
ANSWER_S = 2.0  # a worker that solved before and gives no answer to a frame in this long is stuck: ended


def solve_in_workers(wanted: bool, avatars: int, cores: int | None = None) -> bool:
    """Whether followers should solve in worker processes: when asked, more than one avatar follows
    and the machine has a core for each (one avatar solves fastest here: no hand-over; with fewer
    cores than avatars the workers wait for each other's cores, and the avatars solved here one
    after the other, each on the newest frame at its turn, are set sooner: DESIGN.md section 9)."""
    cores = os.cpu_count() if cores is None else cores
    return bool(wanted) and avatars > 1 and (cores or 1) >= avatars


def forward_filter(smooth: OneEuro | None) -> OneEuro | None:
    """A One Euro configuration as frames arrive: forward only, each device in the room's frame
    (the bake's smoothing of the body parts needs the whole take: DESIGN.md §6b)."""
    if smooth is None:
        return None
    return OneEuro(smooth.min_cutoff, smooth.beta, smooth.rot_min_cutoff, smooth.rot_beta, smooth.d_cutoff,
                   two_pass=False, anchored=False)


@dataclass
class DeviceStatus:
    """One device as the stream shows it: what it is, its role, how often it arrives."""

    name: str
    kind: str
    role: str | None
    frames: int  # frames it was tracked in
    missed: int  # frames of the stream since its first, without it (a dropout, out of view)
    rate_hz: float  # over the last RATE_WINDOW_S


@dataclass
class FollowerStats:
    frames: int = 0  # frames solved
    solve_ms: deque = field(default_factory=lambda: deque(maxlen=STATS_WINDOW))  # wall clock
    solve_cpu_ms: deque = field(default_factory=lambda: deque(maxlen=STATS_WINDOW))  # the pump thread's CPU time
    latency_ms: deque = field(default_factory=lambda: deque(maxlen=STATS_WINDOW))  # arrival -> pose set
    worker_ms: deque = field(default_factory=lambda: deque(maxlen=STATS_WINDOW))  # a worker's own push (wall)

    def line(self) -> str:
        if not self.solve_ms:
            return "no frame solved yet"
        solve, lat = np.asarray(self.solve_ms), np.asarray(self.latency_ms or [np.nan])
        return (f"solve {np.median(solve):.1f} ms, latency {np.median(lat):.1f} ms "
                f"(p95 {np.percentile(lat, 95):.1f} ms)")


def _scatter(names, columns: dict[str, int], first, second, seen) -> None:
    """The frame's rows of `names` into their columns of the solver's arrays (`first` and `second`
    are (the frame's rows, the solver's array) pairs), `seen` set where written."""
    if not names:
        return
    cols = np.array([columns.get(name, -1) for name in names])
    keep = cols >= 0
    cols = cols[keep]
    for rows, out in (first, second) if second is not None else (first,):
        out[cols] = rows[keep]
    seen[cols] = True


@dataclass(frozen=True)
class RigLayout:
    """What a pose writer needs of the avatar's rig: the armature's name, the bones in the order of
    `SolvedFrames.basis` and the root bone's index in it."""

    armature: str
    names: tuple[str, ...]
    root: int


class Follower:
    """An avatar following the stream: `user` (the performer's calibrated model) onto `avatar` by
    `method`. Its solver is made once every role the methods need has a device the stream has
    named (`waiting_for` says which are missing until then)."""

    in_worker = False  # solved in this process

    def __init__(self, name: str, user: BodyModel, avatar: BodyModel, method: str = "egocentric", *,
                 smooth: OneEuro | None = None, plant_feet: bool = True, placement: str = "object"):
        if user.kind != "user":
            raise BodyCalError(f"expected a user body model, got kind '{user.kind}'", source=name)
        if avatar.kind != "avatar" or "rig" not in avatar.extra:
            raise BodyCalError("expected an avatar body model with its rig", source=name,
                               hint="calibrate the avatar first")
        self.name, self.user, self.avatar, self.method = name, user, avatar, method
        self.smooth, self.plant_feet, self.placement = smooth, plant_feet, placement
        self.solver = None  # live.solver.LiveSolver, once prepared
        self.order: dict[str, int] = {}  # device name -> its column in the solver's arrays
        self.marker_order: dict[str, int] = {}  # marker name -> its column (LED gloves: the fingers)
        self.stats = FollowerStats()
        self.last_index = -1  # the newest frame (LiveFrame.index) pushed to its solver or sent to its worker
        self.waiting_for: list[str] = sorted(ANIMATED_ROLES)
        self.note = ""  # the last thing to say about it (a worker that ended), one line
        self._unsaid: list[str] = []  # lines for the pump to say (`said`)

    @property
    def ready(self) -> bool:
        """Prepared: the next frame can be pushed."""
        return self.solver is not None

    @property
    def state(self) -> str:
        """"waiting" for devices, else "running" (a WorkerFollower also "starting" and "preparing")."""
        return "running" if self.ready else "waiting"

    @property
    def layout(self) -> RigLayout | None:
        """The rig's names and root (None until the first frame is solved)."""
        prepared = self.solver.solver if self.solver is not None else None  # made at the first solve
        if prepared is None:
            return None
        rig = prepared.rig
        return RigLayout(rig.armature, tuple(rig.names), int(rig.root))

    @property
    def bone_names(self) -> list[str]:
        layout = self.layout
        return list(layout.names) if layout is not None else []

    def _devices(self, kinds: dict[str, str], roles: dict[str, str], markers) -> list[Device] | None:
        """The devices the solver reads (their columns in `order`, the markers' in `marker_order`),
        or None while a role the methods need has no device the stream has named."""
        named = {n: r for n, r in roles.items() if n in kinds and r}
        self.waiting_for = sorted(set(ANIMATED_ROLES) - set(named.values()))
        if self.waiting_for:
            return None
        devices = [Device(n, kinds[n], r) for n, r in named.items()]
        self.order = {d.name: i for i, d in enumerate(devices)}
        self.marker_order = {m: i for i, m in enumerate(markers)}
        return devices

    def prepare(self, kinds: dict[str, str], roles: dict[str, str], markers: list[str] | tuple = ()) -> bool:
        """The solver, once every role the methods need has a device the stream has named; the
        `markers` named by then pose the fingers (a marker first seen later is not read)."""
        if self.solver is not None:
            return True
        devices = self._devices(kinds, roles, markers)
        if devices is None:
            return False
        self.solver = LiveSolver(self.user, self.avatar, self.method, devices=devices, marker_names=list(markers),
                                 smooth=self.smooth, plant_feet=self.plant_feet, placement=self.placement)
        return True

    def arrays(self, frame: LiveFrame) -> tuple:
        """The frame as the solver's arrays: (time, positions (D, 3), rotations (D, 4), valid (D,),
        marker points (M, 3) and seen (M,), or None without markers)."""
        n, m = len(self.order), len(self.marker_order)
        pos, rot, valid = np.zeros((n, 3)), np.zeros((n, 4)), np.zeros(n, bool)
        rot[:, 0] = 1.0
        _scatter(frame.devices, self.order, (frame.positions, pos), (frame.rotations, rot), valid)
        t = frame.sender_time if frame.sender_time is not None else frame.arrival
        if not m:
            return t, pos, rot, valid, None, None
        points, seen = np.zeros((m, 3)), np.zeros(m, bool)
        _scatter(frame.markers, self.marker_order, (frame.points, points), None, seen)
        return t, pos, rot, valid, points, seen

    @property
    def columns(self) -> tuple:
        """What `arrays` depends on besides the frame: followers with the same share them."""
        return tuple(self.order), tuple(self.marker_order)

    def push(self, frame: LiveFrame) -> SolvedFrames | None:
        """The frame solved (one row), or None: a frame not newer than the last (a replay looping)
        or one before every device the methods need has been tracked."""
        arrays = self.arrays(frame)
        t0, c0 = time.perf_counter(), time.thread_time()
        solved = self.solver.push_newer(*arrays)
        if solved is not None:
            self.stats.solve_cpu_ms.append((time.thread_time() - c0) * 1000.0)
            self.stats.solve_ms.append((time.perf_counter() - t0) * 1000.0)
            self.stats.frames += 1
        return solved

    @property
    def busy(self) -> bool:
        """Solving a frame sent before (a worker): not to be sent the next."""
        return False

    def said(self) -> list[str]:
        """The lines to say since the last call (a worker that ended, a solve that failed)."""
        lines, self._unsaid = self._unsaid, []
        return lines

    def _say(self, line: str) -> None:
        self.note = line
        self._unsaid.append(line)

    def close(self) -> None:
        """Nothing to end here (a WorkerFollower ends its process)."""


class WorkerFollower(Follower):
    """A Follower whose LiveSolver runs in a worker process (worker.py): the same solver, fed
    the same arrays, so the same poses. The process starts when the follower is made (`state`
    "starting"), is given the models and devices once the roles are there ("preparing": no frame
    is waited for until its first pose, so neither the start nor the solver's preparation holds
    the pump up), then solves each frame it is sent ("running"). One frame in flight at most: a
    worker still busy is not sent the next one (latest wins, as for the pump). A worker that cannot
    start, ends or gives no answer in ANSWER_S is said in one line (`note`) and the follower goes
    on solving in this process."""

    def __init__(self, *args, executable: str | None = None, **kwargs):
        super().__init__(*args, **kwargs)
        self.process: SolverProcess | None = SolverProcess(self.name, executable)
        self.solving = False  # a pose has come: the worker's answers are waited for
        self._layout: RigLayout | None = None
        self._prepare_sent = False
        self._in_flight: str | None = None  # "prepare" or "frame": what the worker has not answered yet
        self._sent_at = 0.0

    @property
    def in_worker(self) -> bool:
        return self.process is not None

    @property
    def connection(self):
        return self.process.connection if self.process is not None else None

    @property
    def busy(self) -> bool:
        return self.process is not None and self._in_flight is not None

    @property
    def ready(self) -> bool:
        return super().ready if self.process is None else self._layout is not None

    @property
    def state(self) -> str:
        if self.process is None:
            return super().state
        if self.process.connection is None:
            return "starting"
        if not self._prepare_sent:
            return "waiting"
        return "running" if self.solving else "preparing"

    @property
    def layout(self) -> RigLayout | None:
        return super().layout if self.process is None else self._layout

    def prepare(self, kinds: dict[str, str], roles: dict[str, str], markers: list[str] | tuple = ()) -> bool:
        if self.process is None:
            return super().prepare(kinds, roles, markers)
        if self._layout is not None:
            return True
        if self.process.connection is None or self._prepare_sent:
            return False
        devices = self._devices(kinds, roles, markers)
        if devices is None:
            return False
        try:
            message = prepare_message(self.user, self.avatar, self.method, devices, list(markers), self.smooth,
                                      self.plant_feet, self.placement)
        except (TypeError, ValueError) as exc:  # a model JSON cannot hold (NaN): this process says what is wrong
            self._fall_back(f"its models could not be sent to its worker ({exc})")
            return False
        if self._send(message, "prepare"):
            self._prepare_sent = True
        return False

    def poll(self) -> None:
        """Take an answer that came since (the preparation's, or a frame's not waited for) and
        notice a worker that could not start or has ended."""
        if self.process is None:
            return
        if self.process.error:
            self._fall_back(self.process.error)
            return
        connection = self.process.connection
        if connection is None:
            return
        if self._in_flight is None:
            if not self.process.alive():
                self._fall_back(self._ended())
            return
        try:
            if connection.poll():
                self._take(connection.recv(), waited=False)  # a pose of an older frame: not set
        except (EOFError, OSError):
            self._fall_back(self._ended())

    def send(self, frame: LiveFrame, shared: dict | None = None) -> bool:
        """The frame sent to the worker (True), or not: busy with the one before, or ended.
        `shared` keeps the message made for one worker for the others with the same `columns`
        (made and pickled once a frame)."""
        if self.process is None or self._in_flight is not None:
            return False
        shared = {} if shared is None else shared
        message = shared.get(self.columns)
        if message is None:
            message = shared[self.columns] = pickled(frame_message(*self.arrays(frame)))
        return self._send(message, "frame")

    def receive(self) -> SolvedFrames | None:
        """The worker's answer to the frame sent (it is there: `connection` is ready): the pose, or
        None."""
        try:
            return self._take(self.process.connection.recv())
        except (EOFError, OSError):
            self._fall_back(self._ended())
            return None

    def stuck(self) -> None:
        """No answer in ANSWER_S: the worker is killed."""
        self._fall_back(f"its worker process gave no answer in {ANSWER_S:g} s", kill=True)

    def _send(self, message: tuple | memoryview, what: str) -> bool:
        try:
            if not isinstance(message, tuple):  # pickled already: what `send` would write
                self.process.connection.send_bytes(message)
            else:
                self.process.connection.send(message)
        except (OSError, ValueError):
            self._fall_back(self._ended())
            return False
        self._in_flight, self._sent_at = what, time.perf_counter()
        return True

    def _take(self, reply: tuple, waited: bool = True) -> SolvedFrames | None:
        what, self._in_flight = self._in_flight, None
        kind = reply[0]
        if kind == "ready":
            self._layout = RigLayout(reply[1]["armature"], tuple(reply[1]["names"]), int(reply[1]["root"]))
            return None
        if kind == "error":
            if what == "prepare":  # this process makes the same solver and says what is wrong with it
                self._fall_back(f"its worker could not prepare ({reply[1]})")
            else:
                self._say(f"{self.name}: {reply[1]}")
            return None
        if kind == "pose":
            self.solving = True
            if not waited:
                return None
            self.stats.solve_ms.append((time.perf_counter() - self._sent_at) * 1000.0)
            self.stats.solve_cpu_ms.append(reply[6])
            self.stats.worker_ms.append(reply[7])
            self.stats.frames += 1
            return solved_from(reply)
        return None  # "none": not newer than the last, or a needed device not tracked yet

    def _ended(self) -> str:
        code = self.process.exit_code() if self.process is not None else None
        return "its worker process ended" + (f" (exit code {code})" if code is not None else "")

    def _fall_back(self, reason: str, kill: bool = False) -> None:
        process, self.process = self.process, None
        if process is not None:
            process.close(kill=kill)
        self.solver, self._in_flight, self.solving = None, None, False
        self._say(f"{self.name}: {reason}; solving it in this process from now on")

    def close(self) -> None:
        if self.process is not None:
            self.process.close()


@dataclass
class LiveUpdate:
    """What one pump brings: the newest frame it took (its device poses, internal frame) and each
    follower's solved pose (None while it waits for devices or skipped the frame), with the frame
    each pose was solved from (`frames`: the pump's first frame, or a newer one taken before a
    follower's turn; `frame_of`), when (perf_counter) the pump took the first frame (`taken`) and
    each follower's (`taken_at`), when each follower's solve was done and when its pose was set
    (`LiveSession.posed`): the latency's stages."""

    frame: LiveFrame
    poses: dict[str, SolvedFrames | None]
    taken: float = 0.0
    frames: dict[str, LiveFrame] = field(default_factory=dict)
    taken_at: dict[str, float] = field(default_factory=dict)
    solved_at: dict[str, float] = field(default_factory=dict)
    posed_at: dict[str, float] = field(default_factory=dict)
    pushed: set[str] = field(default_factory=set)  # the followers the frame was pushed to (here or sent)
    notes: list[str] = field(default_factory=list)  # lines to say (a worker that ended, a solve that failed)
    cpu_ms: float = 0.0  # the pump's own CPU time (this thread: solves here, hand-overs, the on_pose calls)

    def frame_of(self, name: str) -> LiveFrame:
        """The frame `name`'s pose was solved from."""
        return self.frames.get(name, self.frame)


class LiveSession:
    """A live source with its followers and recorder (module docstring). `roles` (device name ->
    role) are the user's: they win over roles the stream announces."""

    def __init__(self, source: LiveSource, roles: dict[str, str] | None = None):
        self.source = source
        self.user_roles = dict(roles or {})
        self.followers: dict[str, Follower] = {}
        self.recorder = None  # recording.live.recorder.LiveRecorder while recording
        self._lock = threading.Lock()
        self._kinds: dict[str, str] = {}
        self._announced: dict[str, str] = {}
        self._frames: dict[str, int] = {}
        self._first_frame: dict[str, int] = {}
        self._arrivals: dict[str, deque] = {}
        self._markers: list[str] = []
        self._marker_set: set[str] = set()
        self._stream_frames = 0
        self.recording_from = 0  # frames_seen when the recording started
        self.last_frame: LiveFrame | None = None
        self.clock = PumpClock()
        source.add_sink(self._on_frame)

    # --- the source ---------------------------------------------------------------------------------

    def start(self) -> None:
        self.source.start()

    def stop(self) -> None:
        """Stop the source and end every follower's worker process."""
        for follower in self.followers.values():
            follower.close()
        self.source.stop()

    @property
    def stats(self):
        return self.source.stats

    def _on_frame(self, frame: LiveFrame) -> None:
        """The sink: on the source's thread, with every frame (module docstring)."""
        with self._lock:
            for event in frame.events:
                if event[0] == "device":
                    _, name, kind, role = event
                    self._kinds[name] = kind
                    if role:
                        self._announced[name] = role
                elif event[0] == "marker" and event[1] not in self._marker_set:
                    self._marker_set.add(event[1])
                    self._markers.append(event[1])
            for name in frame.markers:
                if name not in self._marker_set:
                    self._marker_set.add(name)
                    self._markers.append(name)
            k = self._stream_frames
            for name in frame.devices:
                self._kinds.setdefault(name, "tracker")
                self._frames[name] = self._frames.get(name, 0) + 1
                self._first_frame.setdefault(name, k)
                self._arrivals.setdefault(name, deque(maxlen=1024)).append(frame.arrival)
            self._stream_frames = k + 1
            recorder = self.recorder
        if recorder is not None:
            recorder(frame)

    @property
    def frames_seen(self) -> int:
        """Frames the source made since the session started (every one reached the sink)."""
        return self._stream_frames

    @property
    def kinds(self) -> dict[str, str]:
        with self._lock:
            return dict(self._kinds)

    @property
    def markers(self) -> list[str]:
        """The markers the stream has named or sent, in the order first seen."""
        with self._lock:
            return list(self._markers)

    @property
    def roles(self) -> dict[str, str]:
        """Device name -> role: the user's, else the stream's, else what the recorder identified
        from a T-pose (the wizard's first step)."""
        with self._lock:
            roles = dict(self._announced)
        if self.recorder is not None:
            roles.update(self.recorder.identified_roles)
        roles.update(self.user_roles)
        return roles

    def devices(self, now: float | None = None) -> list[DeviceStatus]:
        """Every device the stream has named, in the order first seen."""
        now = time.perf_counter() if now is None else now
        roles = self.roles
        with self._lock:
            out = []
            for name, kind in self._kinds.items():
                recent = [a for a in self._arrivals.get(name, ()) if now - a <= RATE_WINDOW_S]
                rate = (len(recent) - 1) / (recent[-1] - recent[0]) if len(recent) > 1 and recent[-1] > recent[0] \
                    else 0.0
                seen = self._frames.get(name, 0)
                missed = self._stream_frames - self._first_frame.get(name, self._stream_frames) - seen
                out.append(DeviceStatus(name, kind, roles.get(name), seen, max(missed, 0), rate))
        return out

    # --- followers ------------------------------------------------------------------------------------

    def follow(self, name: str, user: BodyModel, avatar: BodyModel, method: str = "egocentric", *,
               smooth: OneEuro | None = None, plant_feet: bool = True, placement: str = "object",
               worker: bool = False) -> Follower:
        """`name` follows from the next frame (replacing a follower of that name). `smooth` is the
        whole-take One Euro configuration: it runs forward here (`forward_filter`). `worker`: solved
        in a process of its own (`WorkerFollower`; `solve_in_workers` says when that pays)."""
        kind = WorkerFollower if worker else Follower
        follower = kind(name, user, avatar, method, smooth=forward_filter(smooth), plant_feet=plant_feet,
                        placement=placement)
        self.unfollow(name)
        self.followers[name] = follower
        return follower

    def unfollow(self, name: str) -> Follower | None:
        follower = self.followers.pop(name, None)
        if follower is not None:
            follower.close()
        return follower

    # --- recording ----------------------------------------------------------------------------------

    def start_recording(self, name: str = "live"):
        """Every frame from now on into a LiveRecorder (recording/live/recorder.py), with the roles
        the user gave."""
        if self.recorder is not None:
            raise BodyCalError("already recording", hint="stop the recording first")
        recorder = LiveRecorder(name, roles=self.user_roles)
        with self._lock:
            recorder.kinds.update(self._kinds)  # devices announced before: their kinds and roles
            recorder.announced_roles.update(self._announced)
            self.recorder = recorder
            self.recording_from = self._stream_frames
        return recorder

    def stop_recording(self):
        """The recorder, no longer fed; None when none ran."""
        with self._lock:
            recorder, self.recorder = self.recorder, None
        return recorder

    # --- the pump -------------------------------------------------------------------------------------

    def wait(self, timeout: float) -> bool:
        """Block until a frame waits to be taken or a follower is `behind` (True), at most `timeout`
        s (False); `wait(0)` only says whether one does."""
        return self.behind() or self.source.wait(timeout)

    def next_delay(self, now: float | None = None) -> float:
        """Seconds until the pump should look for the next frame (pump_clock.PumpClock): 0 when one
        waits, else its expected arrival from the stream's beat."""
        return self.clock.next_delay(time.perf_counter() if now is None else now, self.wait(0))

    def pump(self, on_pose=None) -> LiveUpdate | None:
        """Take the latest frame and solve it for every follower; None when no new frame came and
        no follower is `behind` (else those solve the newest taken: a pump catching up).
        `on_pose(update, name)` is called as soon as each follower's pose is solved: the frame goes
        to every worker first, the followers of this process are solved (each set before the next
        solve; each after the first on the newest frame there is by then) while the workers solve
        theirs, then each worker's pose is set as its answer comes (the first avatar does not wait
        for the others)."""
        frame = self.source.latest()
        catching_up = frame is None
        if catching_up:  # no new frame: the followers that have not solved the newest taken solve it
            frame = self.last_frame
            if frame is None or not self.behind():
                return None
        c0 = time.thread_time()
        update = LiveUpdate(frame, {}, time.perf_counter())
        if not catching_up:
            self._took(frame)
        kinds = roles = markers = None
        here, sent, shared = [], [], {}
        followers = list(self.followers.values())
        for follower in followers:
            name = follower.name
            update.poses[name] = None
            if follower.in_worker:
                follower.poll()
            if not follower.ready:
                if kinds is None:
                    kinds, roles, markers = self.kinds, self.roles, self.markers
                if not follower.prepare(kinds, roles, markers):
                    continue
            if not follower.in_worker:
                here.append(follower)
            elif follower.last_index < frame.index and follower.send(frame, shared):
                follower.last_index = frame.index
                update.pushed.add(name)
                update.frames[name], update.taken_at[name] = frame, update.taken
                if follower.solving:  # its answer is waited for (not a preparation's)
                    sent.append(follower)
        taken = update.taken
        for k, follower in enumerate(here):
            newer = self.source.latest() if k else None  # came while the ones before solved
            if newer is not None:
                frame, update.frame, taken = newer, newer, time.perf_counter()
                self._took(frame)
            if follower.last_index >= frame.index:  # solved it in the pump before (this one catches up)
                continue
            follower.last_index = frame.index
            update.pushed.add(follower.name)
            update.frames[follower.name], update.taken_at[follower.name] = frame, taken
            update.poses[follower.name] = follower.push(frame)
            update.solved_at[follower.name] = time.perf_counter()
            if on_pose is not None and update.poses[follower.name] is not None:
                on_pose(update, follower.name)
        self._collect(update, sent, on_pose)
        for follower in followers:
            update.notes += follower.said()
        update.cpu_ms = (time.thread_time() - c0) * 1000.0
        return update

    def behind(self) -> bool:
        """Whether a follower ready for a frame has not been given the newest one taken (an avatar
        solved before a newer frame came, in the same pump): the next pump is due at once."""
        frame = self.last_frame
        return frame is not None and any(f.ready and f.last_index < frame.index and not f.busy
                                         for f in self.followers.values())

    def _took(self, frame: LiveFrame) -> None:
        self.clock.taken(frame.index, frame.arrival)
        self.last_frame = frame

    def _collect(self, update: LiveUpdate, sent: list, on_pose) -> None:
        """Each worker's pose of the frame, set as its answer comes."""
        waiting = {follower.connection: follower for follower in sent}
        deadline = time.perf_counter() + ANSWER_S
        while waiting:
            ready = wait_for_connections(list(waiting), timeout=max(0.0, deadline - time.perf_counter()))
            if not ready:
                for follower in waiting.values():
                    follower.stuck()
                return
            for connection in ready:
                follower = waiting.pop(connection)
                solved = follower.receive()
                update.poses[follower.name] = solved
                if solved is not None:
                    update.solved_at[follower.name] = time.perf_counter()
                    if on_pose is not None:
                        on_pose(update, follower.name)

    def posed(self, update: LiveUpdate, name: str, at: float | None = None) -> None:
        """Note that `name`'s pose of `update` is now set (on the armature, or sent): the latency
        from the frame's arrival to `at` (now when None)."""
        at = time.perf_counter() if at is None else at
        update.posed_at[name] = at
        self.followers[name].stats.latency_ms.append((at - update.frame_of(name).arrival) * 1000.0)
