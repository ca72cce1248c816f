"""A Recording in the Blender scene: one animated empty per device and per marker, timeline
markers for the calibration steps, and enough custom properties to rebuild the Recording after
the .blend is saved and reopened (`recording_from_scene`).

Layout:
- a collection named after the recording, its custom property `bodycal` holding the recording's
  name, source, notes, device list (name, kind, role), marker names, the time of every frame and
  the frame mapping (frame = frame_start + (t - t0) * fps);
- one empty per device (arrows, quaternion rotation) and per marker (small sphere), with custom
  properties `bodycal_device` / `bodycal_marker` naming what it shows, and a keyed custom property
  `bodycal_tracked` (1 tracked, 0 not; constant interpolation); a device's role in `bodycal_role`
  and where it came from in `bodycal_role_from` (FORMATS.md §2.5);
- keys written with `keyframe_points.add` + `foreach_set` (BLENDER_NOTES.md), portable to slotted
  actions (4.4+ / 5.0) through `action.fcurve_ensure_for_datablock`;
- timeline markers (`step_markers`, FORMATS.md §2.5): `bodycal:<step>[:<point>[:<by>]]` at each
  segment start ("starts", the default: one marker per step), plus `bodycal:end` where a segment
  ends without another one starting ("bounds"), or none ("none": the steps are the stored ones
  until a `bodycal:` marker is added). A step ends at the next `bodycal:` marker (FORMATS.md §2.4),
  or at its recorded end while its marker is where the import put it, so editing the markers
  edits the steps;
- the scene's frame rate and range set to the recording's unless asked not to: with the scene's
  rate kept, sample k is at frame_start + (t_k - t_0) x the scene's rate (the take plays in real
  time, its samples between frames when the rates differ);
- `scene["bodycal_recording"]` points at the collection, so later steps find the recording.
"""

from __future__ import annotations

import json
import math

import bpy
import numpy as np

from ..core.errors import BodyCalError
from ..core.transforms import continuous_quaternions
from ..recording.io import DEFAULT_FILL_GAPS_S as DEFAULT_FILL_GAPS_S  # re-exported: the import's options
from ..recording.io import JSON_SUFFIX as JSON_SUFFIX  # re-exported: File > Import's file filter
from ..recording.io import RECORDING_GLOBS as RECORDING_GLOBS  # re-exported: File > Import's file filter
from ..recording.io import check_recording_file as check_recording_file  # re-exported: a dropped file's check
from ..recording.io import load_recording
from ..recording.model import ROLES, STEPS, Device, Recording, Segment
from .fcurves import CONSTANT, new_fcurve, object_fcurves, read_keys, write_keys

SCENE_KEY = "bodycal_recording"
DEVICE_PROP = "bodycal_device"  # on a device empty: the device name
MARKER_PROP = "bodycal_marker"  # on a marker empty: the marker name
ROLE_PROP = "bodycal_role"  # on a device empty: its role (the user may change it; "" = identify from the T-pose)
ROLE_FROM_PROP = "bodycal_role_from"  # on a device empty: "file", "tpose" (identified) or "user" (set in the list)
META_KEY = "bodycal"
TIME_KEY = "bodycal_time"
TRACKED = "bodycal_tracked"
MARKER_PREFIX = "bodycal:"
END_LABEL = "bodycal:end"
STEP_MARKERS = ("starts", "bounds", "none")  # how the import shows the steps on the timeline


def _scene_of(context_or_scene):
    if context_or_scene is None:
        return bpy.context.scene
    if isinstance(context_or_scene, bpy.types.Scene):
        return context_or_scene
    return context_or_scene.scene


def frame_mapping(rec: Recording) -> tuple[int, float, float]:
    """(fps, fps_base, effective fps) for the scene: the recording's mean rate, as an integer fps
    with fps_base carrying the fraction."""
    rate = rec.fps if rec.frame_count > 1 else 30.0
    fps = max(1, int(round(rate)))
    return fps, fps / rate, rate


