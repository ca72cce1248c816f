"""Animated scene objects as a take (FORMATS.md §2.5): trackers and controllers another tool
recorded in Blender (the Tracking Toolkit extension's objects, another add-on's empties) read as a
BodyCal Recording over the scene's frame range at the scene's rate, and put in the scene as an
imported recording is (`recording_scene.import_recording_to_scene`: its JSON, one empty per device
and marker, the steps as timeline markers), so calibration, retargeting, baking and a saved .blend
read it the same way. The objects themselves are never changed.

How a world matrix is read (docs/BLENDER_NOTES.md, "Sampling objects"):
- from the F-Curves, when the object's transform follows from its action alone (location,
  rotation in any mode, scale and their deltas) and it is parented, if at all, to an object whose
  transform does too: each channel's keys where they sit on every sampled frame (`foreach_get`),
  else `FCurve.evaluate` per frame, composed in numpy by Blender's rule (local = T R_delta R S,
  world = parent's world @ matrix_parent_inverse @ local);
- from the depsgraph otherwise (constraints, drivers, NLA strips or blending, bone, vertex or
  curve parents, a rigid body, time remapping): the scene evaluated at every frame
  (`scene.frame_set`), `matrix_world` read, and the current frame put back.
"""

from __future__ import annotations

import math

import bpy
import numpy as np

from ..core.errors import BodyCalError
from ..core.transforms import axis_angle_to_quat, euler_matrices, quat_to_matrix, unit_and_norm
from ..recording.from_matrices import SampledObject, recording_from_matrices
from ..recording.led_gloves import add_led_hand_frames
from ..recording.model import DEVICE_KINDS, ROLES, ROLES_LIST, Recording
from ..recording.roles import apply_roles
from .fcurves import object_fcurves, sample_fcurve
from .recording_scene import (
    ROLE_PROP,
    frame_mapping_in_scene,
    import_recording_to_scene,
    recording_from_scene,
    scene_recording_collection,
    segments_from_markers,
)

TRANSFORM_PATHS = ("location", "rotation_euler", "rotation_quaternion", "rotation_axis_angle", "scale",
                   "delta_location", "delta_rotation_euler", "delta_rotation_quaternion", "delta_scale")
DEFAULT_NAME = "objects"


def _live_constraints(obj) -> bool:
    return any(not c.mute and c.influence > 0.0 for c in obj.constraints)


def _transform_curves(obj) -> dict:
    """{(path, index): fcurve} of the object's action on its transform channels, muted ones left out
    (the depsgraph skips a muted curve or a curve in a muted group)."""
    return {key: fc for key, fc in object_fcurves(obj).items()
            if key[0] in TRANSFORM_PATHS and not fc.mute and not (fc.group is not None and fc.group.mute)}


def _transform_drivers(obj) -> bool:
    ad = obj.animation_data
    return ad is not None and any(d.data_path in TRANSFORM_PATHS and not d.mute for d in ad.drivers)


def depsgraph_reason(obj, scene) -> str | None:
    """Why the object's world matrix cannot be read from F-Curves alone (then the scene is
    evaluated frame by frame), or None."""
    ad = obj.animation_data
    if _live_constraints(obj):
        return "constraints"
    if _transform_drivers(obj):
        return "drivers"
    if ad is not None:
        if ad.use_nla and any(not t.mute and len(t.strips) for t in ad.nla_tracks):
            return "NLA strips"
        if ad.use_tweak_mode or ad.action_blend_type != "REPLACE" or ad.action_influence != 1.0:
            return "action blending"
        if ad.action is not None and len(getattr(ad.action, "layers", ())) > 1:
            return "action layers"
    if obj.rigid_body is not None:
        return "a rigid body"
    if scene.render.frame_map_old != scene.render.frame_map_new:
        return "time remapping"
    if obj.parent is not None:
        if obj.parent_type != "OBJECT" or obj.parent.type == "CURVE":
            return f"a {obj.parent_type.lower()} parent"
        reason = depsgraph_reason(obj.parent, scene)
        if reason is not None:
            return f"its parent's {reason}"
    return None


def is_animated(obj) -> bool:
    """Whether anything moves the object over time: transform F-Curves, drivers, NLA strips,
    constraints, a rigid body, or an ancestor that moves."""
    ad = obj.animation_data
    own = bool(_transform_curves(obj)) or _transform_drivers(obj) or _live_constraints(obj) \
        or obj.rigid_body is not None \
        or (ad is not None and ad.use_nla and any(not t.mute and len(t.strips) for t in ad.nla_tracks))
    return own or (obj.parent is not None and is_animated(obj.parent))


