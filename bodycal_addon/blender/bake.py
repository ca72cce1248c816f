"""Step 5 of the pipeline (DESIGN.md §1): write an AvatarAnimation into a NEW action.

Keys are reduced first (`keyreduce`): each bone keeps the frames its rotation needs for linear
keys (or, with `interpolation="bezier"`, Bézier keys with Auto Clamped handles) to stay within
`tolerance_deg` of every sample, the root those its location needs to stay within
`location_tolerance_mm`; a tolerance of 0 keeps every sample. Keys are written per F-Curve
with `keyframe_points.add(n)` + `foreach_set("co", ...)`, a few thousand times faster than inserting
one key per call (BLENDER_NOTES.md: 5.8 M keys/s against 11.7 k/s).
Portable across Blender 4.2 (`action.fcurves`) and 4.4+ / 5.0 slotted actions
(`action.fcurve_ensure_for_datablock`). Two passes: `plan_bake` computes everything (the keys,
the action's name, what it replaces) and only reads the scene; `write_bake` is the one pass that
changes it, and if writing fails half way the new action is removed and the previous assignment
restored. `bake_animation` runs both.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from dataclasses import dataclass

import bpy
import numpy as np

from ..body.animation import AvatarAnimation
from ..core.errors import BodyCalError
from ..core.transforms import continuous_quaternions
from ..output import keyreduce
from ..output.keyreduce import DEFAULT_LOCATION_TOLERANCE_MM, DEFAULT_TOLERANCE_DEG, INTERPOLATIONS
from ..output.rigify import check_rigify_target
from ..output.root_motion import check_root_motion
from .fcurves import BEZIER, LINEAR, new_fcurve, write_keys


@dataclass
class BakeOptions:
    """How the bake keys the animation: output rate and key reduction (FORMATS.md §4.2)."""

    tolerance_deg: float = DEFAULT_TOLERANCE_DEG  # rotation error bound per bone; 0 keeps every sample
    location_tolerance_mm: float = DEFAULT_LOCATION_TOLERANCE_MM  # root location bound (world mm)
    fps: float | None = None  # output frame rate; None keys the samples as they are
    root_motion: str = "root"  # where the travel goes: root | pelvis | in-place (retarget/root_motion.py)
    rigify_target: str = "fk"  # a generated Rigify rig: keys on its FK controls or its DEF- bones (retarget/rigify.py)
    interpolation: str = "linear"  # the keys': linear, or bezier (Auto Clamped handles, the bound kept)

    def __post_init__(self):
        check_root_motion(self.root_motion)
        check_rigify_target(self.rigify_target)
        check_interpolation(self.interpolation)
        for name in ("tolerance_deg", "location_tolerance_mm"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) and v >= 0):
                raise BodyCalError(f"{name.replace('_', ' ')} must be a number >= 0, got {v!r}", field=name)
        if self.fps is not None and not (isinstance(self.fps, (int, float)) and not isinstance(self.fps, bool)
                                         and np.isfinite(self.fps) and 1 <= self.fps <= 1000):
            raise BodyCalError(f"the output frame rate must be a number from 1 to 1000, got {self.fps!r}", field="fps")


def check_interpolation(interpolation: str) -> None:
    if interpolation not in INTERPOLATIONS:
        raise BodyCalError(f"unknown key interpolation {interpolation!r}", field="interpolation",
                           hint=f"one of {', '.join(INTERPOLATIONS)}")


# A bone whose rotation keeps more than this share of its frames is named after the bake (takes of
# at least DENSE_MIN_FRAMES): the reduction could hardly thin it, because the rotation changes by
# more than the tolerance from one frame to the next: device or LED noise, mostly (LED gloves at
# 0.15 mm give hands and fingers 0.5-0.7 deg RMS; FORMATS.md §4.2).
DENSE_FRACTION = 0.9
DENSE_MIN_FRAMES = 100


def dense_bones(rot_keep: np.ndarray, names, tolerance_deg: float) -> tuple[str, ...]:
    """The bones whose rotation keeps more than DENSE_FRACTION of its frames (`rot_keep` (F, B)),
    most first; none when every frame was asked for or the take is short."""
    if tolerance_deg <= 0 or len(rot_keep) < DENSE_MIN_FRAMES:
        return ()
    share = rot_keep.mean(axis=0)
    return tuple(names[b] for b in np.argsort(-share, kind="stable") if share[b] > DENSE_FRACTION)


# What makes a bone's rotation change by more than the tolerance every frame, and what keeps fewer
# keys, by kind of take (retarget/takes.py): only what that kind's bake can do.
DENSE_CAUSES = {
    "recording": ("tracker noise reaching the bones, or fast motion",
                  "smoothing the devices (Smooth Devices, --filter) or a larger tolerance keeps fewer keys"),
    "animation": ("the source action's own motion or capture jitter",
                  "smoothing the source (Smooth Source, --filter) or a larger tolerance keeps fewer keys"),
}


def dense_note(bones, kind: str = "recording") -> str:
    """The end of a bake's summary line naming the bones the key reduction could hardly thin, with
    what causes it and what helps for a take of `kind`."""
    if not bones:
        return ""
    cause, remedy = DENSE_CAUSES.get(kind, DENSE_CAUSES["animation"])
    shown = ", ".join(bones[:3]) + (f" and {len(bones) - 3} more" if len(bones) > 3 else "")
    return (f"; {len(bones)} bone{'s' if len(bones) > 1 else ''} kept over {DENSE_FRACTION:.0%} of the frames "
            f"({shown}): their rotation changes by more than the tolerance from frame to frame ({cause}); {remedy}")


def baked_line(action: str, method: str, frames: int, fps: float, keys: int, seconds: float, samples: int = 0,
               frame_range: tuple[float, float] | None = None) -> str:
    """The start of a retarget's or a transfer's summary line (`samples`: the keys an every-frame
    bake would have written, given to show the share kept; `frame_range`: where the keys are)."""
    kept = f" ({keys / samples:.0%} of every frame)" if 0 < keys < samples else ""
    span = f" ({frame_range[0]:g}-{frame_range[1]:g})" if frame_range else ""
    return (f"Baked '{action}' ({method}): {frames} frames{span} at {fps:g} fps, {keys} keys{kept} "
            f"in {seconds:.1f} s")


def scene_rate(fps: float) -> tuple[int, float]:
    """(render.fps, render.fps_base) that play at `fps`, fractional rates included."""
    whole = max(1, int(round(fps)))
    return whole, whole / fps


@dataclass
class BakeResult:
    action: bpy.types.Action
    keys: int
    fcurves: int
    frame_range: tuple[float, float]
    replaced: str | None = None
    nla_track: str | None = None
    samples: int = 0  # keys an every-frame bake would have written
    dense_bones: tuple[str, ...] = ()  # bones keyed at more than DENSE_FRACTION of the frames, most first


_POSE_SETTINGS = ("rotation_mode", "location", "rotation_quaternion", "rotation_euler", "rotation_axis_angle", "scale")


@contextlib.contextmanager
def restored_on_failure(obj, scene):
    """What getting an armature ready for a bake changes, put back if the bake then fails: each
    pose bone's rotation mode and pose, its custom number properties (a Rigify rig's IK/FK
    switches), every bone constraint's mute, the object's own properties and the scene's frame
    rate. A bake that completes keeps them: the new action plays with them."""
    bones = {pb.name: ({k: _copied(getattr(pb, k)) for k in _POSE_SETTINGS},
                       {k: pb[k] for k in pb.keys() if isinstance(pb[k], (int, float))},
                       [c.mute for c in pb.constraints]) for pb in obj.pose.bones}
    props = _plain_properties(obj)
    rate = scene.render.fps, scene.render.fps_base
    try:
        yield
    except BaseException:
        for name, (settings, numbers, mutes) in bones.items():
            pb = obj.pose.bones[name]
            for k, v in settings.items():
                setattr(pb, k, v)
            for k, v in numbers.items():
                pb[k] = v
            for c, m in zip(pb.constraints, mutes):
                c.mute = m
        for k in _plain_properties(obj).keys() - props.keys():
            del obj[k]
        for k, v in props.items():
            obj[k] = v
        scene.render.fps, scene.render.fps_base = rate
        raise


def _copied(value):
    return value if isinstance(value, str) else tuple(value)


def _plain_properties(obj) -> dict:
    """The object's custom properties that are a number or a string (what a bake may set)."""
    return {k: obj[k] for k in obj.keys() if isinstance(obj[k], (int, float, str))}