def _segment_markers(rec: Recording, frame_of, layout: str) -> list[tuple[str, int]]:
    """The timeline markers of `layout` (STEP_MARKERS): each step's start, and with "bounds" an end
    marker where the step ends before the next one starts."""
    out = []
    if layout == "none":
        return out
    segs = sorted(rec.segments, key=lambda s: s.start)
    last_frame = frame_of(rec.time[-1])
    for k, s in enumerate(segs):
        out.append((MARKER_PREFIX + s.label, frame_of(s.start)))
        if layout != "bounds":
            continue
        nxt = segs[k + 1].start if k + 1 < len(segs) else None
        end_frame = frame_of(s.end)
        if (nxt is None and end_frame < last_frame) or (nxt is not None and frame_of(nxt) > end_frame):
            out.append((END_LABEL, end_frame))
    return out


def import_recording_file(path, context_or_scene=None, *, fill_gaps_s: float = DEFAULT_FILL_GAPS_S,
                          hands: str = "geometry", **placing) -> tuple[Recording, object]:
    """Read the recording file at `path` (recording/io) and put it in the scene
    (`import_recording_to_scene`, which `placing` is passed to): (the recording, its new
    collection). Read and checked first, written last: on error the scene is untouched."""
    rec = load_recording(path, fill_gaps_s=fill_gaps_s, hands=hands)
    return rec, import_recording_to_scene(rec, context_or_scene, **placing)


def import_recording_to_scene(rec: Recording, context_or_scene=None, *, frame_start: int = 1,
                              set_scene_rate: bool = True, set_scene_range: bool = True,
                              step_markers: str = "starts"):
    """Put `rec` in the scene (see the module docstring), its first sample at `frame_start`;
    returns the new collection. `set_scene_rate`: the scene plays at the recording's rate, one
    sample per frame (else its rate is kept and the samples are timed to it); `set_scene_range`:
    the scene's range becomes the recording's frames; `step_markers`: one of STEP_MARKERS.
    Everything is computed before the scene is touched."""
    scene = _scene_of(context_or_scene)
    f = rec.frame_count
    if f == 0:
        raise BodyCalError("the recording has no frames", source=rec.source or rec.name)
    if step_markers not in STEP_MARKERS:
        raise BodyCalError(f"unknown step marker layout {step_markers!r}", field="step markers",
                           hint=f"one of {', '.join(STEP_MARKERS)}")
    # --- compute -------------------------------------------------------------------------------
    fps, fps_base, rate = frame_mapping(rec)
    if not set_scene_rate:
        rate = scene.render.fps / scene.render.fps_base
    t0 = float(rec.time[0])
    frames32 = (frame_start + (rec.time - t0) * rate).astype(np.float32)

    def frame_of(t):
        return int(round(frame_start + (float(t) - t0) * rate))

    pos = rec.positions.astype(np.float32)
    rot = continuous_quaternions(rec.rotations).astype(np.float32)  # per device, along the frame axis
    valid = rec.valid.astype(np.float32)
    mk = rec.markers.astype(np.float32)
    mk_valid = rec.marker_valid.astype(np.float32)
    labels = _segment_markers(rec, frame_of, step_markers)
    meta = {
        "name": rec.name, "source": rec.source, "notes": list(rec.notes),
        "devices": [{"name": d.name, "kind": d.kind, "role": d.role or ""} for d in rec.devices],
        "markers": list(rec.marker_names),
        "t0": t0, "rate": rate, "frame_start": frame_start, "step_markers": step_markers,
        "segments": [{"step": s.step, "start": s.start, "end": s.end, "point": s.point or "", "by": s.by or ""}
                     for s in rec.segments],
    }
    # --- write ---------------------------------------------------------------------------------
    coll = bpy.data.collections.new(rec.name or "recording")
    scene.collection.children.link(coll)
    coll[META_KEY] = json.dumps(meta)  # ID properties hold no lists of strings: JSON for the small things
    coll[TIME_KEY] = rec.time.tolist()  # a double array

    def empty(name, display, size):
        obj = bpy.data.objects.new(name[:63], None)
        obj.empty_display_type = display
        obj.empty_display_size = size
        coll.objects.link(obj)
        obj[TRACKED] = 1.0
        obj.animation_data_create()
        action = bpy.data.actions.new(f"{obj.name}|tracks")
        obj.animation_data.action = action
        return obj, action

    for i, d in enumerate(rec.devices):
        obj, action = empty(f"{rec.name}.{d.name}", "ARROWS", 0.1)
        obj[DEVICE_PROP] = d.name
        obj["bodycal_kind"] = d.kind
        obj[ROLE_PROP] = d.role or ""
        obj[ROLE_FROM_PROP] = "tpose" if d.identified else "file" if d.role else ""
        obj.rotation_mode = "QUATERNION"
        for k in range(3):
            write_keys(new_fcurve(action, obj, "location", k), frames32, pos[:, i, k])
        for k in range(4):
            write_keys(new_fcurve(action, obj, "rotation_quaternion", k), frames32, rot[:, i, k])
        write_keys(new_fcurve(action, obj, f'["{TRACKED}"]', 0), frames32, valid[:, i], CONSTANT)
    for j, name in enumerate(rec.marker_names):
        obj, action = empty(f"{rec.name}.{name}", "SPHERE", 0.01)
        obj[MARKER_PROP] = name
        for k in range(3):
            write_keys(new_fcurve(action, obj, "location", k), frames32, mk[:, j, k])
        write_keys(new_fcurve(action, obj, f'["{TRACKED}"]', 0), frames32, mk_valid[:, j], CONSTANT)

    for m in [m for m in scene.timeline_markers if m.name.startswith(MARKER_PREFIX)]:
        scene.timeline_markers.remove(m)  # one recording per scene: its steps replace the old ones
    for label, frame in labels:
        scene.timeline_markers.new(label, frame=frame)
    if set_scene_rate:
        scene.render.fps = fps
        scene.render.fps_base = fps_base
    if set_scene_range:
        scene.frame_start = frame_start
        scene.frame_end = max(frame_start, int(math.ceil(float(frames32[-1]) - 1e-3)))
    scene[SCENE_KEY] = coll
    return coll