def _channel(curves, obj, path: str, size: int, frames: np.ndarray) -> np.ndarray:
    """(F, size) values of `obj.<path>` at `frames`: its F-Curves, else the property's value."""
    current = list(getattr(obj, path))
    out = np.empty((len(frames), size))
    for k in range(size):
        fc = curves.get((path, k))
        out[:, k] = sample_fcurve(fc, frames) if fc is not None else current[k]
    return out


def _rotations(curves, obj, frames: np.ndarray) -> np.ndarray:
    """(F, 3, 3) of the object's rotation after its delta rotation (Blender: R_delta @ R)."""
    mode = obj.rotation_mode
    if mode == "QUATERNION":
        def quat(path):
            q, n = unit_and_norm(_channel(curves, obj, path, 4, frames))
            # Blender's normalize_qt makes a zero quaternion (0, 1, 0, 0): a half turn about X.
            return quat_to_matrix(np.where(n[:, None] > 0.0, q, [0.0, 1.0, 0.0, 0.0]))

        return quat("delta_rotation_quaternion") @ quat("rotation_quaternion")
    if mode == "AXIS_ANGLE":  # no delta: Blender keeps none for axis-angle
        v = _channel(curves, obj, "rotation_axis_angle", 4, frames)  # (angle, x, y, z)
        return quat_to_matrix(axis_angle_to_quat(v[:, 1:], v[:, 0]))
    return euler_matrices(_channel(curves, obj, "delta_rotation_euler", 3, frames), mode) @ \
        euler_matrices(_channel(curves, obj, "rotation_euler", 3, frames), mode)


def local_matrices(obj, frames: np.ndarray) -> np.ndarray:
    """(F, 4, 4) of the object's own transform at `frames` from its F-Curves (BKE_object_to_mat4:
    translation location + delta, then the rotation, then scale x delta scale)."""
    curves = _transform_curves(obj)
    out = np.zeros((len(frames), 4, 4))
    scale = _channel(curves, obj, "scale", 3, frames) * _channel(curves, obj, "delta_scale", 3, frames)
    out[:, :3, :3] = _rotations(curves, obj, frames) * scale[:, None, :]
    out[:, :3, 3] = _channel(curves, obj, "location", 3, frames) + _channel(curves, obj, "delta_location", 3, frames)
    out[:, 3, 3] = 1.0
    return out


def fcurve_world_matrices(obj, frames: np.ndarray, memo: dict) -> np.ndarray:
    """(F, 4, 4) world matrices from the F-Curves of the object and its parents (`memo`: by name)."""
    if obj.name not in memo:
        local = local_matrices(obj, frames)
        if obj.parent is not None:
            inverse = np.array(obj.matrix_parent_inverse, float)
            local = fcurve_world_matrices(obj.parent, frames, memo) @ (inverse @ local)
        memo[obj.name] = local
    return memo[obj.name]


def depsgraph_world_matrices(scene, objects, frames: np.ndarray) -> np.ndarray:
    """(F, N, 4, 4) of `matrix_world` with the scene evaluated at each frame; the current frame
    (and subframe) put back afterwards."""
    out = np.empty((len(frames), len(objects), 4, 4))
    current, sub = scene.frame_current, scene.frame_subframe
    try:
        for k, f in enumerate(frames):
            scene.frame_set(int(f))
            for i, obj in enumerate(objects):
                out[k, i] = obj.matrix_world
    finally:
        scene.frame_set(current, subframe=sub)
    return out


def sample_world_matrices(scene, objects, frames: np.ndarray) -> tuple[np.ndarray, dict[str, str]]:
    """(F, N, 4, 4) world matrices of `objects` at the integer scene `frames`, and {name: reason}
    for those read through the depsgraph."""
    frames = np.asarray(frames, float)
    slow = {obj.name: r for obj in objects if (r := depsgraph_reason(obj, scene)) is not None}
    out = np.empty((len(frames), len(objects), 4, 4))
    memo: dict = {}
    for i, obj in enumerate(objects):
        if obj.name not in slow:
            out[:, i] = fcurve_world_matrices(obj, frames, memo)
    idx = [i for i, obj in enumerate(objects) if obj.name in slow]
    if idx:
        out[:, idx] = depsgraph_world_matrices(scene, [objects[i] for i in idx], frames)
    return out, slow