def default_action_name(recording: str, avatar: str, method: str) -> str:
    return f"{recording}|{avatar}|{method}"


def key_frames(time: np.ndarray, fps: float, frame_start: float) -> np.ndarray:
    return frame_start + (np.asarray(time, float) - float(time[0])) * fps


def validate(anim: AvatarAnimation, obj) -> None:
    if obj is None or obj.type != "ARMATURE":
        raise BodyCalError("pick an armature to bake onto", source=getattr(obj, "name", "no object"))
    missing = [b for b in [*anim.bone_names, anim.root_bone, *anim.bone_locations] if b not in obj.pose.bones]
    if missing:
        raise BodyCalError(f"the armature has no bones named {', '.join(sorted(set(missing))[:6])}",
                           source=obj.name, hint="recalibrate the avatar after renaming bones")
    if anim.frame_count == 0:
        raise BodyCalError("nothing to bake: the animation has no frames", source=obj.name)
    if not (np.all(np.isfinite(anim.rotations)) and np.all(np.isfinite(anim.root_location))
            and all(np.all(np.isfinite(v)) for v in anim.bone_locations.values())):
        raise BodyCalError("the retargeted animation has non-finite values; nothing was written", source=obj.name)


def world_scale(obj) -> float:
    """The armature object's (uniform) world scale: armature units per metre is its inverse."""
    # From the object's own transform (always current; matrix_world waits for a depsgraph update).
    m = obj.matrix_basis
    if obj.parent is not None:
        m = obj.parent.matrix_world @ obj.matrix_parent_inverse @ m
    lin = np.array(m, float)[:3, :3]
    return float(np.cbrt(abs(np.linalg.det(lin)))) or 1.0