def import_summary(rec: Recording, coll, context_or_scene=None) -> str:
    """The import's report line: what was read and where it went in the scene (its frames, the
    scene's rate and whether the scene's rate and range were set)."""
    scene = _scene_of(context_or_scene)
    meta = json.loads(coll[META_KEY])
    first = meta["frame_start"]
    last = first + (float(rec.time[-1]) - meta["t0"]) * meta["rate"]
    scene_rate = scene.render.fps / scene.render.fps_base
    timing = ("one sample per frame" if abs(scene_rate - rec.fps) <= 1e-6 * rec.fps or rec.frame_count < 2
              else f"timed to the scene's {scene_rate:.4g} fps")
    marks = sum(1 for m in scene.timeline_markers if m.name.startswith(MARKER_PREFIX))
    return (f"Imported {coll.name}: {len(rec.devices)} devices, {len(rec.marker_names)} markers, {rec.frame_count} "
            f"frames at {rec.fps:.4g} Hz on frames {first:g}-{last:.6g} ({timing}), {len(rec.segments)} steps, "
            f"{marks} timeline markers")


def scene_recording_collection(scene):
    coll = scene.get(SCENE_KEY)
    if isinstance(coll, bpy.types.Collection) and META_KEY in coll:
        return coll
    return None


def _step_marks(scene) -> list[tuple[int, str]]:
    return sorted((m.frame, m.name) for m in scene.timeline_markers if m.name.startswith(MARKER_PREFIX))


