"""`LiveSession`: a live source, what it records and the avatars that follow it, pumped by whoever
runs the loop (DESIGN.md "Live session"): the command line's `bodycal live`, Blender's timer or a
headless station's explicit pump (bodycal_addon/blender/live.py). No bpy.

    session = LiveSession(VmcReceiver(port, bind))
    session.start()
    session.follow("avatar", user_model, avatar_model, "egocentric", worker=True)
    update = session.pump(on_pose)   # the newest frame (its device poses) and the poses solved since
    delay = session.next_delay()     # when to look again: the stream's beat, a pose's expected answer
    session.start_recording("take"); ...; recorder = session.stop_recording()
    session.stop()

The source's thread gives every frame to the session's sink (`_on_frame`), which counts each
device's frames (its rate), keeps the kinds and roles the stream announces, hands the frame on to
the recorder when one runs and wakes the session's solving thread; it copies, it does not compute.

**The solving thread** (`_solve_loop`) hands each follower the newest frame the moment it arrives,
or the moment the follower is done with the one before (latest wins: the frames it never got are
counted, `FollowerStats.skipped`): a `WorkerFollower` is sent the frame (its process solves it;
followers/worker.py), a `Follower` of this process is solved on this thread, after the workers
were sent theirs and each on the newest frame there is when its turn comes. The answers wait in
each follower's one-pose slot. So the thread that pumps (Blender's main thread) never solves and
never waits for a solve: `pump` takes the newest frame and the poses that are there and calls
`on_pose` for each (Blender writes it on the armature). `wait` blocks until a frame or a pose is
there, for a loop that may block; the session's `clock` (pump_clock.PumpClock) learns the stream's
beat from the frames taken, and `next_delay` says when to look again, for a loop that may not.

It imports the recorder, hence python-osc (recording/live/__init__.py): only what runs a live
session imports it.
"""

from __future__ import annotations

import sys
import threading
import time
import traceback
from collections import deque
from dataclasses import dataclass, field
from multiprocessing.connection import Pipe
from multiprocessing.connection import wait as wait_for_connections

from ..body.bodymodel import BodyModel
from ..core.errors import BodyCalError
from ..recording.filters import OneEuro
from ..recording.live.recorder import LiveRecorder
from ..recording.live.source import LiveFrame, LiveSource
from ..retarget.solver import SolvedFrames
from .followers import Follower, WorkerFollower
from .pump_clock import POLL_S, PumpClock

