"""The avatars that follow a live session (DESIGN.md §9 "Live session"): each one's solver, where it
runs, and what it hands back. No bpy.

A `Follower` solves in this process, on the session's solving thread (session.py), never on the
thread that pumps the session (Blender's main thread); a `WorkerFollower` solves in a worker
process of its own (worker.py), the same `LiveSolver` fed the same arrays, so the same poses. Both
are handed frames by the session's thread as they arrive, latest wins: a follower still solving
one frame is handed the newest there is when it is done, and every frame it never solved is counted
(`FollowerStats.skipped`). What it solved waits in a one-pose slot for the pump (`take_result`); a
pose replaced there before the pump set it is counted too (`FollowerStats.unshown`).
"""

from __future__ import annotations

import dataclasses
import sys
import threading
import time
import traceback
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from ..body.bodymodel import BodyModel
from ..calibration.coverage import ANIMATED_ROLES
from ..core.errors import BodyCalError
from ..recording.filters import OneEuro
from ..recording.live.source import LiveFrame
from ..recording.model import Device
from ..retarget.solver import SolvedFrames
from .solver import LiveSolver
from .worker import SolverProcess, frame_message, pickled, prepare_message, solved_from

STATS_WINDOW = 512  # solve times and latencies kept per follower (the figures shown are over these)
ANSWER_S = 2.0  # a worker that solved before and gives no answer to a frame in this long is stuck: ended


@dataclass
class FollowerStats:
    """What a follower did: `frames` poses solved, `handed` frames handed to its solver (a frame
    before every needed device was tracked gives no pose), `skipped` frames of the stream it was
    never handed (it was solving the one before), `unshown` poses replaced before the pump set
    them; over the last STATS_WINDOW, the solve's times and the latency."""

    frames: int = 0
    handed: int = 0
    skipped: int = 0
    unshown: int = 0
    solve_ms: deque = field(default_factory=lambda: deque(maxlen=STATS_WINDOW))  # wall: handed -> solved
    solve_cpu_ms: deque = field(default_factory=lambda: deque(maxlen=STATS_WINDOW))  # the solving thread's CPU
    latency_ms: deque = field(default_factory=lambda: deque(maxlen=STATS_WINDOW))  # arrival -> pose set
    worker_ms: deque = field(default_factory=lambda: deque(maxlen=STATS_WINDOW))  # a worker's own push (wall)
    indices: deque = field(default_factory=lambda: deque(maxlen=STATS_WINDOW))  # the frames handed (their index)
    worker_memory: tuple = (0, 0)  # a worker's (bytes of the frames its solver keeps, peak resident MB), last answer

    @property
    def not_shown(self) -> int:
        """Frames of the stream since it first solved that it did not show: skipped or replaced."""
        return self.skipped + self.unshown

    def line(self) -> str:
        if not self.solve_ms:
            return "no frame solved yet"
        solve, lat = np.asarray(list(self.solve_ms)), np.asarray(list(self.latency_ms) or [np.nan])
        return (f"solve {np.median(solve):.1f} ms, latency {np.median(lat):.1f} ms "
                f"(p95 {np.percentile(lat, 95):.1f} ms), {self.not_shown} of {self.handed + self.skipped} "
                "frames skipped")


@dataclass(frozen=True)
class RigLayout:
    """What a pose writer needs of the avatar's rig: the armature's name, the bones in the order of
    `SolvedFrames.basis` and the root bone's index in it."""

    armature: str
    names: tuple[str, ...]
    root: int


@dataclass(frozen=True)
class Result:
    """A frame a follower's solver was handed, and what came of it: `solved` (None: not newer than
    the last, or a needed device not tracked yet), when it was handed over and when it was solved
    (perf_counter), and what the follower's `convert` made of the pose (None without one)."""

    solved: SolvedFrames | None
    frame: LiveFrame
    handed_at: float
    solved_at: float
    converted: object = None


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


