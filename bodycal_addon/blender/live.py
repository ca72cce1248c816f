"""The live session in Blender (DESIGN.md "Live session"): one per Blender process, held here.

    connect(port, bind)              # a VMC receiver on its own thread; a timer pumps it (not in background)
    follow(arm, user, method, ...)   # the armature's pose set from every solved frame
    start_recording(name) / start_wizard(name); stop_recording(folder)   # a take, saved and imported
    pump_once()                      # take the newest frame now, if one came (tests)
    pump_for(seconds)                # background Blender (headless stations, the bench): the timer's loop
    stop_following(); disconnect()   # every armature exactly as it was

Each pump takes the stream's newest frame (live/session.py) and moves the live empties (one per
device and marker, named and drawn as the importer makes them, in their own collection), and sets
each pose the followers solved since on its armature with `foreach_set` (preview.PoseWriter). The
solves run elsewhere (each avatar in a worker process of its own by default, else on the session's
solving thread): this thread never solves and never waits for a solve. Nothing here
is an operator: no undo step is made and the file is not marked changed; the viewport is only
asked to redraw. While an armature follows, its action and NLA are set aside (the animation
system would overwrite the pose on the next frame change) and put back with its pose, rotation
modes and values when it stops (pose_state.PoseState). A file saved while live holds neither the
live pose nor the live empties (save_pre puts everything back, save_post takes it up again);
loading another file ends the session.

The pump is locked onto the stream (live/pump_clock.py): `tick` pumps and says when to look
again, at the next frame's expected arrival or a pose's expected end, whichever is first; the UI's
timer returns that delay to Blender (a frame or pose due within `UI_BLOCK_S` is waited for, never
longer), `pump_for` sleeps it, or wakes as soon as a frame or a pose arrives (`wake_on_arrival`, a
loop that may block).
"""

from __future__ import annotations

import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import bpy
import numpy as np

from ..body import naming
from ..body.animation import AvatarAnimation
from ..body.bodymodel import BodyModel
from ..core.errors import BodyCalError
from ..live.session import LiveSession, LiveUpdate
from ..live.worker import blender_command
from ..output.armature_space import ArmatureSpacePlan, keyed_in_armature_space
from ..output.root_motion import apply_root_motion, check_root_motion
from ..recording.filters import OneEuro
from ..recording.io import load_recording
from ..recording.live.receiver import VmcReceiver
from ..recording.live.vmc import DEFAULT_PORT
from ..recording.live.wizard import LiveWizard
from . import avatar_rig, preview, recording_scene, rig_output
from .pose_state import PoseState
from .session import prepare_target

TICK_HZ = 90.0  # the display rate: the timer's rate while no stream sets the beat (pump_clock.DISPLAY_HZ)
UI_BLOCK_S = 0.001  # the longest the UI thread waits for a frame due in that time
LIVE_COLLECTION = "BodyCal Live"
LIVE_PREFIX = "live"  # the empties are "live.<device>", as the importer names "<recording>.<device>"


@dataclass
class Following:
    """An armature following the stream."""

    armature: str  # object name (the follower's name in the session)
    bone_map: naming.BoneMap
    root_motion: str
    saved: PoseState
    writer: preview.PoseWriter | None = None
    rest: object = None  # output.root_motion.RootRest, read at the first write
    first: AvatarAnimation | None = None  # the first solved frame: in-place root motion holds its spot
    loose_limbs: ArmatureSpacePlan | None = None  # IK feet beside the legs (a game rig), read at the first write
    rigify_target: str | None = None  # a generated Rigify rig: "fk" (its controls) or "def" (no constraints left)
    rigify: rig_output.RigifyPlan | None = None  # made at the first write (it sets the rig up)
    def_muted: bool = False  # the rig's DEF- constraints were muted (a DEF bake): so again on Stop
    write_ms: deque = field(default_factory=lambda: deque(maxlen=512))  # root motion + the pose write, wall clock
    write_cpu_ms: deque = field(default_factory=lambda: deque(maxlen=512))  # the same, this thread's CPU time


@dataclass
class _State:
    """The process's live session and what follows it (one per Blender process)."""

    session: LiveSession | None = None
    following: dict[str, Following] = field(default_factory=dict)
    timer: bool = False
    port: int = 0
    recorded_for: list[str] = field(default_factory=list)
    wizard: object = None  # recording.live.wizard.LiveWizard while the calibration wizard runs
    error: str = ""  # the last pump's failure, one line (the panel shows it)


_state = _State()


def session() -> LiveSession | None:
    return _state.session


def connected() -> bool:
    return _state.session is not None