def check_unit_scale(scene) -> None:
    """BodyCal reads one scene unit as one metre (imports, avatars, bakes): a scene whose Unit
    Scale says otherwise is refused, rather than read at a scale the avatars in it are not."""
    scale = scene.unit_settings.scale_length
    if not math.isclose(scale, 1.0, rel_tol=0.0, abs_tol=1e-9):
        raise BodyCalError(f"the scene's Unit Scale is {scale:g}: BodyCal reads object locations as metres, one "
                           "unit a metre", source=scene.name, field="Scene > Units > Unit Scale",
                           hint="set the Unit Scale to 1.0 (scale the objects' animation to metres if it is not)")


def _given(obj, prop: str, allowed) -> str | None:
    value = obj.get(prop)
    return value if isinstance(value, str) and value in allowed else None


def identify_missing_roles(rec: Recording) -> None:
    """Roles of the devices given none, from the T-pose when the timeline marks one (roles.py);
    a T-pose that cannot be read is a note, not an error: the user assigns the roles instead."""
    missing = [d.name for d in rec.devices if d.role is None]
    if not missing:
        return
    if not rec.segments_of("tpose"):
        rec.notes.append(f"no role for {', '.join(missing)} and no T-pose marked on the timeline: assign them "
                         f"({ROLES_LIST}) or mark the T-pose (a bodycal:tpose marker) and press Identify Roles")
        return
    try:
        apply_roles(rec)
    except BodyCalError as exc:
        rec.notes.append(f"roles not identified from the T-pose ({exc.line()}): assign them ({ROLES_LIST})")


def recording_from_objects(scene, objects, name: str = DEFAULT_NAME) -> tuple[bpy.types.Collection, Recording]:
    """The animated `objects` over the scene's frame range as the scene's recording (the module
    docstring); returns its new collection and the Recording. Objects nothing moves are left out
    (a note says which). Everything is read and checked before the scene is touched."""
    check_unit_scale(scene)
    objects = list(objects)
    moving = [o for o in objects if is_animated(o)]
    if not moving:
        raise BodyCalError(f"none of the {len(objects)} selected objects is animated", source=scene.name,
                           hint="select the tracker objects: keyed location / rotation, constraints or an "
                                "animated parent")
    f0, f1 = scene.frame_start, scene.frame_end
    if f1 <= f0:
        raise BodyCalError(f"the scene's frame range {f0}-{f1} holds fewer than 2 frames", source=scene.name,
                           hint="set the frame range to the take's frames")
    frames = np.arange(f0, f1 + 1, dtype=float)
    rate = scene.render.fps / scene.render.fps_base
    matrices, slow = sample_world_matrices(scene, moving, frames)
    notes = [f"read {len(moving)} objects over frames {f0}-{f1} at {rate:.4g} fps"
             + (f"; through the scene's evaluation: {', '.join(f'{n} ({r})' for n, r in slow.items())}"
                if slow else "")]
    if len(moving) < len(objects):
        notes.append("left out (not animated): " + ", ".join(o.name for o in objects if o not in moving))
    time = (frames - frames[0]) / rate
    segments = segments_from_markers(scene, time, 0.0, rate, f0, _recorded_steps(scene, f0, rate), source=scene.name)
    sampled = [SampledObject(o.name, kind=_given(o, "bodycal_kind", DEVICE_KINDS), role=_given(o, ROLE_PROP, ROLES))
               for o in moving]
    rec = recording_from_matrices(name or DEFAULT_NAME, frames, rate, matrices, sampled, segments=segments,
                                  source=f"objects in scene {scene.name}", notes=notes)
    identify_missing_roles(rec)
    add_led_hand_frames(rec)
    return import_recording_to_scene(rec, scene, frame_start=f0), rec


def _recorded_steps(scene, f0: int, rate: float) -> list[dict] | None:
    """The steps of the scene's recording (its markers, with the ends it stored), on the clock of a
    take read from frame `f0` at `rate`: a marker the import placed keeps its step's end for the
    objects' take too (the import marks only where steps start)."""
    if scene_recording_collection(scene) is None:
        return None
    try:
        old = recording_from_scene(scene)
        frame_start, old_rate = frame_mapping_in_scene(scene)
    except BodyCalError:  # its steps cannot be read: the markers alone say them
        return None
    t0 = float(old.time[0])

    def clock(t: float) -> float:
        # A bound on one of the recording's samples (its times rounded to 1e-9 s in the file) stays
        # on that sample here, so the same samples fall in the step.
        frames = frame_start + (t - t0) * old_rate - f0  # since the take's first frame
        return (round(frames) if abs(frames - round(frames)) < 1e-5 else frames) / rate

    return [{"step": s.step, "point": s.point or "", "by": s.by or "", "start": clock(s.start), "end": clock(s.end)}
            for s in old.segments]