class Follower:
    """An avatar following the stream: `user` (the performer's calibrated model) onto `avatar` by
    `method`, solved in this process. Its solver is made once every role the methods need has a
    device the stream has named (`waiting_for` says which are missing until then)."""

    in_worker = False  # solved in this process

    def __init__(self, name: str, user: BodyModel, avatar: BodyModel, method: str = "egocentric", *,
                 smooth: OneEuro | None = None, plant_feet: bool = True, placement: str = "object",
                 seat_height: float | None = None):
        if user.kind != "user":
            raise BodyCalError(f"expected a user body model, got kind '{user.kind}'", source=name)
        if avatar.kind != "avatar" or "rig" not in avatar.extra:
            raise BodyCalError("expected an avatar body model with its rig", source=name,
                               hint="calibrate the avatar first")
        self.name, self.user, self.avatar, self.method = name, user, avatar, method
        self.smooth, self.plant_feet, self.placement = smooth, plant_feet, placement
        self.seat_height = seat_height  # a seated performer of a kit without foot trackers (lower_body)
        self.solver = None  # live.solver.LiveSolver, once prepared
        self.order: dict[str, int] = {}  # device name -> its column in the solver's arrays
        self.marker_order: dict[str, int] = {}  # marker name -> its column (LED gloves: the fingers)
        self.stats = FollowerStats()
        self.last_index = -1  # the newest frame (LiveFrame.index) handed to its solver
        self.handed_at: float | None = None  # when the frame being solved was handed over (None: idle)
        self.closed = False
        # What the pose's writer wants of each solved pose, made on the solving thread as it comes (the
        # Blender glue: root motion), so that the pump's thread only sets it: convert(solved, frame).
        self.convert = None
        # the roles a device must come for: the animated ones the user's calibration does not estimate
        self.needs = set(ANIMATED_ROLES) - set((user.extra or {}).get("estimated_devices") or {})
        self.waiting_for: list[str] = sorted(self.needs)
        self.note = ""  # the last thing to say about it (a worker that ended), one line
        self._lock = threading.Lock()  # the result slot and the lines to say: the solving thread and the pump
        self._result: Result | None = None
        self._unsaid: list[str] = []  # lines for the pump to say (`said`)

    @property
    def ready(self) -> bool:
        """Prepared: the next frame can be handed over."""
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

    @property
    def busy(self) -> bool:
        """Solving a frame handed over before: not to be handed the next."""
        return self.handed_at is not None

    def _devices(self, kinds: dict[str, str], roles: dict[str, str], markers) -> list[Device] | None:
        """The devices the solver reads (their columns in `order`, the markers' in `marker_order`),
        or None while a role the methods need has no device the stream has named."""
        named = {n: r for n, r in roles.items() if n in kinds and r}
        self.waiting_for = sorted(self.needs - set(named.values()))
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
                                 smooth=self.smooth, plant_feet=self.plant_feet, placement=self.placement,
                                 seat_height=self.seat_height)
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

    def _handing(self, frame: LiveFrame) -> float:
        """`frame` is handed to the solver now: the frames of the stream it never got are counted."""
        if self.last_index >= 0:
            self.stats.skipped += max(frame.index - self.last_index - 1, 0)
        self.last_index = frame.index
        self.stats.handed += 1
        self.stats.indices.append(frame.index)
        self.handed_at = time.perf_counter()
        return self.handed_at

    def solve(self, frame: LiveFrame) -> None:
        """Solve `frame` here (the session's solving thread) and leave the result for the pump. A
        solve that fails is one line (`said`) and no pose; the next frame is solved as ever."""
        handed_at = self._handing(frame)
        arrays = self.arrays(frame)
        c0 = time.thread_time()
        try:
            solved = self.solver.push_newer(*arrays)
        except BodyCalError as exc:
            solved = None
            self._say(f"{self.name}: {exc.line()}")
        except Exception as exc:  # noqa: BLE001 - a bug in one solve: its traceback, one line, the stream goes on
            solved = None
            traceback.print_exc(file=sys.stderr)
            self._say(f"{self.name}: the solve failed: {type(exc).__name__}: {exc}")
        done = time.perf_counter()
        if solved is not None:
            self.stats.solve_cpu_ms.append((time.thread_time() - c0) * 1000.0)
            self.stats.solve_ms.append((done - handed_at) * 1000.0)
            self.stats.frames += 1
        try:
            self._deliver(Result(solved, frame, handed_at, done))
        finally:
            self.handed_at = None  # idle only once the result is in its slot (`busy`, `has_result`)

    def _deliver(self, result: Result) -> None:
        """The result into the slot the pump takes from (converted first, when the follower has a
        `convert`), latest wins: a pose not yet taken is replaced (counted); a frame that gave no
        pose never replaces one."""
        convert = self.convert
        if convert is not None and result.solved is not None:
            try:
                result = dataclasses.replace(result, converted=convert(result.solved, result.frame))
            except Exception as exc:  # noqa: BLE001 - the pump's thread converts it instead, and says nothing new
                self._say(f"{self.name}: its pose could not be converted here ({type(exc).__name__}: {exc})")
                self.convert = None
        with self._lock:
            pending = self._result
            if pending is not None and pending.solved is not None:
                if result.solved is None:
                    return
                self.stats.unshown += 1
            self._result = result

    @property
    def has_result(self) -> bool:
        return self._result is not None

    def take_result(self) -> Result | None:
        """The newest result not yet taken (the pump's), or None."""
        with self._lock:
            result, self._result = self._result, None
        return result

    def said(self) -> list[str]:
        """The lines to say since the last call (a worker that ended, a solve that failed)."""
        with self._lock:
            lines, self._unsaid = self._unsaid, []
        return lines

    def _say(self, line: str) -> None:
        with self._lock:
            self.note = line
            self._unsaid.append(line)

    def expected_done(self) -> float | None:
        """When the frame being solved should be done (perf_counter; the median solve so far), or
        None when idle or nothing solved yet."""
        handed, times = self.handed_at, list(self.stats.solve_ms)
        if handed is None or not times:
            return None
        return handed + float(np.median(times)) / 1000.0

    def close(self) -> None:
        """Nothing to end here (a WorkerFollower ends its process)."""
        self.closed = True