def segments_from_markers(scene, time: np.ndarray, t0: float, rate: float, frame_start: int,
                          stored: list[dict] | None = None, source: str = "") -> list[Segment]:
    """Steps from the timeline markers `bodycal:<step>[:<point>[:<by>]]`; each ends at the next
    `bodycal:` marker (or the end of the recording). A marker left where the import put it keeps
    the exact stored start and, unless the next marker comes first or is a moved `bodycal:end`,
    the stored end."""
    marks = _step_marks(scene)
    t_end = float(time[-1])
    half = 0.5 / rate + 1e-9

    def frame_time(frame):
        return t0 + (frame - frame_start) / rate

    exact = {}
    for s in stored or []:
        label = ":".join(p for p in (s["step"], s["point"], s["by"]) if p)
        exact.setdefault((label, int(round(frame_start + (s["start"] - t0) * rate))), (s["start"], s["end"]))
    out = []
    for k, (frame, name) in enumerate(marks):
        if name == END_LABEL:
            continue
        parts = name[len(MARKER_PREFIX):].split(":")
        step = parts[0]
        if step not in STEPS:
            raise BodyCalError(f"timeline marker '{name}' names no step", source=source, field="timeline markers",
                               where=f"frame {frame}", hint=f"steps: {', '.join(STEPS)}")
        nxt = marks[k + 1] if k + 1 < len(marks) else None
        start = frame_time(frame)
        end = frame_time(nxt[0]) if nxt else t_end
        key = (name[len(MARKER_PREFIX):], frame)
        if key in exact:
            start, e0 = exact[key]
            if nxt is None or (abs(end - e0) <= half if nxt[1] == END_LABEL else end >= e0 - half):
                end = e0
        start, end = max(start, float(time[0])), min(end, t_end)
        if end <= start:
            continue
        out.append(Segment(step=step, start=start, end=end, point=parts[1] if len(parts) > 1 and parts[1] else None,
                           by=parts[2] if len(parts) > 2 and parts[2] else None))
    return out


def _stored_segments(meta: dict) -> list[Segment]:
    return [Segment(step=s["step"], start=s["start"], end=s["end"], point=s["point"] or None, by=s["by"] or None)
            for s in meta.get("segments", [])]


def _steps_are_stored(scene, meta: dict) -> bool:
    """Imported without markers and none added since: the steps are the recording's own."""
    return meta.get("step_markers") == "none" and not _step_marks(scene)


def steps_in_scene(scene) -> dict[str, int]:
    """{step: count} of the scene's recording: from its `bodycal:` timeline markers, or the stored
    steps of a recording imported without markers (none added since)."""
    coll = scene_recording_collection(scene)
    try:
        meta = json.loads(coll[META_KEY]) if coll is not None else {}
    except (TypeError, ValueError):
        meta = {}
    if _steps_are_stored(scene, meta):
        steps = [s["step"] for s in meta.get("segments", [])]
    else:
        steps = [name[len(MARKER_PREFIX):].split(":")[0] for _frame, name in _step_marks(scene) if name != END_LABEL]
    out: dict[str, int] = {}
    for step in steps:
        out[step] = out.get(step, 0) + 1
    return out


def frame_mapping_in_scene(context_or_scene=None) -> tuple[float, float]:
    """(frame of the first sample, frames per second) the scene's recording was imported with:
    sample k is at frame_start + (t_k - t_0) x rate."""
    scene = _scene_of(context_or_scene)
    coll = scene_recording_collection(scene)
    try:
        meta = json.loads(coll[META_KEY])
        return float(meta["frame_start"]), float(meta["rate"])
    except (KeyError, TypeError, ValueError):
        raise BodyCalError("the stored recording is damaged", source=getattr(coll, "name", scene.name),
                           hint="re-import the recording") from None


def device_role(obj, imported: str) -> str | None:
    """The device's role as its empty says now: the user may set `bodycal_role` (the object's custom
    property) to a role or to "" (identified from the T-pose again); else the imported one."""
    role = obj.get(ROLE_PROP, imported)
    if not isinstance(role, str) or (role and role not in ROLES):
        raise BodyCalError(f"{role!r} is not a device role", source=obj.name, field=ROLE_PROP,
                           hint=f"set it to one of {', '.join(ROLES)}, or to \"\" to identify it from the T-pose")
    return role or None


def _check_roles_unique(devices: list[Device], source: str) -> None:
    seen: dict[str, str] = {}
    for d in devices:
        if d.role is not None and seen.setdefault(d.role, d.name) != d.name:
            raise BodyCalError(f"devices '{seen[d.role]}' and '{d.name}' both have the role '{d.role}'",
                               source=source, field=ROLE_PROP, hint="give each role to one device")


