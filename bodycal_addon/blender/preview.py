"""The timeline preview: avatars follow the scene's take as the user scrubs or plays, before any
bake (DESIGN.md §1, "Preview").

A preview prepares the take once (`Take.prepare`: the pipeline's whole-take steps, the feet plan
included, over the frames the bake would take) and, on every frame change, solves the one sample
under the playhead and sets it on the armature's pose bones: the values the bake would key at
that frame, before key reduction. Nothing is keyed and no undo step is made; the pose bones'
rotation modes and values are put back when the preview stops, and while a file is saved (so
the preview never ends up in the file).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import bpy
import numpy as np

from ..body import naming
from ..body.animation import AvatarAnimation
from ..core.errors import BodyCalError
from ..retarget.pipeline import PreparedTake
from ..retarget.takes import Take
from . import avatar_rig, rig_output
from .pose_state import PoseState
from .session import Settings, Target

# A preview rebuilds itself when what it was made from changes. What it was made from (the scene's
# settings, the take, the models) is the UI's to say: `follow(key_of, rebuild)` gives the handler a
# function that says it now (`key_of(scene, armature, key it was made with) -> tuple`) and one that
# starts it again (`rebuild(scene, armature, key)`).
_follow: dict = {"key_of": None, "rebuild": None}


def follow(key_of, rebuild) -> None:
    _follow.update(key_of=key_of, rebuild=rebuild)


@dataclass
class Preview:
    armature: str  # object name
    take: Take
    target: Target
    prepared: PreparedTake
    root_motion: str
    key: tuple
    saved: PoseState | None = None  # the pose as it was (modes and every rotation kind's values)
    first: AvatarAnimation | None = None  # the take's first sample: in-place root motion holds its spot
    solve_ms: float = 0.0  # the last frame's solve and write


_active: dict[str, Preview] = {}


def active(arm) -> Preview | None:
    return _active.get(getattr(arm, "name", None))


def any_active() -> bool:
    return bool(_active)


def start(arm, take: Take, target: Target, settings: Settings, root_motion: str, key: tuple) -> Preview:
    """Prepare `take` onto `target` (an armature's avatar model) and show the current frame."""
    if avatar_rig.is_rigify_generated(arm):
        raise BodyCalError("the preview poses plain rigs; a generated Rigify rig is shown by its bake",
                           source=arm.name, hint="Retarget and Bake, then scrub the baked action")
    prepared = take.prepare(target.avatar, settings.method, plant_feet=settings.plant_feet,
                            placement=settings.placement)
    stop(arm.name)
    pv = Preview(arm.name, take, target, prepared, root_motion, key)
    pv.first = prepared.solve(0, 1)
    pv.saved = PoseState.capture(arm)
    _active[arm.name] = pv
    show(pv, bpy.context.scene)
    return pv


def stop(name: str) -> bool:
    """Stop the armature's preview and put its pose back as it was; False when none was on."""
    pv = _active.pop(name, None)
    if pv is None:
        return False
    _put_back(pv)
    return True


def stop_all() -> None:
    for name in list(_active):
        stop(name)


def _put_back(pv: Preview) -> None:
    arm = bpy.data.objects.get(pv.armature)
    if arm is None or arm.type != "ARMATURE":
        return
    pv.saved.restore_pose(arm)


def sample_at(pv: Preview, frame: float) -> int:
    """The take's sample the scene frame `frame` shows (the nearest; the first or last outside)."""
    t = pv.prepared.source.time
    at = float(t[0]) + (frame - pv.take.frame_start) / pv.take.rate
    k = int(np.searchsorted(t, at))
    if k >= len(t) or (k > 0 and at - t[k - 1] <= t[k] - at):
        k -= 1
    return max(k, 0)


def show(pv: Preview, scene) -> None:
    """Solve the sample under the playhead and set it on the armature's pose bones."""
    arm = bpy.data.objects.get(pv.armature)
    if arm is None or arm.type != "ARMATURE":
        _active.pop(pv.armature, None)  # deleted (or undone away) while previewed
        return
    t0 = time.perf_counter()
    k = sample_at(pv, scene.frame_current + scene.frame_subframe)
    anim = pv.prepared.solve(k, k + 1)
    if pv.root_motion == "in-place":  # the travel removed relative to the take's first sample
        anim = joined(pv.first, anim)
    bone_map = naming.BoneMap.from_dict(pv.target.avatar.extra["rig"]["bone_map"])
    anim = rig_output.with_root_motion(anim, arm, bone_map, pv.root_motion, own=True)
    anim = rig_output.with_armature_space(anim, arm, bone_map)  # as the bake keys it
    write_pose(arm, anim, row=anim.frame_count - 1)
    pv.solve_ms = (time.perf_counter() - t0) * 1000.0


def joined(a: AvatarAnimation, b: AvatarAnimation) -> AvatarAnimation:
    return AvatarAnimation(b.armature, b.bone_names, np.concatenate([a.rotations, b.rotations]), b.root_bone,
                           np.concatenate([a.root_location, b.root_location]), np.concatenate([a.time, b.time]),
                           b.method, notes=list(b.notes))


def write_pose(arm, anim: AvatarAnimation, row: int = 0) -> None:
    """Set frame `row` of `anim` on the armature's pose bones, every bone at once (foreach_set)."""
    PoseWriter(arm, anim).write(arm, anim, row)


class PoseWriter:
    """Frames of animations with the bones of `like` (the same names, root and located bones)
    set on the armature's pose bones: the rows found once, then per frame one foreach_get and one
    foreach_set per channel, no loop over bones (the live follow writes every frame). The bones'
    rotation modes become quaternions here."""

    def __init__(self, arm, like: AvatarAnimation):
        bones = arm.pose.bones
        index = {pb.name: i for i, pb in enumerate(bones)}
        self.count = len(bones)
        self.rows = np.array([index[b] for b in like.bone_names], int)
        self.root = index[like.root_bone]
        self.located = {name: index[name] for name in like.bone_locations}
        self.quats = np.empty((self.count, 4), np.float32)
        self.locs = np.empty((self.count, 3), np.float32)
        for name in like.bone_names:
            if bones[name].rotation_mode != "QUATERNION":
                bones[name].rotation_mode = "QUATERNION"

    def write(self, arm, anim: AvatarAnimation, row: int = 0) -> None:
        bones = arm.pose.bones
        bones.foreach_get("rotation_quaternion", self.quats.ravel())
        bones.foreach_get("location", self.locs.ravel())
        self.quats[self.rows] = anim.rotations[row]
        self.locs[self.root] = anim.root_location[row]
        for name, i in self.located.items():
            self.locs[i] = anim.bone_locations[name][row]
        bones.foreach_set("rotation_quaternion", self.quats.ravel())
        bones.foreach_set("location", self.locs.ravel())
        arm.update_tag(refresh={"DATA"})


@bpy.app.handlers.persistent
def on_frame_change(scene, _depsgraph=None) -> None:
    key_of, rebuild = _follow["key_of"], _follow["rebuild"]
    for pv in list(_active.values()):
        try:
            arm = bpy.data.objects.get(pv.armature)
            if arm is not None and key_of is not None and key_of(scene, arm, pv.key) != pv.key:
                rebuild(scene, arm, pv.key)  # starts it again, showing this frame
            else:
                show(pv, scene)
        except BodyCalError as exc:  # a handler must not raise: the preview stops with its reason
            stop(pv.armature)
            print(f"BodyCal preview stopped: {exc.line()}")


@bpy.app.handlers.persistent
def on_save_pre(*_args) -> None:
    for pv in _active.values():  # the file keeps the armature as it was, never the preview
        _put_back(pv)


@bpy.app.handlers.persistent
def on_save_post(*_args) -> None:
    if _active:
        on_frame_change(bpy.context.scene)


@bpy.app.handlers.persistent
def on_load_pre(*_args) -> None:
    _active.clear()  # another file: its armatures are not the ones previewed


HANDLERS = ((bpy.app.handlers.frame_change_post, on_frame_change), (bpy.app.handlers.save_pre, on_save_pre),
            (bpy.app.handlers.save_post, on_save_post), (bpy.app.handlers.load_pre, on_load_pre))


def register_handlers() -> None:
    for handlers, fn in HANDLERS:
        if fn not in handlers:
            handlers.append(fn)


def unregister_handlers() -> None:
    stop_all()
    for handlers, fn in HANDLERS:
        if fn in handlers:
            handlers.remove(fn)