class WorkerFollower(Follower):
    """A Follower whose LiveSolver runs in a worker process (worker.py): the same solver, fed the
    same arrays, so the same poses. The process starts when the follower is made (`state`
    "starting"), is given the models and devices once the roles are there ("preparing"), then
    solves each frame it is sent ("running"). One frame in flight at most. A worker that cannot
    start, ends or gives no answer in ANSWER_S is said in one line (`note`) and the follower goes
    on solving in this process (the session's solving thread). `on_change` is called (on the
    process's starting thread) once the process is up or could not start."""

    def __init__(self, *args, command: list[str] | None = None, on_change=None, **kwargs):
        super().__init__(*args, **kwargs)
        self.process: SolverProcess | None = SolverProcess(self.name, command, on_change=on_change)
        self.kernels = ""  # what the worker solves one frame with ("mathutils" or "numpy"), once ready
        self.solving = False  # a pose has come: each frame's answer is due within ANSWER_S
        self._layout: RigLayout | None = None
        self._prepare_sent = False
        self._in_flight: str | None = None  # "prepare" or "frame": what the worker has not answered yet
        self._sent_frame: LiveFrame | None = None

    @property
    def in_worker(self) -> bool:
        return self.process is not None

    @property
    def connection(self):
        return self.process.connection if self.process is not None else None

    @property
    def busy(self) -> bool:
        return super().busy if self.process is None else self._in_flight is not None

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
                                      self.plant_feet, self.placement, self.seat_height)
        except (TypeError, ValueError) as exc:  # a model JSON cannot hold (NaN): this process says what is wrong
            self._fall_back(f"its models could not be sent to its worker ({exc})")
            return False
        if self._send(message, "prepare"):
            self._prepare_sent = True
        return False

    def check(self) -> None:
        """Notice a worker that could not start or has ended while idle."""
        if self.process is None:
            return
        if self.process.error:
            self._fall_back(self.process.error)
        elif self.process.connection is not None and self._in_flight is None and not self.process.alive():
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
        last, handed, skipped = self.last_index, self.stats.handed, self.stats.skipped
        self._handing(frame)
        if not self._send(message, "frame"):  # ended: not handed after all
            self.last_index, self.stats.handed, self.stats.skipped = last, handed, skipped
            self.stats.indices.pop()
            return False
        self._sent_frame = frame
        return True

    def receive(self) -> None:
        """The worker's answer (its connection is ready): the pose into the slot, the rig's layout
        after a preparation, or the worker's end noticed."""
        try:
            reply = self.process.connection.recv()
        except (EOFError, OSError):
            self._fall_back(self._ended())
            return
        self._take(reply)

    def answer_due(self) -> float | None:
        """When a frame's answer becomes overdue (perf_counter), or None when none is awaited so."""
        return self.handed_at + ANSWER_S if self._in_flight == "frame" and self.solving else None

    def overdue(self, now: float) -> bool:
        """A frame's answer not come in ANSWER_S (only once the worker has solved: a preparation
        may take its time)."""
        return self._in_flight == "frame" and self.solving and now - self.handed_at > ANSWER_S

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
        self._in_flight = what
        if what == "prepare":
            self.handed_at = time.perf_counter()
        return True

    def _take(self, reply: tuple) -> None:
        try:
            self._answered(reply, self._in_flight, self._sent_frame, self.handed_at)
        finally:  # idle only once the result is in its slot (`busy`, `has_result`)
            self._in_flight = self._sent_frame = self.handed_at = None

    def _answered(self, reply: tuple, what: str | None, frame: LiveFrame | None, handed_at: float | None) -> None:
        kind = reply[0]
        if kind == "ready":
            self._layout = RigLayout(reply[1]["armature"], tuple(reply[1]["names"]), int(reply[1]["root"]))
            self.kernels = reply[1].get("kernels", "")
            return
        if kind == "error":
            if what == "prepare":  # this process makes the same solver and says what is wrong with it
                self._fall_back(f"its worker could not prepare ({reply[1]})")
                return
            self._say(f"{self.name}: {reply[1]}")
        if frame is None:
            return
        solved = None
        if kind == "pose":
            self.solving = True
            now = time.perf_counter()
            self.stats.solve_ms.append((now - handed_at) * 1000.0)
            self.stats.solve_cpu_ms.append(reply[6])
            self.stats.worker_ms.append(reply[7])
            self.stats.worker_memory = tuple(reply[8:10])
            self.stats.frames += 1
            solved = solved_from(reply)
        self._deliver(Result(solved, frame, handed_at, time.perf_counter()))  # "none": no pose, handled

    def _ended(self) -> str:
        code = self.process.exit_code() if self.process is not None else None
        return "its worker process ended" + (f" (exit code {code})" if code is not None else "")

    def _fall_back(self, reason: str, kill: bool = False) -> None:
        process, self.process = self.process, None
        if process is not None:
            process.close(kill=kill)
        self.solver, self._in_flight, self.solving, self.handed_at = None, None, False, None
        self._sent_frame = None
        self._say(f"{self.name}: {reason}; solving it in this process from now on")

    def close(self) -> None:
        if self.process is not None:
            self.process.close()
        self.closed = True  # after: `LiveSession.unfollow` waits for it