def bake_animation(anim: AvatarAnimation, obj, *, action_name: str | None = None, replace: bool = False,
                   fps: float | None = None, frame_start: float | None = None, push_to_nla: bool = False,
                   tolerance_deg: float = DEFAULT_TOLERANCE_DEG,
                   location_tolerance_mm: float = DEFAULT_LOCATION_TOLERANCE_MM, own: bool = False,
                   set_scene_range: bool = False, interpolation: str = "linear",
                   verify: Callable[[], None] | None = None) -> BakeResult:
    """Bake `anim` onto armature `obj` as a new action and make it the active action; one key per
    sample at frame_start (default: the scene's first frame) + (t - t0) x fps, reduced within the
    tolerances (0 keeps every sample). The scene's frame range becomes the action's only with
    `set_scene_range`.
    `own`: the caller gives `anim` away; its rotations are made sign-continuous in place instead
    of in a copy (a 10-minute take: 87 MB less while the keys are made). `interpolation`: "linear"
    keys, or "bezier" keys with Auto Clamped handles (the reduction then keeps the bound on the
    Bézier curves: keyreduce).

    An existing action of the same name is kept (the new one gets Blender's `.001` suffix) unless
    `replace` is True, in which case the old action is removed once the new one is written.
    `verify()` runs once the keys are written and the action assigned, before anything else is
    changed (`bake_check.verify`); when it raises, the new action is removed as on a failed write.

    Two passes: `plan_bake` computes everything (no scene change), `write_bake` writes it.
    """
    plan = plan_bake(anim, obj, action_name=action_name, replace=replace, fps=fps, frame_start=frame_start,
                     tolerance_deg=tolerance_deg, location_tolerance_mm=location_tolerance_mm, own=own,
                     interpolation=interpolation)
    return write_bake(plan, obj, push_to_nla=push_to_nla, set_scene_range=set_scene_range, verify=verify)