def following() -> dict[str, Following]:
    return _state.following


def last_error() -> str:
    return _state.error


# --- connect -----------------------------------------------------------------------------------------


def connect(port: int = DEFAULT_PORT, bind: str = "127.0.0.1", roles: dict[str, str] | None = None,
            timer: bool | None = None) -> LiveSession:
    """Listen for a VMC stream on `bind`:`port` (0: a free port; `port()` says which). `timer`:
    pump from a timer on the main thread (default: unless Blender runs in the background)."""
    if _state.session is not None:
        raise BodyCalError("already connected", hint="Disconnect first")
    rx = VmcReceiver(port, bind)
    live = LiveSession(rx, roles)
    live.start()  # a port in use: one line, nothing kept
    _state.session, _state.port, _state.error = live, rx.port, ""
    if timer is None:
        timer = not bpy.app.background  # background Blender runs no timers: its scripts pump
    if timer:
        bpy.app.timers.register(_tick, first_interval=0.0, persistent=True)
        _state.timer = True
    return live


def port() -> int:
    return _state.port


def disconnect():
    """Stop following (every armature put back), stop listening and remove the live empties.
    Returns the recorder of a recording still running (the caller saves it), else None."""
    stop_following()
    live, _state.session = _state.session, None
    if _state.timer and bpy.app.timers.is_registered(_tick):
        bpy.app.timers.unregister(_tick)
    _state.timer = False
    if live is None:
        return None
    recorder = live.stop_recording()
    _state.wizard = None
    live.stop()
    remove_empties()
    return recorder


# --- follow --------------------------------------------------------------------------------------------


def worker_command() -> list[str] | None:
    """The program a follower's worker process runs: Blender itself in the background inside
    Blender (its own Python, `sys.executable` there, has no mathutils: live/worker.py), the
    interpreter in the bpy module (`bpy.app.binary_path` empty) or a plain Python (None)."""
    return blender_command(bpy.app.binary_path) if bpy.app.binary_path else None


def follow(arm, user: BodyModel, method: str = "egocentric", *, smooth: OneEuro | None = None,
           plant_feet: bool = True, placement: str = "object", root_motion: str = "root",
           worker: bool = True, seat_height: float | None = None) -> Following:
    """`arm` follows the stream from the next frame: `user` (the performer's model) onto the
    armature's avatar model (measured now when it has none stored) by `method`; `worker`: solved
    in a process of its own (live/worker.py: Blender's process never runs the solve, several
    avatars use several cores), else on the session's solving thread in Blender's process;
    `seat_height`: the performer seated (a kit without foot trackers)."""
    live = _need_session()
    check_root_motion(root_motion)
    preview.stop(arm.name)  # the preview's pose put back first: the armature as the user left it
    target = prepare_target(arm)
    stop_following(arm.name)  # a second Follow: put back as it was before the first
    live.follow(arm.name, user, target.avatar, method, smooth=smooth, plant_feet=plant_feet, placement=placement,
                seat_height=seat_height, worker=worker, command=worker_command())
    saved = PoseState.capture(arm)
    saved.detach(arm)
    bone_map = naming.BoneMap.from_dict(target.avatar.extra["rig"]["bone_map"])
    f = Following(arm.name, bone_map, root_motion, saved)
    if avatar_rig.is_rigify_generated(arm):  # as the bake keys it (rig_output.for_bake): its FK controls
        f.rigify_target = "fk" if rig_output.controls_drive_deform(arm) else "def"
        f.def_muted = bool(arm.get(rig_output.DEF_MUTED_PROP))
    _state.following[arm.name] = f
    return f


def stop_following(name: str | None = None) -> None:
    """Stop `name` (every armature when None) following and put it back exactly as it was."""
    for key in [name] if name is not None else list(_state.following):
        f = _state.following.pop(key, None)
        if _state.session is not None:
            _state.session.unfollow(key)
        arm = bpy.data.objects.get(key)
        if f is not None and arm is not None and arm.type == "ARMATURE":
            _put_back(f, arm)


def _put_back(f: Following, arm) -> None:
    f.saved.restore(arm)
    if f.rigify_target is not None and bool(arm.get(rig_output.DEF_MUTED_PROP)) != f.def_muted:
        rig_output.mute_deform(arm, f.def_muted)


def _need_session() -> LiveSession:
    if _state.session is None:
        raise BodyCalError("not connected", hint="press Connect in the Live panel")
    return _state.session


# --- record ----------------------------------------------------------------------------------------------