RATE_WINDOW_S = 1.0  # a device's rate: its frames over the last second
IDLE_WAKE_S = 0.25  # the solving thread looks at its followers at least this often (a worker that ended)
STOP_S = 5.0  # the longest `stop` and `unfollow` wait for the solving thread (it is milliseconds)


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
class LiveUpdate:
    """What one pump brings: the newest frame it took (its device poses, internal frame; None when
    only poses came) and each follower's result that came since the last pump: its pose (None: the
    frame gave none, a needed device not tracked yet), the frame it was solved from (`frames`,
    `frame_of`), when the frame was handed to its solver (`taken_at`), when it was solved
    (`solved_at`) and when its pose was set (`LiveSession.posed`): the latency's stages. `taken` is
    when the pump ran."""

    frame: LiveFrame | None
    poses: dict[str, SolvedFrames | None]
    taken: float = 0.0
    frames: dict[str, LiveFrame] = field(default_factory=dict)
    taken_at: dict[str, float] = field(default_factory=dict)
    solved_at: dict[str, float] = field(default_factory=dict)
    posed_at: dict[str, float] = field(default_factory=dict)
    pushed: set[str] = field(default_factory=set)  # the followers with a result in this update
    converted: dict[str, object] = field(default_factory=dict)  # each pose as the follower's `convert` made it
    notes: list[str] = field(default_factory=list)  # lines to say (a worker that ended, a solve that failed)
    cpu_ms: float = 0.0  # the pump's own CPU time (its thread: taking the results, the on_pose calls)

    def frame_of(self, name: str) -> LiveFrame | None:
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
        self.last_frame: LiveFrame | None = None  # the newest frame the pump took
        self.frames_not_taken = 0  # frames the pump never took (it ran slower than the stream): counted
        self.clock = PumpClock()
        self._newest: LiveFrame | None = None  # the newest frame the sink saw
        self._ready = threading.Event()  # a frame or a result waits for the pump
        self._wake_r, self._wake_w = Pipe(duplex=False)  # the sink and the workers' starts wake the thread
        self._wake_pending = False
        self._thread: threading.Thread | None = None
        self._stopping = threading.Event()
        self._closing: list[Follower] = []  # followers the thread is to end (it owns their connections)
        self._unsaid: list[str] = []  # the session's own lines (the solving thread's failures)
        source.add_sink(self._on_frame)

    # --- the source ---------------------------------------------------------------------------------

    def start(self) -> None:
        self.source.start()

    def stop(self) -> None:
        """Stop the source, the solving thread and every follower's worker process."""
        self._stopping.set()
        self._wake()
        thread = self._thread
        if thread is not None and thread is not threading.current_thread():
            thread.join(STOP_S)
        with self._lock:
            followers, self._closing = list(self.followers.values()) + self._closing, []
        for follower in followers:
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
            self._newest = frame
            recorder = self.recorder
            following = bool(self.followers)
        if recorder is not None:
            recorder(frame)
        self._ready.set()
        if following:
            self._wake()

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
        recorder = self.recorder
        if recorder is not None:
            roles.update(recorder.identified_roles)
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
               seat_height: float | None = None, worker: bool = False, command: list[str] | None = None) -> Follower:
        """`name` follows from the next frame (replacing a follower of that name). `smooth` is the
        whole-take One Euro configuration: it runs forward here (`forward_filter`). `worker`: solved
        in a process of its own (`WorkerFollower`; `command` the program that runs it,
        worker.python_command() by default), else on the session's solving thread. `seat_height`:
        the performer seated (a kit without foot trackers: the estimated pelvis on the seat,
        lower_body)."""
        options = dict(smooth=forward_filter(smooth), plant_feet=plant_feet, placement=placement,
                       seat_height=seat_height)
        follower = (WorkerFollower(name, user, avatar, method, command=command, on_change=self._wake,
                                   **options) if worker else Follower(name, user, avatar, method, **options))
        self.unfollow(name)
        with self._lock:
            self.followers[name] = follower
        self._start_thread()
        self._wake()
        return follower

    def unfollow(self, name: str) -> Follower | None:
        """`name` no longer follows; its worker process ends (the solving thread ends it: it owns
        the connection) before this returns."""
        with self._lock:
            follower = self.followers.pop(name, None)
            thread = self._thread
            running = thread is not None and thread.is_alive() and thread is not threading.current_thread()
            if follower is not None and running:
                self._closing.append(follower)
        if follower is None:
            return None
        if running:
            self._wake()
            deadline = time.perf_counter() + STOP_S
            while not follower.closed and time.perf_counter() < deadline and thread.is_alive():
                time.sleep(0.001)
        if not follower.closed:
            follower.close()
        return follower

    def _snapshot(self) -> list[Follower]:
        with self._lock:
            return list(self.followers.values())

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
        """Block until a frame or a follower's result waits for the pump (True), at most `timeout`
        s (False); `wait(0)` only says whether one does."""
        return self._ready.wait(timeout) if timeout > 0 else self._ready.is_set()

    def next_delay(self, now: float | None = None) -> float:
        """Seconds until the pump should look again: 0 when a frame or a result waits; else the
        next frame's expected arrival (pump_clock.PumpClock) or a solve's expected end, whichever
        comes first (once due, looked for every POLL_S)."""
        if self.wait(0):
            return 0.0
        now = time.perf_counter() if now is None else now
        delay = self.clock.next_delay(now)
        for follower in self._snapshot():
            done = follower.expected_done()
            if done is not None:
                delay = min(delay, max(done + self.clock.margin_s - now, POLL_S))
        return delay

    def pump(self, on_pose=None) -> LiveUpdate | None:
        """The newest frame not taken yet and every follower's result that came since the last
        pump; None when neither came. `on_pose(update, name)` is called for each pose, in the order
        they were solved. Nothing here solves or waits for a solve (module docstring)."""
        self._ready.clear()  # before looking: what comes from now on sets it again
        c0, taken = time.thread_time(), time.perf_counter()
        frame = self._newest
        last = self.last_frame.index if self.last_frame is not None else -1
        if frame is None or frame.index <= last:
            frame = None
        else:
            self.frames_not_taken += frame.index - last - 1 if last >= 0 else 0
            self.clock.taken(frame.index, frame.arrival)
            self.last_frame = frame
        followers = self._snapshot()
        results = [(f, r) for f in followers if (r := f.take_result()) is not None]
        with self._lock:
            notes, self._unsaid = self._unsaid, []
        for follower in followers:
            notes += follower.said()
        if frame is None and not results and not notes:
            return None
        update = LiveUpdate(frame, {}, taken, notes=notes)
        for follower, result in sorted(results, key=lambda fr: fr[1].solved_at):
            name = follower.name
            update.poses[name], update.frames[name] = result.solved, result.frame
            update.taken_at[name], update.solved_at[name] = result.handed_at, result.solved_at
            update.pushed.add(name)
            if result.converted is not None:
                update.converted[name] = result.converted
            if on_pose is not None and result.solved is not None:
                on_pose(update, name)
        update.cpu_ms = (time.thread_time() - c0) * 1000.0
        return update

    def posed(self, update: LiveUpdate, name: str, at: float | None = None) -> None:
        """Note that `name`'s pose of `update` is now set (on the armature, or sent): the latency
        from the frame's arrival to `at` (now when None)."""
        at = time.perf_counter() if at is None else at
        update.posed_at[name] = at
        follower = self.followers.get(name)
        if follower is not None:
            follower.stats.latency_ms.append((at - update.frame_of(name).arrival) * 1000.0)

    # --- the solving thread ---------------------------------------------------------------------------

    def _wake(self) -> None:
        """Wake the solving thread (the sink's new frame, a worker up, a follower to end)."""
        if self._wake_pending:
            return
        self._wake_pending = True
        try:
            self._wake_w.send_bytes(b"")
        except OSError:  # the session is being let go
            pass

    def _start_thread(self) -> None:
        with self._lock:
            if self._thread is not None or self._stopping.is_set():
                return
            self._thread = threading.Thread(target=self._solve_loop, name="bodycal-live-solve", daemon=True)
        self._thread.start()

    def _solve_loop(self) -> None:
        """The solving thread (module docstring): wait for a frame, an answer or a worker's change;
        take the answers, hand the newest frame to every idle follower; end the followers asked."""
        while not self._stopping.is_set():
            followers = self._snapshot()
            connections = [f.connection for f in followers
                           if f.in_worker and f.connection is not None and not f.closed]
            ready = wait_for_connections([self._wake_r, *connections], self._timeout(followers))
            if self._wake_r in ready:
                while self._wake_r.poll():
                    self._wake_r.recv_bytes()
                self._wake_pending = False  # after draining: a wake sent from now on is seen
            try:
                self._end_closing()
                self._solve_round(self._snapshot(), set(ready))
            except Exception as exc:  # noqa: BLE001 - a bug must not end the live view: said, and on
                traceback.print_exc(file=sys.stderr)
                with self._lock:
                    self._unsaid.append(f"the live solve failed: {type(exc).__name__}: {exc}")
                self._ready.set()

    def _timeout(self, followers: list[Follower]) -> float:
        """How long the thread may sleep: until the first worker's answer is overdue, at most
        IDLE_WAKE_S."""
        now, timeout = time.perf_counter(), IDLE_WAKE_S
        for f in followers:
            due = f.answer_due() if f.in_worker else None
            if due is not None:
                timeout = min(timeout, max(due - now, 0.0))
        return timeout

    def _end_closing(self) -> None:
        with self._lock:
            closing, self._closing = self._closing, []
        for follower in closing:
            follower.close()

    def _solve_round(self, followers: list[Follower], ready: set) -> None:
        """One turn: the answers that came, the workers' changes, the newest frame to every idle
        worker, then the followers of this process solved here, each on the newest frame there is."""
        now = time.perf_counter()
        for follower in followers:
            if not follower.in_worker:
                continue
            if follower.connection in ready:
                follower.receive()
            elif follower.overdue(now):
                follower.stuck()
            else:
                follower.check()
        frame = self._newest
        if frame is None:
            self._ready_if_results(followers)
            return
        kinds = roles = markers = None
        shared, here = {}, []
        for follower in followers:
            if follower.closed:
                continue
            if not follower.ready:
                if kinds is None:
                    kinds, roles, markers = self.kinds, self.roles, self.markers
                if not follower.prepare(kinds, roles, markers):
                    continue
            if not follower.in_worker:
                here.append(follower)
            elif not follower.busy and follower.last_index < frame.index:
                follower.send(frame, shared)
        self._ready_if_results(followers)
        for follower in here:
            frame = self._newest  # the newest there is when its turn comes
            if follower.last_index < frame.index and not follower.closed:
                follower.solve(frame)
                self._ready.set()

    def _ready_if_results(self, followers: list[Follower]) -> None:
        if any(f.has_result for f in followers):
            self._ready.set()