def recording_from_scene(context_or_scene=None, *, role_of=device_role) -> Recording:
    """Rebuild the scene's Recording from the empties' animation, their custom properties and the
    timeline markers (works after saving and reopening the .blend). `role_of(empty, imported)`:
    a device's role (default: what its empty says, `device_role`)."""
    scene = _scene_of(context_or_scene)
    coll = scene_recording_collection(scene)
    if coll is None:
        raise BodyCalError("no recording in this scene", source=scene.name,
                           hint="File > Import > BodyCal recording")
    try:
        meta = json.loads(coll[META_KEY])
        time = np.asarray(coll[TIME_KEY], float)
    except (KeyError, TypeError, ValueError):
        raise BodyCalError("the stored recording is damaged", source=coll.name,
                           hint="re-import the recording") from None
    f = len(time)
    t0, rate, frame_start = float(meta["t0"]), float(meta["rate"]), int(meta["frame_start"])
    by_device, by_marker = {}, {}
    for obj in coll.all_objects:
        if DEVICE_PROP in obj:
            by_device[obj[DEVICE_PROP]] = obj
        elif MARKER_PROP in obj:
            by_marker[obj[MARKER_PROP]] = obj
    notes = list(meta.get("notes", []))

    def channels(obj, path, count, what):
        curves = object_fcurves(obj)
        out = np.zeros((f, count), np.float32)
        for k in range(count):
            fc = curves.get((path, k))
            if fc is None:
                raise BodyCalError(f"{path}[{k}] is not animated", source=obj.name, field=what,
                                   hint="re-import the recording")
            _frames, values = read_keys(fc)
            if len(values) != f:
                raise BodyCalError(f"{path}[{k}] has {len(values)} keys, the recording {f} frames", source=obj.name,
                                   field=what, hint="re-import the recording")
            out[:, k] = values
        return out

    devices, pos, rot, valid = [], [], [], []
    for d in meta["devices"]:
        obj = by_device.get(d["name"])
        if obj is None:
            notes.append(f"device '{d['name']}' has no empty in {coll.name}: left out")
            continue
        devices.append(Device(name=d["name"], kind=d["kind"], role=role_of(obj, d["role"])))
        pos.append(channels(obj, "location", 3, d["name"]))
        rot.append(channels(obj, "rotation_quaternion", 4, d["name"]))
        valid.append(channels(obj, f'["{TRACKED}"]', 1, d["name"])[:, 0] > 0.5)
    names, mk, mk_valid = [], [], []
    for name in meta["markers"]:
        obj = by_marker.get(name)
        if obj is None:
            notes.append(f"marker '{name}' has no empty in {coll.name}: left out")
            continue
        names.append(name)
        mk.append(channels(obj, "location", 3, name))
        mk_valid.append(channels(obj, f'["{TRACKED}"]', 1, name)[:, 0] > 0.5)
    _check_roles_unique(devices, coll.name)
    stack = lambda xs, shape: np.stack(xs, axis=1).astype(float) if xs else np.zeros(shape)  # noqa: E731
    rotations = stack(rot, (f, 0, 4))
    if rotations.size:
        norm = np.linalg.norm(rotations, axis=-1, keepdims=True)
        rotations = np.divide(rotations, norm, out=np.tile([1.0, 0, 0, 0], rotations.shape[:-1] + (1,)),
                              where=norm > 1e-9)
    segments = (_stored_segments(meta) if _steps_are_stored(scene, meta) else
                segments_from_markers(scene, time, t0, rate, frame_start, meta.get("segments", []),
                                      source=scene.name))
    rec = Recording(name=str(meta["name"]), time=time, devices=devices, positions=stack(pos, (f, 0, 3)),
                    rotations=rotations, valid=np.stack(valid, axis=1) if valid else np.zeros((f, 0), bool),
                    marker_names=names, markers=stack(mk, (f, 0, 3)),
                    marker_valid=np.stack(mk_valid, axis=1) if mk_valid else np.zeros((f, 0), bool),
                    segments=segments, source=str(meta.get("source", "")), notes=notes)
    if not math.isfinite(rate) or rate <= 0:
        raise BodyCalError("broken frame rate in the stored recording", source=coll.name)
    return rec
