"""`bodycal live --user USER.body.json --avatar AVATAR.body.json --send HOST:PORT [--method M] [--port N]
[--bind ADDRESS] [--role NAME=ROLE ...] [--duration S] [--worker] [--no-filter] [--no-plant-feet]` (FORMATS.md §6):
a performer's VMC stream retargeted frame by frame and sent on as the avatar's VMC bones.

The newest frame is solved as soon as the solver is free (`live.session.LiveSession`, the Live
panel's too, whose follower runs `live.solver.LiveSolver`: the causal stance and, unless
`--no-filter`, the forward One Euro), on the session's solving thread, and the pose goes out at once
(`output.vmc_bones.AvatarVmcOut`); frames that arrive while a solve runs are skipped, counted and
said (the progress line and the summary). Devices get their roles from the stream's announcements
(`bodycal stream` sends them) or `--role NAME=ROLE`; the solve starts once the HMD, both hands, the
pelvis and both feet have roles and have been seen. `--worker` solves in a worker process of its
own (`live.worker`): the receiver's thread then never waits for the solve to let go of the GIL.
Ctrl-C (or `--duration`) ends it; a summary line says how many frames were solved and skipped and
how long a solve took."""

from __future__ import annotations

import time

import numpy as np

from ...body.bodymodel import BodyModel
from ...core.errors import BodyCalError
from ...live.session import LiveSession
from ...recording.filters import OneEuro
from .. import console
from .record import PROGRESS_S, check_port, parse_roles, stop_on_signals
from .retarget import seat_height

WAIT_S = 0.1  # the longest the loop sleeps waiting for a pose (it wakes at once when one comes)


def send_target(text: str) -> tuple[str, int]:
    host, sep, port = (text or "").rpartition(":")
    if not sep or not host or not port.isdigit():
        raise BodyCalError(f"'{text}' is not HOST:PORT", field="--send", hint="e.g. --send 127.0.0.1:39540")
    return host, check_port(int(port), "--send")


def _models(args):
    user, avatar = BodyModel.load(args.user), BodyModel.load(args.avatar)
    if user.kind != "user":
        raise BodyCalError(f"expected a user body model, got kind '{user.kind}'", source=str(args.user))
    if avatar.kind != "avatar" or "rig" not in avatar.extra:
        raise BodyCalError("expected an avatar body model with its rig (calibrate-avatar's)", source=str(args.avatar),
                           hint="bodycal calibrate-avatar AVATAR -o AVATAR.body.json")
    return user, avatar


def run(args) -> int:
    # python-osc's, loaded when the command runs: every other module imports without it
    from ...recording.live.receiver import VmcReceiver
    from ...recording.live.sender import VmcSender

    host, out_port = send_target(args.send)  # the arguments first, then the files
    roles = parse_roles(args.role)
    seat = seat_height(args)
    user, avatar = _models(args)
    smooth = None if args.filter is None else OneEuro.parse(args.filter)
    rx = VmcReceiver(check_port(args.port), args.bind)
    live = LiveSession(rx, roles)  # the one live path: Blender's Live panel pumps the same session
    live.follow(AVATAR, user, avatar, args.method, smooth=smooth, plant_feet=args.plant_feet,
                seat_height=seat, worker=args.worker)
    loop = _Loop(live, args)
    try:
        with stop_on_signals() as stop, rx, VmcSender(host, out_port) as tx:
            console.say(f"listening on {args.bind}:{args.port}, sending the avatar to {host}:{out_port}")
            loop.run(tx, stop)
    finally:
        live.stop()  # the worker process ends with the command
    console.say(loop.summary())
    return 0


AVATAR = "avatar"  # the one follower's name


class _Loop:
    def __init__(self, live, args):
        self.live, self.args = live, args
        self.sent = 0

    def run(self, tx, stop) -> None:
        from ...output.vmc_bones import AvatarVmcOut

        out = AvatarVmcOut(self.live.followers[AVATAR].avatar, tx)
        start = last = time.monotonic()
        while not stop.is_set():
            now = time.monotonic()
            if self.args.duration is not None and now - start >= self.args.duration:
                break
            if now - last >= PROGRESS_S:
                console.status(self.progress())
                last = now
            if not self.live.wait(WAIT_S):
                continue
            update = self.live.pump()
            if update is None:
                continue
            for line in update.notes:  # a worker process that ended: solved here from then on
                console.say(line)
            solved = update.poses.get(AVATAR)
            if solved is not None:
                frame = update.frame_of(AVATAR)
                t = frame.sender_time if frame.sender_time is not None else frame.arrival
                out.send_pose_values(solved.basis[0], solved.root_location[0], t)
                self.live.posed(update, AVATAR)
                self.sent += 1

    def progress(self) -> str:
        follower = self.live.followers[AVATAR]
        state = follower.state
        if state == "starting":
            return "starting the worker process"
        if state == "waiting":
            return (f"waiting for devices with the roles {', '.join(follower.waiting_for)} "
                    f"({len(self.live.kinds)} devices seen)")
        if state == "preparing":
            return "preparing the solver in the worker process"
        return f"{follower.stats.frames} frames solved, {self._skipped()}; {self.live.stats.line()}"

    def summary(self) -> str:
        stats = self.live.followers[AVATAR].stats
        if not self.sent:
            return f"no frame solved ({self.live.stats.line()})"
        ms = np.asarray(stats.solve_ms)
        where = " in the worker process" if self.live.followers[AVATAR].in_worker else ""
        return (f"solved and sent {self.sent} frames, {self._skipped()} ({self.live.stats.line()}); a solve took "
                f"{np.median(ms):.1f} ms median, {np.percentile(ms, 99):.1f} ms p99{where} (the last {len(ms)})")

    def _skipped(self) -> str:
        """The stream's frames the avatar did not show: skipped while it solved the one before."""
        stats = self.live.followers[AVATAR].stats
        return f"{stats.not_shown} of {stats.handed + stats.skipped} frames skipped"
