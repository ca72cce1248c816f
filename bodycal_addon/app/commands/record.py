"""`bodycal record [--port N] [--bind ADDRESS] [--duration S] [--idle S] [--role NAME=ROLE ...] [--name
NAME] [--wizard [--pause S] [--step-timeout S]] -o TAKE.bcrec.json|.csv [--overwrite]` (FORMATS.md §6.2):
a live VMC stream into a recording.

Listens until Ctrl-C (or SIGTERM), until `--duration` seconds (wall clock) after the first frame
arrived, or until no frame has come for `--idle` seconds after the first (the sender stopped);
whichever comes first, the file is written whole and the reason said, then exit 0. A progress line
every PROGRESS_S: the take's length, frames, rate, devices seen and tracked now, markers, and what
the receiver skipped ("nothing received" while no packet has come).

With `--wizard`, the calibration steps the devices allow are run with the performer
(recording/live/wizard.py): each step's instruction is printed, it begins `--pause` seconds later
(the take's clock), its progress line follows, and it ends by itself once enough data is in (or is
skipped after `--step-timeout`); the take ends when the last step is done and is saved with the
steps as its segments."""

from __future__ import annotations

import contextlib
import signal
import threading
import time
from pathlib import Path

from ...core.errors import BodyCalError
from ...core.outputs import check_output
from ...recording.live.recorder import LiveRecorder, save_whole
from ...recording.live.wizard import LiveWizard
from .. import console

PROGRESS_S = 2.0


@contextlib.contextmanager
def stop_on_signals():
    """An Event set by SIGINT or SIGTERM for the block (the main thread's handlers, put back after):
    a live command ends its loop cleanly instead of being cut anywhere by KeyboardInterrupt."""
    stop = threading.Event()
    previous = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(ValueError):  # not the main thread: Ctrl-C stays KeyboardInterrupt
            previous[sig] = signal.signal(sig, lambda *_: stop.set())
    try:
        yield stop
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


def check_port(port: int, field: str = "--port") -> int:
    if not 0 < port < 65536:
        raise BodyCalError(f"{port} is not a port", field=field, hint="give 1..65535 (VMC: 39539)")
    return port


def parse_roles(items) -> dict[str, str]:
    roles = {}
    for item in items or []:
        name, sep, role = item.partition("=")
        if not sep or not name or not role:
            raise BodyCalError(f"'{item}' is not NAME=ROLE", field="--role", hint="e.g. --role LHR-1A2B3C4D=pelvis")
        roles[name] = role
    return roles


def run(args) -> int:
    # python-osc's, loaded when the command runs: `live` imports this module and must import without it
    from ...recording.live.receiver import VmcReceiver

    out = Path(args.output)
    if not out.name.lower().endswith((".json", ".csv")):
        raise BodyCalError("must be a .bcrec.json (or .json) or .csv recording", source=str(out), field="-o")
    check_port(args.port)
    if args.duration is not None and not args.duration > 0:
        raise BodyCalError(f"{args.duration:g} is not a positive number of seconds", field="--duration")
    idle = getattr(args, "idle", 0.0) or 0.0
    if not idle >= 0:
        raise BodyCalError(f"{idle:g} is not a number of seconds", field="--idle", hint="give 0 (no limit) or more")
    if getattr(args, "wizard", False):
        if not args.pause >= 0:
            raise BodyCalError(f"{args.pause:g} is not a number of seconds", field="--pause", hint="give 0 or more")
        if args.step_timeout is not None and not args.step_timeout > 0:
            raise BodyCalError(f"{args.step_timeout:g} is not a positive number of seconds", field="--step-timeout")
    overwrite = getattr(args, "overwrite", False)
    for target in ([out, out.with_suffix(".json")] if out.suffix.lower() == ".csv" else [out]):
        check_output(target, overwrite=overwrite)  # before listening: a bad path costs no take
    recorder = LiveRecorder(args.name or out.name.split(".")[0], parse_roles(args.role), limit_s=args.duration)
    receiver = VmcReceiver(args.port, args.bind)
    receiver.add_sink(recorder)
    with stop_on_signals() as stop:
        receiver.start()
        try:
            console.say(f"listening for VMC on {args.bind}:{receiver.port}; Ctrl-C ends the recording")
            ended = _Ending(recorder, args.duration, idle)
            if getattr(args, "wizard", False):
                _record_wizard(recorder, receiver, stop, args.pause, args.step_timeout, ended)
            else:
                _record(recorder, receiver, stop, ended)
            if ended.why:
                console.say(ended.why)
        finally:
            receiver.stop()
    return _save(recorder, receiver, out, overwrite)


class _Ending:
    """Whether the take is over by the clock (`--duration` after the first frame, `--idle` without
    one; `why` then says which), else None. Both on the receiver's clock (vmc.now)."""

    def __init__(self, recorder, duration: float | None, idle: float):
        self.recorder, self.duration, self.idle = recorder, duration, idle
        self.why = ""

    def __call__(self) -> bool:
        first, last = self.recorder.first_arrival, self.recorder.last_arrival
        if first is None:
            return False
        now = time.perf_counter()  # vmc.now's clock: the frames' arrival
        if self.recorder.full.is_set() or (self.duration is not None and now - first >= self.duration):
            self.why = f"--duration {self.duration:g} s reached (wall clock from the first frame): the take ends"
        elif self.idle and now - last >= self.idle:
            self.why = (f"no frame for {self.idle:g} s (the sender stopped?): the take ends at its last frame "
                        "(--idle 0 waits for Ctrl-C)")
        return bool(self.why)


