"""`bodycal live --user USER.body.json --avatar AVATAR.body.json --send HOST:PORT [--method M] [--port N]
[--bind ADDRESS] [--role NAME=ROLE ...] [--duration S] [--no-filter] [--no-plant-feet]` (FORMATS.md §6):
a performer's VMC stream retargeted frame by frame and sent on as the avatar's VMC bones.

The receiver's latest frame is solved as soon as it is taken (`retarget.live.LiveSolver`: the
causal stance and, unless `--no-filter`, the forward One Euro), and the pose goes out at once
(`output.vmc_bones.AvatarVmcOut`); frames that arrive while a solve runs are dropped by the
receiver, counted and said. Devices get their roles from the stream's announcements (`bodycal
stream` sends them) or `--role NAME=ROLE`; the solve starts once the HMD, both hands, the pelvis and
both feet have roles and have been seen. Ctrl-C (or `--duration`) ends it; a summary line says how
many frames were solved and how long a solve took."""

from __future__ import annotations

import time

import numpy as np

from ...calibration.coverage import ANIMATED_ROLES
from ...core.errors import BodyCalError
from .. import console
from .record import PROGRESS_S, check_port, parse_roles, stop_on_signals

POLL_S = 0.0005  # how often the loop looks for a new frame when none is waiting


def send_target(text: str) -> tuple[str, int]:
    host, sep, port = (text or "").rpartition(":")
    if not sep or not host or not port.isdigit():
        raise BodyCalError(f"'{text}' is not HOST:PORT", field="--send", hint="e.g. --send 127.0.0.1:39540")
    return host, check_port(int(port), "--send")


def _models(args):
    from ...body.bodymodel import BodyModel

    user, avatar = BodyModel.load(args.user), BodyModel.load(args.avatar)
    if user.kind != "user":
        raise BodyCalError(f"expected a user body model, got kind '{user.kind}'", source=str(args.user))
    if avatar.kind != "avatar" or "rig" not in avatar.extra:
        raise BodyCalError("expected an avatar body model with its rig (calibrate-avatar's)", source=str(args.avatar),
                           hint="bodycal calibrate-avatar AVATAR -o AVATAR.body.json")
    return user, avatar


def run(args) -> int:
    from ...recording.filters import OneEuro
    from ...recording.live.receiver import VmcReceiver
    from ...recording.live.sender import VmcSender

    host, out_port = send_target(args.send)  # the arguments first, then the files
    roles = parse_roles(args.role)
    user, avatar = _models(args)
    smooth = None if args.filter is None else OneEuro.parse(args.filter)
    # As frames arrive the filter runs forward only, each device in the room's frame (the bake's
    # smoothing on the body parts needs the whole take: DESIGN.md §6b).
    smooth = None if smooth is None else OneEuro(smooth.min_cutoff, smooth.beta, smooth.rot_min_cutoff,
                                                 smooth.rot_beta, smooth.d_cutoff, two_pass=False, anchored=False)
    loop = _Loop(user, avatar, args, roles, smooth)
    with stop_on_signals() as stop, VmcReceiver(check_port(args.port), args.bind) as rx, \
            VmcSender(host, out_port) as tx:
        console.say(f"listening on {args.bind}:{args.port}, sending the avatar to {host}:{out_port}")
        loop.run(rx, tx, stop)
    console.say(loop.summary(rx.stats))
    return 0


class _Loop:
    def __init__(self, user, avatar, args, roles: dict[str, str], smooth):
        self.user, self.avatar, self.args, self.roles, self.smooth = user, avatar, args, roles, smooth
        self.solver = None
        self.out = None
        self.order: dict[str, int] = {}
        self.solve_ms: list[float] = []
        self.frames = 0

    def run(self, rx, tx, stop) -> None:
        from ...output.vmc_bones import AvatarVmcOut

        self.out = AvatarVmcOut(self.avatar, tx)
        start = last = time.monotonic()
        while not stop.is_set():
            now = time.monotonic()
            if self.args.duration is not None and now - start >= self.args.duration:
                break
            if now - last >= PROGRESS_S:
                console.status(self.progress(rx))
                last = now
            frame = rx.latest()
            if frame is None:
                time.sleep(POLL_S)
                continue
            self._announced(frame)
            if self.solver is None and not self._prepare(rx):
                continue
            self._solve(frame)

    def _announced(self, frame) -> None:
        for event in frame.events:
            if event[0] == "device" and event[3] and event[1] not in self.roles:
                self.roles[event[1]] = event[3]

    def _prepare(self, rx) -> bool:
        """The solver, once every role the methods need has a device the stream has named."""
        from ...recording.model import Device
        from ...retarget.live import LiveSolver

        kinds = rx.devices
        named = {n: r for n, r in self.roles.items() if n in kinds}
        if not set(ANIMATED_ROLES) <= set(named.values()):
            return False
        devices = [Device(n, kinds[n], r) for n, r in named.items()]
        self.order = {d.name: i for i, d in enumerate(devices)}
        self.solver = LiveSolver(self.user, self.avatar, self.args.method, devices=devices, smooth=self.smooth,
                                 plant_feet=self.args.plant_feet)
        return True

    def _solve(self, frame) -> None:
        n = len(self.order)
        pos, rot, valid = np.zeros((n, 3)), np.tile([1.0, 0.0, 0.0, 0.0], (n, 1)), np.zeros(n, bool)
        for k, name in enumerate(frame.devices):
            i = self.order.get(name)
            if i is not None:
                pos[i], rot[i], valid[i] = frame.positions[k], frame.rotations[k], True
        t = frame.sender_time if frame.sender_time is not None else frame.arrival
        if self.solver.recording.frame_count and t <= self.solver.recording.time[-1]:
            return  # a sender's clock that went back (a replay looping): not a new moment
        t0 = time.perf_counter()
        solved = self.solver.push(t, pos, rot, valid)
        if solved is not None:
            self.out.send_pose_values(solved.basis[0], solved.root_location[0], t)
            self.solve_ms.append((time.perf_counter() - t0) * 1000.0)
        self.frames += 1

    def progress(self, rx) -> str:
        if self.solver is None:
            missing = sorted(set(ANIMATED_ROLES) - {r for n, r in self.roles.items() if n in rx.devices})
            return f"waiting for devices with the roles {', '.join(missing)} ({len(rx.devices)} devices seen)"
        return f"{len(self.solve_ms)} frames solved, {rx.stats.line()}"

    def summary(self, stats) -> str:
        if not self.solve_ms:
            return f"no frame solved ({stats.line()})"
        ms = np.asarray(self.solve_ms)
        return (f"solved and sent {len(ms)} frames ({stats.line()}); a solve took {np.median(ms):.1f} ms median, "
                f"{np.percentile(ms, 99):.1f} ms p99")