@dataclass
class KeyedProperty:
    """One property the bake keys, one F-Curve per channel: a pose bone's rotation_quaternion (4)
    or location (3), or a custom property (1, a Rigify switch). `values` holds every sample (F,
    channels), float32, as Blender keys them; the keys are those at the frames `kept` marks (F,)."""

    data_path: str
    group: str | None  # the F-Curve group: the bone's name
    kept: np.ndarray
    values: np.ndarray
    interpolation: int = LINEAR

    @property
    def keys(self) -> int:
        return self.values.shape[1] * int(np.count_nonzero(self.kept))


@dataclass
class BakePlan:
    """Everything a bake writes, computed by `plan_bake` without changing the scene: the action's
    name, what it replaces, the bones set to quaternion rotation and every property's keys.
    `write_bake` writes it. The action's slot is the armature object's, the one Blender makes when
    the new action is assigned (4.4+; fcurves.py)."""

    action_name: str  # the action's name once written
    new_name: str  # the name it is created with (a temporary one while it replaces `replaces`)
    replaces: str | None  # the existing action of that name it removes once written (`replace`)
    frames32: np.ndarray  # (F,) the key frames of every sample, float32
    quaternion_bones: tuple[str, ...]  # their rotation_mode becomes QUATERNION
    properties: list[KeyedProperty]
    dense_bones: tuple[str, ...] = ()  # bones keyed at more than DENSE_FRACTION of the frames, most first

    @property
    def keys(self) -> int:
        return sum(p.keys for p in self.properties)

    @property
    def fcurves(self) -> int:
        return sum(p.values.shape[1] for p in self.properties)


def _bone_path(bone_name: str, prop: str) -> str:
    return f'pose.bones["{bpy.utils.escape_identifier(bone_name)}"].{prop}'


def plan_bake(anim: AvatarAnimation, obj, *, action_name: str | None = None, replace: bool = False,
              fps: float | None = None, frame_start: float | None = None,
              tolerance_deg: float = DEFAULT_TOLERANCE_DEG,
              location_tolerance_mm: float = DEFAULT_LOCATION_TOLERANCE_MM, own: bool = False,
              interpolation: str = "linear") -> BakePlan:
    """The bake of `anim` onto `obj` (`bake_animation`'s arguments), computed in numpy: the checks,
    the key frames, the sign-continuous rotations, the keys the reduction keeps (rotations; the
    root's location, and the bones root motion and a Rigify torso key: `anim.bone_locations`; the
    Rigify switches' constant keys), the action's name. Reads the scene (its rate and first frame,
    the armature, the actions' names); changes nothing in it. With `own`, `anim`'s rotations are
    made continuous and reduced in place."""
    validate(anim, obj)
    check_interpolation(interpolation)
    bezier = interpolation == "bezier"
    kind = BEZIER if bezier else LINEAR
    scene = bpy.context.scene
    fps = float(fps or scene.render.fps / scene.render.fps_base)
    frame_start = float(scene.frame_start if frame_start is None else frame_start)
    frames32 = key_frames(anim.time, fps, frame_start).astype(np.float32)
    in_place = own and anim.rotations.dtype in (np.float32, np.float64) and anim.rotations.flags.writeable
    # (F, B, 4) as Blender keys them, float32: what an every-frame bake holds, so the reduction's
    # bound is measured against it, whatever precision `anim` came in.
    rotations = np.asarray(continuous_quaternions(anim.rotations, in_place=in_place), np.float32)
    # The key values go into `rotations` itself, at the kept frames (it is the bake's own array, or
    # the one `own` gave away).
    rot_keep, _ = keyreduce.rotation_keys(rotations, np.radians(max(tolerance_deg, 0.0)), out=rotations,
                                          bezier=bezier, frames=frames32)
    properties = [KeyedProperty(_bone_path(bone_name, "rotation_quaternion"), bone_name, rot_keep[:, b],
                                rotations[:, b], kind)
                  for b, bone_name in enumerate(anim.bone_names)]
    # The tolerance is in world millimetres; locations are keyed in armature units.
    location_tolerance = max(location_tolerance_mm, 0.0) / 1000.0 / world_scale(obj)
    # the root (or pelvis) bone, then the root bone under root motion and Rigify's torso
    for bone_name, loc in {anim.root_bone: anim.root_location, **anim.bone_locations}.items():
        kept, values = keyreduce.location_keys(np.asarray(loc, np.float32), location_tolerance, bezier=bezier,
                                               frames=frames32)
        properties.append(KeyedProperty(_bone_path(bone_name, "location"), bone_name, kept, values, kind))
    first = np.zeros(len(frames32), bool)
    first[0] = True
    for path, value in anim.constant_keys.items():  # switches: one key holds for the whole action
        properties.append(KeyedProperty(path, None, first, np.broadcast_to(np.float32(value), (len(frames32), 1))))
    name = action_name or default_action_name("recording", obj.name, anim.method)
    old = bpy.data.actions.get(name)
    replaces = old.name if old is not None and replace else None
    return BakePlan(name, name + ".bodycal-new" if replaces else name, replaces, frames32, tuple(anim.bone_names),
                    properties, dense_bones(rot_keep, anim.bone_names, tolerance_deg))