def _record(recorder, receiver, stop: threading.Event, ended) -> None:
    last = (time.perf_counter(), 0)
    while not stop.wait(0.1) and not ended():
        now = time.perf_counter()
        if now - last[0] >= PROGRESS_S:
            rate = (recorder.frames - last[1]) / (now - last[0])
            last = (now, recorder.frames)
            console.status(_progress(recorder, receiver, rate))
        if receiver.stats.sink_error:
            raise BodyCalError(f"recording failed: {receiver.stats.sink_error}")


WIZARD_POLL_S = 1.0 / 30.0  # the wizard's update rate (a UI timer's)


def _record_wizard(recorder, receiver, stop: threading.Event, pause: float, step_timeout: float | None,
                   ended) -> None:
    """The calibration wizard over the stream (module docstring): waits for the first frame (the
    roles and markers a BodyCal sender announces come with it), then runs every step."""
    while not stop.wait(WIZARD_POLL_S) and not recorder.frames:
        if receiver.stats.sink_error:
            raise BodyCalError(f"recording failed: {receiver.stats.sink_error}")
    if not recorder.frames:
        return
    wizard = LiveWizard(recorder, _known_roles(recorder), recorder.marker_names, auto=True, auto_begin_s=pause)
    console.say(f"calibration wizard: {len(wizard.steps)} steps for {len(recorder.names)} devices and "
                f"{len(recorder.marker_names)} markers")
    shown, last_status, began = -1, 0.0, None
    while not wizard.finished and not stop.wait(WIZARD_POLL_S) and not ended():
        if receiver.stats.sink_error:
            raise BodyCalError(f"recording failed: {receiver.stats.sink_error}")
        if wizard.index != shown:
            shown, step = wizard.index, wizard.current
            console.say(f"step {shown + 1}/{len(wizard.steps)} {step.title}: {step.instruction} "
                        f"(begins in {pause:g} s)")
        index = wizard.index
        progress = wizard.update()
        if wizard.active and began is None:
            began = recorder.now
        if wizard.index != index:  # the step ended by itself
            seg = wizard.segments.get(index)
            console.say(f"  done: {progress.figure}" + (f" ({seg.end - seg.start:.2f} s kept)" if seg else ""))
            began = None
            if wizard.steps[index].step == "tpose":
                _roles_from_the_tpose(recorder, wizard)
        elif wizard.active and step_timeout is not None and recorder.now - began > step_timeout:
            console.warn("record", f"{wizard.current.title} skipped: not done after {step_timeout:g} s "
                                   f"({progress.figure if progress else 'no progress'})")
            wizard.skip_step()
            began = None
        elif progress is not None and time.perf_counter() - last_status >= 0.5:
            last_status = time.perf_counter()
            console.status(f"  {wizard.status_line()}")
    console.say(wizard.status_line())


def _known_roles(recorder) -> dict[str, str]:
    """Device name -> role: the user's, else what the stream announced, else found from the T-pose."""
    return {n: r for n in recorder.names if (r := recorder.user_roles.get(n) or recorder.announced_roles.get(n)
                                             or recorder.identified_roles.get(n))}


def _roles_from_the_tpose(recorder, wizard) -> None:
    """Devices without a role get theirs from the T-pose just recorded; the steps are planned again."""
    if all(n in _known_roles(recorder) for n in recorder.names):
        return
    try:
        found = recorder.identify_roles()
    except BodyCalError as exc:
        console.warn("record", f"roles not found from the T-pose: {exc.line()}")
        return
    if found:
        console.say("  roles from the T-pose: " + ", ".join(f"{n}={r}" for n, r in found.items()))
        wizard.replan(_known_roles(recorder), recorder.marker_names)


def _progress(recorder, receiver, rate: float) -> str:
    if not recorder.frames:
        if not receiver.stats.datagrams:
            return f"nothing received on port {receiver.port} yet"
        return f"waiting for VMC on port {receiver.port}: {receiver.stats.datagrams} packets so far, no device in them"
    return (f"recording {recorder.duration:.1f} s: {recorder.frames} frames, {rate:.1f} Hz, "
            f"{len(recorder.names)} devices ({recorder.last_tracked} tracked now), "
            f"{len(recorder.marker_names)} markers; {receiver.stats.line()}")


def _save(recorder, receiver, out: Path, overwrite: bool) -> int:
    stats = receiver.stats
    if stats.sink_error:
        raise BodyCalError(f"recording failed: {stats.sink_error}")
    if not stats.datagrams:
        raise BodyCalError(f"nothing received on port {receiver.port}: 0 packets",
                           hint="is the sender sending to this host and port?")
    if not recorder.frames:
        raise BodyCalError(f"nothing arrived on port {receiver.port} ({stats.datagrams} packets, none with a device)",
                           hint="is the sender sending device transforms to this host and port?")
    rec = recorder.recording()
    for name in sorted(stats.scaled_devices):
        console.warn("record", f"{name} came only as /VMC/Ext/*/Pos, scaled to the sender's avatar (its raw "
                               "values are the /Local messages: enable them in the sender)")
    if stats.bad_datagrams + stats.bad_messages:
        console.warn("record", f"{stats.bad_datagrams} bad packets and {stats.bad_messages} bad messages skipped "
                               f"(last: {stats.last_error})")
    written = save_whole(rec, out, overwrite=overwrite, extra=recorder.extra())
    for note in rec.notes:
        console.say(note)
    console.say(f"recorded {rec.frame_count} frames, {rec.time[-1] - rec.time[0]:.2f} s ({rec.fps:.1f} Hz, "
                f"{'sender' if recorder.sender_clock else 'arrival'} clock), {len(rec.devices)} devices, "
                f"{len(rec.marker_names)} markers, {len(rec.segments)} calibration steps; "
                f"receiver CPU {stats.cpu_seconds:.2f} s")
    for path in written:
        console.say(f"saved {path}")
    return 0
