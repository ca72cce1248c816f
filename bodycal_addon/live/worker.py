"""A live follower's solver in a process of its own (DESIGN.md "Live session": several avatars on
several cores). No bpy, no python-osc: the worker imports numpy and the engine's solver only.

    process = SolverProcess("avatar")        # started on a thread: `connection` is None until it is up
    process.connection.send(prepare_message(user, avatar, "egocentric", devices, markers, ...))
    process.connection.recv()                # ("ready", {"armature", "names", "root", "kernels"}) or ("error", line)
    process.connection.send(frame_message(t, positions, rotations, valid, points, seen))
    process.connection.recv()                # ("pose", ...) / ("none", ...) / ("error", line): `solved_from`
    process.close()                          # the worker ends; killed if it does not within CLOSE_S

The parent runs inside Blender as often as not, where the extension is the dynamic package
`bl_ext.<repository>.bodycal`, which another interpreter cannot import, and where pickled classes
would name it. So nothing crosses as an engine object: the models go as their FORMATS.md JSON
(`BodyModel.to_json(exact=True)`: every float64 as it is, so the worker solves what this process
would, bit for bit), the settings and devices as builtins, the frames and poses as numpy arrays. The
child runs `BOOTSTRAP`, the folder holding `bodycal_addon` its last argument: it puts that folder on
`sys.path` and imports this module from there, so `bodycal_addon` is a top-level package in the
child (the engine's imports are relative). Which program runs it (`python_command`,
`blender_command`): inside Blender, Blender itself in the background with its factory settings
(Blender's own Python, `sys.executable` there, has no `mathutils`: a frame would take the numpy
kernels, several times the instructions, core/one_frame.py); elsewhere the interpreter, isolated
(`-I`). The worker says which kernels it solves with ("ready": `kernels`).

The two ends meet on a `multiprocessing.connection` Listener the child opens (a Unix socket in
the abstract namespace on Linux, one in a private temporary folder on macOS, a named pipe on
Windows), authenticated with a key the parent writes on the child's stdin; the child writes the
address on its stdout. The child watches its stdin: when the parent closes it or ends (a crash
included), the child exits at once, so no worker outlives the process that started it.
"""

from __future__ import annotations

import dataclasses
import json
import os
import secrets
import shutil
import subprocess
import sys
import tempfile
import threading
import time
import traceback
from multiprocessing.connection import Client, Listener
from multiprocessing.reduction import ForkingPickler
from pathlib import Path

import numpy as np

try:  # the worker's peak memory, for the figures (not on Windows)
    import resource
except ImportError:  # pragma: no cover - Windows
    resource = None

from ..body.bodymodel import BodyModel
from ..core import one_frame
from ..core.errors import BodyCalError
from ..recording.filters import OneEuro
from ..recording.model import Device
from ..retarget.avatar_pose import AvatarRig
from ..retarget.solver import SolvedFrames
from .solver import LiveSolver

ENGINE_DIR = Path(__file__).resolve().parents[2]  # the folder holding `bodycal_addon` (the extension's own)
START_S = 60.0  # a worker not up by then (a cold disk, a stuck import) is killed: the follower solves here
CLOSE_S = 2.0  # a worker not gone this long after its stdin closed is killed
ONE_BLAS_THREAD = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")  # a worker per core

# Run as `python -I -c BOOTSTRAP ENGINE_DIR` (or by Blender: `blender_command`): the parent's key
# first, then the watch on stdin, before the engine's imports (a worker closed while it imports numpy
# ends at once).
BOOTSTRAP = """\
import os, sys, threading
key = sys.stdin.buffer.readline()
def _watch():
    sys.stdin.buffer.read()
    os._exit(0)
threading.Thread(target=_watch, daemon=True).start()
sys.path.insert(0, sys.argv[-1])
try:
    from bodycal_addon.live.worker import serve
    serve(key)
except BaseException:
    import traceback
    traceback.print_exc()
finally:
    sys.stderr.flush()
    os._exit(0)  # not the interpreter's shutdown: the watch holds stdin's lock
"""


