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
for each follower with its `LiveSolver` (retarget/live.py): the causal stance and the forward One
Euro, from the frames so far only. The session's `clock` (pump_clock.PumpClock) learns the stream's
beat from the frames taken and says when the next pump should look (`next_delay`); `wait` blocks
until a frame is there, for a loop that may block.

It imports the recorder, hence python-osc (recording/live/__init__.py): only what runs a live
session imports it.
"""

from __future__ import annotations

import threading
import time
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from ..body.bodymodel import BodyModel
from ..calibration.coverage import ANIMATED_ROLES
from ..core.errors import BodyCalError
from ..recording.filters import OneEuro
from ..recording.live.recorder import LiveRecorder
from ..recording.live.source import LiveFrame, LiveSource
from ..recording.model import Device
from .live import LiveSolver
from .pump_clock import PumpClock
from .solver import SolvedFrames

RATE_WINDOW_S = 1.0  # a device's rate: its frames over the last second
STATS_WINDOW = 512  # solve times and latencies kept per follower (the figures shown are over these)


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

    def line(self) -> str:
        if not self.solve_ms:
            return "no frame solved yet"
        solve, lat = np.asarray(self.solve_ms), np.asarray(self.latency_ms or [np.nan])
        return (f"solve {np.median(solve):.1f} ms, latency {np.median(lat):.1f} ms "
                f"(p95 {np.percentile(lat, 95):.1f} ms)")


class Follower:
    """An avatar following the stream: `user` (the performer's calibrated model) onto `avatar` by
    `method`. Its solver is made once every role the methods need has a device the stream has
    named (`waiting_for` says which are missing until then)."""

    def __init__(self, name: str, user: BodyModel, avatar: BodyModel, method: str = "egocentric", *,
                 smooth: OneEuro | None = None, plant_feet: bool = True, placement: str = "object"):
        if user.kind != "user":
            raise BodyCalError(f"expected a user body model, got kind '{user.kind}'", source=name)
        if avatar.kind != "avatar" or "rig" not in avatar.extra:
            raise BodyCalError("expected an avatar body model with its rig", source=name,
                               hint="calibrate the avatar first")
        self.name, self.user, self.avatar, self.method = name, user, avatar, method
        self.smooth, self.plant_feet, self.placement = smooth, plant_feet, placement
        self.solver = None  # retarget.live.LiveSolver, once prepared
        self.order: dict[str, int] = {}  # device name -> its column in the solver's arrays
        self.marker_order: dict[str, int] = {}  # marker name -> its column (LED gloves: the fingers)
        self.stats = FollowerStats()
        self.waiting_for: list[str] = sorted(ANIMATED_ROLES)

    @property
    def bone_names(self) -> list[str]:
        prepared = self.solver.solver if self.solver is not None else None  # made at the first solve
        return list(prepared.rig.names) if prepared is not None else []

    def prepare(self, kinds: dict[str, str], roles: dict[str, str], markers: list[str] | tuple = ()) -> bool:
        """The solver, once every role the methods need has a device the stream has named; the
        `markers` named by then pose the fingers (a marker first seen later is not read)."""
        if self.solver is not None:
            return True
        named = {n: r for n, r in roles.items() if n in kinds and r}
        self.waiting_for = sorted(set(ANIMATED_ROLES) - set(named.values()))
        if self.waiting_for:
            return False
        devices = [Device(n, kinds[n], r) for n, r in named.items()]
        self.order = {d.name: i for i, d in enumerate(devices)}
        self.marker_order = {m: i for i, m in enumerate(markers)}
        self.solver = LiveSolver(self.user, self.avatar, self.method, devices=devices, marker_names=list(markers),
                                 smooth=self.smooth, plant_feet=self.plant_feet, placement=self.placement)
        return True

    def push(self, frame: LiveFrame) -> SolvedFrames | None:
        """The frame solved (one row), or None: a frame not newer than the last (a replay looping)
        or one before every device the methods need has been tracked."""
        n = len(self.order)
        pos, rot, valid = np.zeros((n, 3)), np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)), np.zeros(n, bool)
        for k, name in enumerate(frame.devices):
            i = self.order.get(name)
            if i is not None:
                pos[i], rot[i], valid[i] = frame.positions[k], frame.rotations[k], True
        t = frame.sender_time if frame.sender_time is not None else frame.arrival
        if self.solver.recording.frame_count and t <= self.solver.recording.time[-1]:
            return None  # a sender's clock that went back (a replay looping): not a new moment
        m = len(self.marker_order)
        points, seen = (np.zeros((m, 3)), np.zeros(m, bool)) if m else (None, None)
        for k, name in enumerate(frame.markers if m else ()):
            i = self.marker_order.get(name)
            if i is not None:
                points[i], seen[i] = frame.points[k], True
        t0, c0 = time.perf_counter(), time.thread_time()
        solved = self.solver.push(t, pos, rot, valid, points, seen)
        if solved is not None:
            self.stats.solve_cpu_ms.append((time.thread_time() - c0) * 1000.0)
            self.stats.solve_ms.append((time.perf_counter() - t0) * 1000.0)
            self.stats.frames += 1
        return solved


@dataclass
class LiveUpdate:
    """What one pump brings: the frame (its device poses, internal frame) and each follower's
    solved pose (None while it waits for devices or skipped the frame), with when (perf_counter)
    the pump took the frame, when each follower's solve was done and when its pose was set
    (`LiveSession.posed`): the latency's stages."""

    frame: LiveFrame
    poses: dict[str, SolvedFrames | None]
    taken: float = 0.0
    solved_at: dict[str, float] = field(default_factory=dict)
    posed_at: dict[str, float] = field(default_factory=dict)


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
               smooth: OneEuro | None = None, plant_feet: bool = True, placement: str = "object") -> Follower:
        """`name` follows from the next frame (replacing a follower of that name). `smooth` is the
        whole-take One Euro configuration: it runs forward here (`forward_filter`)."""
        follower = Follower(name, user, avatar, method, smooth=forward_filter(smooth), plant_feet=plant_feet,
                            placement=placement)
        self.followers[name] = follower
        return follower

    def unfollow(self, name: str) -> Follower | None:
        return self.followers.pop(name, None)

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
        """Block until a frame waits to be taken (True), at most `timeout` s (False); `wait(0)` only
        says whether one does."""
        return self.source.wait(timeout)

    def next_delay(self, now: float | None = None) -> float:
        """Seconds until the pump should look for the next frame (pump_clock.PumpClock): 0 when one
        waits, else its expected arrival from the stream's beat."""
        return self.clock.next_delay(time.perf_counter() if now is None else now, self.source.wait(0))

    def pump(self, on_pose=None) -> LiveUpdate | None:
        """Take the latest frame and solve it for every follower; None when no new frame came.
        `on_pose(update, name)` is called as soon as each follower's pose is solved (before the
        next follower's solve: the first avatar is set while the others are solved)."""
        frame = self.source.latest()
        if frame is None:
            return None
        update = LiveUpdate(frame, {}, time.perf_counter())
        self.clock.taken(frame.index, frame.arrival)
        self.last_frame = frame
        kinds, roles = None, None
        for name, follower in list(self.followers.items()):
            if follower.solver is None:
                kinds, roles = kinds or self.kinds, roles or self.roles
                if not follower.prepare(kinds, roles, self.markers):
                    update.poses[name] = None
                    continue
            update.poses[name] = follower.push(frame)
            update.solved_at[name] = time.perf_counter()
            if on_pose is not None and update.poses[name] is not None:
                on_pose(update, name)
        return update

    def posed(self, update: LiveUpdate, name: str, at: float | None = None) -> None:
        """Note that `name`'s pose of `update` is now set (on the armature, or sent): the latency
        from the frame's arrival to `at` (now when None)."""
        at = time.perf_counter() if at is None else at
        update.posed_at[name] = at
        self.followers[name].stats.latency_ms.append((at - update.frame.arrival) * 1000.0)