def start_recording(name: str = "take"):
    """Every frame from now on into a recorder (the wizard marks its steps on it)."""
    _state.recorded_for = list(_state.following)
    return _need_session().start_recording(name)


def start_wizard(name: str = "calibration", auto_begin_s: float | None = None):
    """The calibration wizard (recording/live/wizard.py) over the take being recorded (recording
    starts now when it is not): the steps the devices and markers allow, in protocol order. A step
    begins when `begin` is called (the operator's Begin), or by itself `auto_begin_s` seconds after
    the previous one ended; each ends by itself when enough data is in."""
    live = _need_session()
    if not live.kinds:
        raise BodyCalError("no device has arrived yet", hint="is the sender sending to this port?")
    recorder = live.recorder or start_recording(name)
    _state.wizard = LiveWizard(recorder, live.roles, live.markers, auto=True, auto_begin_s=auto_begin_s)
    return _state.wizard


def wizard():
    """The running calibration wizard, or None."""
    return _state.wizard


def _update_wizard(live: LiveSession) -> None:
    """The wizard's progress from the frames recorded so far; after the T-pose, the roles it gives
    to devices that had none, and the steps planned again for them."""
    w = _state.wizard
    if w is None or w.finished:
        return
    index = w.index
    w.update()
    if w.index != index and w.steps[index].step == "tpose" and any(n not in live.roles for n in live.kinds):
        try:
            live.recorder.identify_roles()
        except BodyCalError as exc:
            _state.error = f"roles not found from the T-pose: {exc.line()}"
            return
        w.replan(live.roles, live.markers)


def recording():
    """The running recorder, or None."""
    return _state.session.recorder if _state.session is not None else None


def recorded_for() -> list[str]:
    """The armatures that followed while the last take was recorded (Bake Take's avatars)."""
    return [n for n in _state.recorded_for if n in bpy.data.objects]


def take_folder(folder: str = "") -> Path:
    """Where takes are saved: `folder` (a Blender path, "//" relative to the .blend) when given,
    else the .blend's folder."""
    if folder:
        return Path(bpy.path.abspath(folder))
    if not bpy.data.filepath:
        raise BodyCalError("the .blend is not saved: no folder to put the take next to",
                           hint="save the .blend, or pick a folder for the takes in the Live panel")
    return Path(bpy.data.filepath).parent


def stop_recording(folder: str = "", scene=None, step_markers: str = "starts"):
    """Stop recording, save the take as a recording file (FORMATS.md §2; its steps as segments) in
    `take_folder(folder)`, import it into the scene as a file would be (recording_scene.py), so
    Calibrate and the bakes work on it. Returns (path, collection)."""
    live = _need_session()
    if live.recorder is None:
        raise BodyCalError("not recording", hint="press Record first")
    where = take_folder(folder)  # before the recorder is let go: a missing folder keeps it recording
    w, _state.wizard = _state.wizard, None
    if w is not None and w.active:  # a step cut short is left out, not kept half done
        w.skip_step()
    recorder = live.stop_recording()
    stamp = time.strftime("%Y%m%d-%H%M%S")
    path = where / f"{bpy.path.clean_name(recorder.name)}_{stamp}.bcrec.json"
    k = 1
    while path.exists():
        k += 1
        path = where / f"{bpy.path.clean_name(recorder.name)}_{stamp}_{k}.bcrec.json"
    recorder.name = path.name[: -len(".bcrec.json")]
    recorder.save(path)
    rec = load_recording(path)
    coll = recording_scene.import_recording_to_scene(rec, scene or bpy.context.scene, step_markers=step_markers)
    return path, coll


# --- the pump ------------------------------------------------------------------------------------------


def pump_once() -> LiveUpdate | None:
    """Set each pose the followers solved since the last pump, then move the empties to the newest
    frame and update the wizard (what nobody waits for comes last); None when nothing came."""
    live = _state.session
    if live is None:
        return None
    update = live.pump(on_pose=_set_pose)
    if update is not None:
        for line in update.notes:  # a worker process that ended, a solve that failed (the panel shows it too)
            print(f"BodyCal live: {line}")
        for name in [n for n in update.poses if n not in _state.following]:  # gone while following
            live.unfollow(name)
        if update.frame is not None:
            update_empties(update.frame, live.roles, live.kinds)
    if live.recorder is not None:
        _update_wizard(live)
    if update is not None:
        _tag_redraw()
    return update