class SolverProcess:
    """A worker process, started on a thread of its own (spawning Python and importing numpy and
    the engine take a few tenths of a second: nobody waits for it). `connection` is the
    `multiprocessing.connection.Connection` once the worker is up, None before; `error` says in
    one line why it could not start."""

    def __init__(self, name: str, command: list[str] | None = None, on_change=None):
        self.name = name
        self.on_change = on_change  # called once the worker is up or could not start (its starting thread)
        self.command = list(command) if command else python_command()
        self.connection = None
        self.error = ""
        self.pid: int | None = None
        self._proc: subprocess.Popen | None = None
        self._closed = False
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._start, name=f"bodycal-start-{name}", daemon=True)
        self._thread.start()

    @property
    def starting(self) -> bool:
        return self.connection is None and not self.error and not self._closed

    def _start(self) -> None:
        authkey = secrets.token_bytes(32)
        env = dict(os.environ)
        for var in ONE_BLAS_THREAD:
            env.setdefault(var, "1")
        try:
            with self._lock:
                if self._closed:
                    return
                self._proc = subprocess.Popen(
                    self.command, stdin=subprocess.PIPE,
                    stdout=subprocess.PIPE, env=env, creationflags=getattr(subprocess, "CREATE_NO_WINDOW", 0))
                self.pid = self._proc.pid
            watchdog = threading.Timer(START_S, self._proc.kill)
            watchdog.daemon = True
            watchdog.start()
            self._proc.stdin.write(authkey.hex().encode() + b"\n")
            self._proc.stdin.flush()
            said = _first_said(self._proc.stdout)  # the address, or why not ({}: it ended)
            self._proc.stdout.close()
            if "address" not in said:
                code = self._proc.wait(timeout=CLOSE_S)
                raise BodyCalError(said.get("error") or f"it ended before it was ready (exit code {code})")
            connection = Client(said["address"], authkey=authkey)
            watchdog.cancel()
            with self._lock:
                if self._closed:
                    connection.close()
                    return
                self.connection = connection
        except Exception as exc:  # noqa: BLE001 - any failure to start is one line; the follower solves here
            self.error = f"no worker process ({exc.line() if isinstance(exc, BodyCalError) else _one_line(exc)})"
            self._stop_process()
        if self.on_change is not None:
            self.on_change()

    def alive(self) -> bool:
        return self._proc is not None and self._proc.poll() is None

    def exit_code(self) -> int | None:
        return self._proc.poll() if self._proc is not None else None

    def close(self, kill: bool = False) -> None:
        """End the worker: its connection and stdin closed (it exits at once), killed after
        CLOSE_S if it has not (at once with `kill`: a stuck worker); reaped either way."""
        with self._lock:
            self._closed = True
            connection, self.connection = self.connection, None
        if connection is not None:
            connection.close()
        self._stop_process(kill)

    def _stop_process(self, kill: bool = False) -> None:
        proc = self._proc
        if proc is None:
            return
        if kill:
            proc.kill()
        try:
            proc.stdin.close()
        except OSError:
            pass
        try:
            proc.wait(timeout=CLOSE_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def python_command(executable: str | None = None) -> list[str]:
    """The worker run by a Python interpreter (this one by default), isolated from the user's site."""
    return [executable or sys.executable, "-I", "-c", BOOTSTRAP, str(ENGINE_DIR)]


def blender_command(binary: str) -> list[str]:
    """The worker run by Blender's own program in the background (BLENDER_NOTES.md "A worker
    process"): its Python has the built-in `mathutils` the one-frame kernels use. Factory settings:
    no user add-on, startup file or preference runs in it; no .blend is opened."""
    return [binary, "--background", "--factory-startup", "-noaudio", "--python-expr", BOOTSTRAP,
            "--", str(ENGINE_DIR)]


def _first_said(stdout, lines: int = 200) -> dict:
    """The child's first JSON line on `stdout` (Blender prints its banner first), {} at its end."""
    for _ in range(lines):
        line = stdout.readline()
        if not line:
            return {}
        if line.lstrip().startswith(b"{"):
            return json.loads(line)
    return {}


def _one_line(exc: BaseException) -> str:
    return " ".join(f"{type(exc).__name__}: {exc}".split())


# --- the messages (builtins and numpy arrays only: see the module docstring) ------------------------------


def prepare_message(user: BodyModel, avatar: BodyModel, method: str, devices: list[Device], markers: list[str],
                    smooth: OneEuro | None, plant_feet: bool, placement: str,
                    seat_height: float | None = None) -> tuple:
    """What the worker needs to make its LiveSolver (`Follower.prepare`'s arguments)."""
    return ("prepare", {
        "user": user.to_json(exact=True), "avatar": avatar.to_json(exact=True), "method": method,
        "devices": [(d.name, d.kind, d.role) for d in devices], "markers": list(markers),
        "smooth": None if smooth is None else dataclasses.asdict(smooth), "plant_feet": bool(plant_feet),
        "placement": placement, "seat_height": seat_height})


def frame_message(t: float, positions, rotations, valid, points, seen) -> tuple:
    return ("frame", float(t), positions, rotations, valid, points, seen)


def pickled(message: tuple) -> memoryview:
    """A message as `Connection.send` writes it (`Connection.recv` reads it back): made once, sent
    to every worker that reads the same columns with `send_bytes`."""
    return ForkingPickler.dumps(message)


def solved_from(reply: tuple) -> SolvedFrames:
    """A "pose" reply as the SolvedFrames the worker's LiveSolver gave."""
    _kind, basis, root_location, joints, names, targets = reply[:6]
    return SolvedFrames(basis, root_location, joints, {n: targets[k] for k, n in enumerate(names)})


# --- the worker (the child process) ----------------------------------------------------------------------


class _Worker:
    """The child's side: one LiveSolver, fed the frames the parent sends."""

    def __init__(self):
        self.solver: LiveSolver | None = None

    def handle(self, message: tuple) -> tuple:
        try:
            if message[0] == "prepare":
                return self.prepare(message[1])
            if message[0] == "frame":
                return self.push(*message[1:])
            return ("error", f"unknown message {message[0]!r:.40}")
        except BodyCalError as exc:
            return ("error", exc.line())
        except Exception as exc:  # noqa: BLE001 - a bug: its traceback on stderr, one line to the parent
            traceback.print_exc()
            return ("error", _one_line(exc))

    def prepare(self, spec: dict) -> tuple:
        user = BodyModel.from_dict(json.loads(spec["user"]), source="user", exact=True)
        avatar = BodyModel.from_dict(json.loads(spec["avatar"]), source="avatar", exact=True)
        smooth = None if spec["smooth"] is None else OneEuro(**spec["smooth"])
        devices = [Device(name, kind, role) for name, kind, role in spec["devices"]]
        self.solver = LiveSolver(user, avatar, spec["method"], devices=devices, marker_names=spec["markers"],
                                 smooth=smooth, plant_feet=spec["plant_feet"], placement=spec["placement"],
                                 seat_height=spec.get("seat_height"))
        rig = AvatarRig.from_model(avatar)  # what the parent's pose writer needs: names, root, armature
        return ("ready", {"armature": rig.armature, "names": list(rig.names), "root": int(rig.root),
                          "kernels": "mathutils" if one_frame.ENABLED else "numpy"})

    def push(self, t, positions, rotations, valid, points, seen) -> tuple:
        if self.solver is None:
            return ("error", "a frame before the solver was prepared")
        c0, w0 = time.thread_time(), time.perf_counter()
        solved = self.solver.push_newer(t, positions, rotations, valid, points, seen)
        cost = ((time.thread_time() - c0) * 1000.0, (time.perf_counter() - w0) * 1000.0)
        if solved is None:
            return ("none", *cost)
        names = list(solved.targets)
        targets = np.stack([solved.targets[n] for n in names]) if names else np.zeros((0, 1, 3))
        rec = self.solver.recording  # the bench's memory figures: the frames kept, and this process's peak
        kept = sum(a.nbytes for a in (rec.time, rec.positions, rec.rotations, rec.valid, rec.markers, rec.marker_valid))
        memory = (kept, _peak_rss_mb())
        return ("pose", solved.basis, solved.root_location, solved.joints, names, targets, *cost, *memory)


def _peak_rss_mb() -> float:
    """This process's peak resident memory (MB), 0 where the platform does not say."""
    if resource is None:
        return 0.0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return peak / (2 ** 20 if sys.platform == "darwin" else 2 ** 10)  # bytes on macOS, KB on Linux


def _listen_address() -> tuple[str, str | None]:
    """Where the child listens, and a folder to remove after (macOS's socket file)."""
    token = f"bodycal-solver-{os.getpid()}-{secrets.token_hex(8)}"
    if sys.platform == "win32":
        return rf"\\.\pipe\{token}", None
    if sys.platform.startswith("linux"):
        return "\0" + token, None  # the abstract namespace: no file
    folder = tempfile.mkdtemp(prefix="bodycal-")
    return os.path.join(folder, "solver"), folder


def serve(key_line: bytes) -> None:
    """The child's main (BOOTSTRAP): listen, say where on stdout, take the parent's one connection,
    then answer each message until the parent closes it."""
    try:
        authkey = bytes.fromhex(key_line.decode().strip())
        address, folder = _listen_address()
        listener = Listener(address, authkey=authkey)
    except Exception as exc:  # noqa: BLE001 - said to the parent, which solves in its own process
        print(json.dumps({"error": _one_line(exc)}), flush=True)
        return
    print(json.dumps({"address": address}), flush=True)  # Linux's abstract address reads back as bytes
    try:
        connection = listener.accept()
    finally:
        listener.close()
        if folder is not None:
            shutil.rmtree(folder, ignore_errors=True)
    sys.stdout = sys.stderr  # the parent reads nothing more on stdout: a stray print must not fill the pipe
    worker = _Worker()
    with connection:
        while True:
            try:
                message = connection.recv()
            except (EOFError, OSError):  # the parent closed it: done
                return
            answer = worker.handle(message)
            try:
                connection.send(answer)
            except OSError:  # the parent closed it while this one solved: done
                return