def write_bake(plan: BakePlan, obj, *, push_to_nla: bool = False, set_scene_range: bool = False,
               verify: Callable[[], None] | None = None) -> BakeResult:
    """Writes `plan` (`plan_bake`) onto `obj`, the only pass that changes the scene: one new action,
    assigned, its keys written with foreach_set, then `verify()`; if anything fails the action is
    removed and the previous assignment restored. Then the replaced action is removed, the action
    pushed to the NLA (`push_to_nla`) and the scene's frame range set (`set_scene_range`)."""
    scene = bpy.context.scene
    frames32 = plan.frames32
    had_animation_data = obj.animation_data is not None
    previous_action = obj.animation_data.action if had_animation_data else None
    action = bpy.data.actions.new(plan.new_name)
    action.use_fake_user = False
    try:
        ad = obj.animation_data_create()
        ad.action = action
        for bone_name in plan.quaternion_bones:
            obj.pose.bones[bone_name].rotation_mode = "QUATERNION"
        for prop in plan.properties:
            frames, values = frames32[prop.kept], prop.values[prop.kept]
            for i in range(values.shape[1]):
                write_keys(new_fcurve(action, obj, prop.data_path, i, prop.group), frames, values[:, i],
                           prop.interpolation)
        if verify is not None:
            verify()
    except Exception:
        if had_animation_data:
            obj.animation_data.action = previous_action
        elif obj.animation_data is not None:
            obj.animation_data_clear()
        bpy.data.actions.remove(action)
        raise
    if plan.replaces is not None:
        bpy.data.actions.remove(bpy.data.actions[plan.replaces])
        action.name = plan.action_name
    track = None
    if push_to_nla:
        nla = obj.animation_data.nla_tracks.new()
        nla.name = action.name
        nla.strips.new(action.name, int(round(frames32[0])), action)
        obj.animation_data.action = None
        track = nla.name
    if set_scene_range:
        scene.frame_start = int(np.floor(frames32[0]))
        scene.frame_end = max(scene.frame_start, int(np.ceil(frames32[-1])))
    return BakeResult(action, plan.keys, plan.fcurves, (float(frames32[0]), float(frames32[-1])), plan.replaces,
                      track, plan.fcurves * len(frames32), plan.dense_bones)