def _set_pose(update: LiveUpdate, name: str) -> None:
    """`name`'s solved pose of `update` on its armature (the session's `on_pose`)."""
    f = _state.following.get(name)
    if f is None:
        return
    arm = bpy.data.objects.get(name)
    if arm is None or arm.type != "ARMATURE":  # deleted (or undone away) while following
        _state.following.pop(name, None)
        return
    live = _state.session
    t0, c0 = time.perf_counter(), time.thread_time()
    _write(f, arm, live.followers[name], update.poses[name], update)
    done = time.perf_counter()
    f.write_cpu_ms.append((time.thread_time() - c0) * 1000.0)
    f.write_ms.append((done - t0) * 1000.0)
    live.posed(update, name, done)


def _animation(follower, solved, frame) -> AvatarAnimation:
    """The solved frame as an animation of one row (its own copy: root motion changes it in place,
    and the update keeps the solver's pose as solved)."""
    rig = follower.layout  # the rig's names and root (from the worker, when the follower solves in one)
    return AvatarAnimation(rig.armature, list(rig.names), np.array(solved.basis, float), rig.names[rig.root],
                           np.asarray(solved.root_location, float), np.array([frame.arrival]), follower.method)


def _with_root_motion(f: Following, anim: AvatarAnimation) -> AvatarAnimation:
    if f.root_motion == "in-place":  # the travel removed relative to the first frame followed
        anim = preview.joined(f.first, anim)
    anim = apply_root_motion(anim, f.rest, f.root_motion, own=True)
    return keyed_in_armature_space(anim, f.loose_limbs)  # a game rig's IK feet, as the bake keys them


def _converter(f: Following, follower):
    """The follower's `convert` (live/followers.py): each solved pose with its root motion, made on
    the session's solving thread (numpy only, no Blender data: the rig's rest was read here at the
    first pose), so that this thread only sets it. None until that first pose was written."""
    def convert(solved, frame):
        return _with_root_motion(f, _animation(follower, solved, frame)) if f.rest is not None else None
    return convert


def _write(f: Following, arm, follower, solved, update: LiveUpdate) -> None:
    """The solved frame as the bake would key it (root motion where asked) on the pose bones."""
    anim = update.converted.get(follower.name)
    if anim is None:  # the first pose (its rig's rest read now), or one solved before that
        anim = _animation(follower, solved, update.frame_of(follower.name))
        if f.rest is None:
            f.rest = rig_output.root_rest(arm, anim, f.bone_map)
            f.loose_limbs = rig_output.armature_space_plan(arm, f.bone_map)
            f.first = anim
            follower.convert = _converter(f, follower)
        anim = _with_root_motion(f, anim)
    if f.rigify_target is not None:  # the DEF- skeleton's pose carried onto the controls
        if f.rigify is None:
            f.rigify = rig_output.RigifyPlan(arm, f.rigify_target, anim.bone_names)
        anim = f.rigify.animation(anim)
    if f.writer is None:
        f.writer = preview.PoseWriter(arm, anim)
    f.writer.write(arm, anim, row=anim.frame_count - 1)


def tick(block_s: float = UI_BLOCK_S) -> float | None:
    """One turn of the pump's loop, the timer's and `pump_for`'s: a frame expected within
    `block_s` is waited for (no longer), the newest frame pumped; returns the seconds until the
    next turn (the session's clock: the next frame's expected arrival), None when not connected."""
    return _turn(block_s)[1]


def _turn(block_s: float) -> tuple[LiveUpdate | None, float | None]:
    live = _state.session
    if live is None:
        return None, None
    soon = live.next_delay()
    if 0.0 < soon <= block_s:
        live.wait(soon)
    update = pump_once()
    return update, live.next_delay()


def pump_for(seconds: float, wake_on_arrival: bool = True, on_update=None) -> int:
    """Pump for `seconds` as the UI's timer does (background Blender runs no timers): `tick`, then
    sleep until the next turn; with `wake_on_arrival` the sleep ends when a frame arrives (a
    headless loop may block; the UI may not). `on_update(update)` after each frame pumped.
    Returns the frames pumped (one turn at least is taken: a frame waiting is pumped)."""
    end, frames = time.perf_counter() + seconds, 0
    while True:  # one turn at least: a frame waiting is pumped whatever `seconds`
        update, delay = _turn(UI_BLOCK_S)
        if update is not None:
            frames += 1
            if on_update is not None:
                on_update(update)
        left = end - time.perf_counter()
        if delay is None or left <= 0 or _state.session is None:  # disconnected by `on_update`, say
            return frames
        delay = min(delay, left)
        if wake_on_arrival:
            _state.session.wait(delay)
        elif delay > 0:
            time.sleep(delay)


