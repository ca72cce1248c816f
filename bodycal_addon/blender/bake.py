"""Step 5 of the pipeline (DESIGN.md §1): write an AvatarAnimation into a NEW action.

Keys are written per F-Curve with `keyframe_points.add(n)` + `foreach_set("co", ...)`, a few
thousand times faster than inserting one key per call (BLENDER_NOTES.md: 5.8 M keys/s against 11.7 k/s).
Portable across Blender 4.2 (`action.fcurves`) and 4.4+ / 5.0 slotted actions
(`action.fcurve_ensure_for_datablock`). Everything is computed before the scene is touched, and
if writing fails half way the new action is removed and the previous assignment restored.
"""

from __future__ import annotations

from dataclasses import dataclass

import bpy
import numpy as np

from ..animation import AvatarAnimation
from ..errors import BodyCalError
from .fcurves import continuous_quaternions, new_fcurve, write_keys


@dataclass
class BakeResult:
    action: bpy.types.Action
    keys: int
    fcurves: int
    frame_range: tuple[float, float]
    replaced: str | None = None
    nla_track: str | None = None


def default_action_name(recording: str, avatar: str, method: str) -> str:
    return f"{recording}|{avatar}|{method}"


def key_frames(time: np.ndarray, fps: float, frame_start: float) -> np.ndarray:
    return frame_start + (np.asarray(time, float) - float(time[0])) * fps


def validate(anim: AvatarAnimation, obj) -> None:
    if obj is None or obj.type != "ARMATURE":
        raise BodyCalError("pick an armature to bake onto", source=getattr(obj, "name", "no object"))
    missing = [b for b in anim.bone_names + [anim.root_bone] if b not in obj.pose.bones]
    if missing:
        raise BodyCalError(f"the armature has no bones named {', '.join(sorted(set(missing))[:6])}",
                           source=obj.name, hint="recalibrate the avatar after renaming bones")
    if anim.frame_count == 0:
        raise BodyCalError("nothing to bake: the animation has no frames", source=obj.name)
    if not (np.all(np.isfinite(anim.rotations)) and np.all(np.isfinite(anim.root_location))):
        raise BodyCalError("the retargeted animation has non-finite values; nothing was written", source=obj.name)


def bake_animation(anim: AvatarAnimation, obj, *, action_name: str | None = None, replace: bool = False,
                   fps: float | None = None, frame_start: float | None = None, push_to_nla: bool = False
                   ) -> BakeResult:
    """Bake `anim` onto armature `obj` as a new action and make it the active action.

    An existing action of the same name is kept (the new one gets Blender's `.001` suffix) unless
    `replace` is True, in which case the old action is removed once the new one is written.
    """
    validate(anim, obj)
    scene = bpy.context.scene
    fps = float(fps or scene.render.fps / scene.render.fps_base)
    frame_start = float(scene.frame_start if frame_start is None else frame_start)
    # --- compute everything first -------------------------------------------------------------
    frames32 = key_frames(anim.time, fps, frame_start).astype(np.float32)
    rotations = continuous_quaternions(anim.rotations).astype(np.float32)  # (F, B, 4)
    root_location = np.asarray(anim.root_location, dtype=np.float32)
    name = action_name or default_action_name("recording", obj.name, anim.method)
    old = bpy.data.actions.get(name)

    # --- then write ---------------------------------------------------------------------------
    had_animation_data = obj.animation_data is not None
    previous_action = obj.animation_data.action if had_animation_data else None
    action = bpy.data.actions.new(name + ".bodycal-new" if old is not None and replace else name)
    action.use_fake_user = False
    fcurves = 0
    try:
        ad = obj.animation_data_create()
        ad.action = action
        for b, bone_name in enumerate(anim.bone_names):
            pb = obj.pose.bones[bone_name]
            pb.rotation_mode = "QUATERNION"
            path = f'pose.bones["{bpy.utils.escape_identifier(bone_name)}"].rotation_quaternion'
            for i in range(4):
                write_keys(new_fcurve(action, obj, path, i, bone_name), frames32, rotations[:, b, i])
                fcurves += 1
        path = f'pose.bones["{bpy.utils.escape_identifier(anim.root_bone)}"].location'
        for i in range(3):
            write_keys(new_fcurve(action, obj, path, i, anim.root_bone), frames32, root_location[:, i])
            fcurves += 1
    except Exception:
        if had_animation_data:
            obj.animation_data.action = previous_action
        elif obj.animation_data is not None:
            obj.animation_data_clear()
        bpy.data.actions.remove(action)
        raise
    replaced = None
    if old is not None and replace:
        replaced = old.name
        bpy.data.actions.remove(old)
        action.name = name
    track = None
    if push_to_nla:
        nla = obj.animation_data.nla_tracks.new()
        nla.name = action.name
        nla.strips.new(action.name, int(round(frames32[0])), action)
        obj.animation_data.action = None
        track = nla.name
    scene.frame_start = int(np.floor(frames32[0]))
    scene.frame_end = max(scene.frame_start, int(np.ceil(frames32[-1])))
    return BakeResult(action, fcurves * len(frames32), fcurves, (float(frames32[0]), float(frames32[-1])),
                      replaced, track)
