"""`bodycal stream TAKE [--host H] [--port N] [--speed X] [--loop] [--local-only]` (FORMATS.md §6.3):
a recording sent as a VMC stream in real time, its devices and markers; with `--retarget --user
USER.body.json --avatar AVATAR [--armature NAME] [--bone-map FILE] [--method M] [--filter ...]
[--no-plant-feet]`, the avatar retargeted from it (offline, before sending), as VMC bones (§6.4).

AVATAR is an avatar body model (`*.body.json` written by calibrate-avatar: no Blender needed) or,
as for `retarget`, a .blend, .fbx, .glb, .gltf or .vrm (opened with Blender, its stored model used
or measured). Ctrl-C (or SIGTERM) stops the stream; exit 0."""

from __future__ import annotations

from pathlib import Path

from ...body.bodymodel import BodyModel
from ...body.bone_presets import load_preset
from ...core.errors import BodyCalError
from ...output.vmc_bones import AvatarMessages
from ...recording.filters import OneEuro
from ...recording.io import load_recording
from ...recording.live.sender import RecordingMessages, VmcSender, replay
from ...retarget.takes import RecordingTake
from .. import console
from .record import check_port, stop_on_signals


def run(args) -> int:
    check_port(args.port)
    if not args.speed > 0:
        raise BodyCalError(f"{args.speed:g} is not a positive speed", field="--speed", hint="1 is real time")
    if args.retarget:
        take, what = _retargeted(args), "the avatar's bones"
    else:
        if args.user or args.avatar:
            raise BodyCalError("--user and --avatar are for --retarget", field="--retarget",
                               hint="add --retarget to send the avatar instead of the devices")
        take, what = _devices(args), "devices and markers"
    t = take.time
    rate = (len(t) - 1) / (t[-1] - t[0]) if len(t) > 1 else 0.0
    with VmcSender(args.host, args.port) as sender, stop_on_signals() as stop:
        console.say(f"streaming {take.name} ({what}): {len(t)} frames, {t[-1] - t[0]:.2f} s at {rate:.1f} Hz, "
                    f"to {args.host}:{args.port} at {args.speed:g}x{', looping' if args.loop else ''}; "
                    "Ctrl-C stops")
        stats = replay(take, sender, speed=args.speed, loop=args.loop, stop=stop,
                       progress=lambda s: console.status(f"sent {s.take_seconds:.1f} s of {take.name}, {s.frames} "
                                                         f"frames, {s.loops} loops, {s.late} late"))
        console.say(f"sent {stats.frames} frames ({stats.take_seconds:.2f} s of the take, {stats.loops} loops, "
                    f"{stats.late} late) in {sender.datagrams} packets"
                    + (f"; {sender.errors} packets refused ({sender.last_error})" if sender.errors else ""))
    return 0


def _devices(args):
    rec = load_recording(args.take, raw=True, hands=getattr(args, "hands", "geometry"))
    if not rec.devices and not rec.marker_names:
        raise BodyCalError("has no device and no marker to send", source=str(args.take))
    return RecordingMessages(rec, scaled=not args.local_only)


def _retargeted(args):
    if not args.user or not args.avatar:
        raise BodyCalError("needs --user USER.body.json and --avatar AVATAR", field="--retarget")
    rec = load_recording(args.take, hands=getattr(args, "hands", "geometry"))
    user = BodyModel.load(args.user)
    if user.kind != "user":
        raise BodyCalError(f"expected a user body model, got kind '{user.kind}'", source=str(args.user))
    avatar = _avatar_model(Path(args.avatar), args.armature, args.bone_map)
    cfg = None if args.filter is None else OneEuro.parse(args.filter)
    for note in rec.notes:
        console.say(note)
    anim = RecordingTake(rec, user, cfg).animate(avatar, args.method, plant_feet=args.plant_feet, placement="object")
    for note in anim.notes:
        console.say(note)
    return AvatarMessages(anim, avatar)


def _avatar_model(path: Path, armature: str | None, bone_map: str | None):
    """An avatar body model with its rig: read from a *.body.json, or the avatar file's own (Blender)."""
    if path.name.lower().endswith(".json"):
        if bone_map:
            raise BodyCalError("a body model carries its bone map; --bone-map is for an avatar file",
                               field="--bone-map")
        model = BodyModel.load(path)
        if model.kind != "avatar" or not isinstance(model.extra.get("rig"), dict):
            raise BodyCalError("is not an avatar body model with its rig", source=str(path), field="--avatar",
                               hint="give the *.body.json written by calibrate-avatar, or the avatar's file")
        return model
    # Blender's glue, only for an avatar file (a body model streams without Blender)
    from ...blender.avatar_rig import apply_preset
    from ...blender.blendfile import find_armature, open_avatar
    from ...blender.session import prepare_target

    preset = load_preset(bone_map) if bone_map else None
    for note in open_avatar(path):
        console.say(note)
    arm = find_armature(armature, str(path))
    if preset is not None:
        apply_preset(arm, preset)
    target = prepare_target(arm)
    for line in target.warnings:
        console.warn("stream", line)
    return target.avatar