def _tick():
    """The timer: `tick`, then again when the session's clock says; stops when the session ends."""
    if _state.session is None:
        _state.timer = False
        return None
    delay = None
    try:
        delay = tick()
        _state.error = ""
    except BodyCalError as exc:  # bad input: the panel shows the line, the stream goes on
        _state.error = exc.line()
    except Exception as exc:  # a bug: said in the panel; Blender prints it and drops the timer
        _state.error = f"the live view stopped: {type(exc).__name__}: {exc}"
        _state.timer = False
        raise
    return 1.0 / TICK_HZ if delay is None else delay


def _tag_redraw() -> None:
    wm = bpy.context.window_manager
    for window in getattr(wm, "windows", ()):
        for area in window.screen.areas:
            if area.type == "VIEW_3D":  # the empties, the avatars and the Live panel's figures
                area.tag_redraw()


# --- the live empties ------------------------------------------------------------------------------------


def _collection(scene):
    coll = bpy.data.collections.get(LIVE_COLLECTION)
    if coll is None:
        coll = bpy.data.collections.new(LIVE_COLLECTION)
    if coll.name not in scene.collection.children:
        scene.collection.children.link(coll)
    return coll


def _empty(coll, name: str, display: str, size: float):
    obj = bpy.data.objects.get(name)
    if obj is None or obj.type != "EMPTY":
        obj = bpy.data.objects.new(name, None)
        obj.empty_display_type, obj.empty_display_size = display, size
        obj.rotation_mode = "QUATERNION"
        obj[recording_scene.TRACKED] = 1.0
    if obj.name not in coll.objects:
        coll.objects.link(obj)
    return obj


def empty_name(device: str) -> str:
    return f"{LIVE_PREFIX}.{device}"[:63]


def update_empties(frame, roles: dict[str, str], kinds: dict[str, str]) -> None:
    """One empty per device (arrows) and marker (a small sphere) at the frame's poses, with the
    importer's custom properties (recording_scene.py); the role kept up to date."""
    coll = _collection(bpy.context.scene)
    for k, device in enumerate(frame.devices):
        obj = _empty(coll, empty_name(device), "ARROWS", 0.1)
        obj.location = frame.positions[k]
        obj.rotation_quaternion = frame.rotations[k]
        if obj.get(recording_scene.DEVICE_PROP) != device:
            obj[recording_scene.DEVICE_PROP] = device
        kind, role = kinds.get(device, "tracker"), roles.get(device) or ""
        if obj.get("bodycal_kind") != kind:
            obj["bodycal_kind"] = kind
        if obj.get(recording_scene.ROLE_PROP) != role:
            obj[recording_scene.ROLE_PROP] = role
    for k, marker in enumerate(frame.markers):
        obj = _empty(coll, empty_name(marker), "SPHERE", 0.01)
        obj.location = frame.points[k]
        if obj.get(recording_scene.MARKER_PROP) != marker:
            obj[recording_scene.MARKER_PROP] = marker


def remove_empties() -> None:
    coll = bpy.data.collections.get(LIVE_COLLECTION)
    if coll is None:
        return
    for obj in list(coll.objects):
        bpy.data.objects.remove(obj)
    bpy.data.collections.remove(coll)


# --- the file -----------------------------------------------------------------------------------------------


@bpy.app.handlers.persistent
def on_save_pre(*_args) -> None:
    """The file keeps every armature as it was and no live empty."""
    if _state.session is None:
        return
    for name, f in _state.following.items():
        arm = bpy.data.objects.get(name)
        if arm is not None and arm.type == "ARMATURE":
            _put_back(f, arm)
    remove_empties()


@bpy.app.handlers.persistent
def on_save_post(*_args) -> None:
    """Following again: actions set aside; the next frame sets the poses and brings the empties."""
    for name, f in _state.following.items():
        arm = bpy.data.objects.get(name)
        if arm is not None and arm.type == "ARMATURE":
            f.saved = PoseState.capture(arm)  # what the file now holds is what Stop puts back
            f.saved.detach(arm)
            f.writer, f.rigify = None, None


@bpy.app.handlers.persistent
def on_load_pre(*_args) -> None:
    """Another file: its armatures are not the ones following; the session ends."""
    _state.following.clear()
    disconnect()


HANDLERS = ((bpy.app.handlers.save_pre, on_save_pre), (bpy.app.handlers.save_post, on_save_post),
            (bpy.app.handlers.load_pre, on_load_pre))


def register_handlers() -> None:
    for handlers, fn in HANDLERS:
        if fn not in handlers:
            handlers.append(fn)


def unregister_handlers() -> None:
    disconnect()
    for handlers, fn in HANDLERS:
        if fn in handlers:
            handlers.remove(fn)
