"""Writing and reading F-Curve keys in bulk, portable across Blender 4.2 (`action.fcurves`) and
the layered, slotted actions of 4.4+ / 5.0 (`action.fcurve_ensure_for_datablock`, channelbags).

Keys go in with `keyframe_points.add(n)` + `foreach_set`, never one insertion call per key
(BLENDER_NOTES.md: 5.8 M keys/s against 11.7 k/s).
"""

from __future__ import annotations

import numpy as np

LINEAR, CONSTANT = 1, 0  # KeyframePoint.interpolation enum values (CONSTANT=0, LINEAR=1, BEZIER=2)


def _channelbag(action, obj):
    slot = obj.animation_data.action_slot if obj.animation_data else None
    if slot is None or not action.layers:
        return None
    for strip in action.layers[0].strips:
        bag = strip.channelbag(slot)
        if bag is not None:
            return bag
    return None


def new_fcurve(action, obj, data_path: str, index: int, group: str | None = None):
    """An F-Curve of `action` (already assigned to `obj`) for `data_path[index]`."""
    if hasattr(action, "fcurve_ensure_for_datablock"):  # Blender 4.4+: layered, slotted actions
        fc = action.fcurve_ensure_for_datablock(obj, data_path, index=index)
        bag = _channelbag(action, obj) if group else None
        if bag is not None:
            fc.group = bag.groups.get(group) or bag.groups.new(group)
        return fc
    if group:  # Blender 4.2 / 4.3
        return action.fcurves.new(data_path, index=index, action_group=group)
    return action.fcurves.new(data_path, index=index)


def write_keys(fc, frames32: np.ndarray, values: np.ndarray, interpolation: int = LINEAR) -> None:
    """Append one key per frame. Dense samples are keyed linearly (or constant): exact at the
    keys and no Bézier handles to compute (FCurve.update() costs more than writing the keys)."""
    n = len(frames32)
    co = np.empty(2 * n, dtype=np.float32)
    co[0::2] = frames32
    co[1::2] = values
    fc.keyframe_points.add(n)
    fc.keyframe_points.foreach_set("co", co)
    fc.keyframe_points.foreach_set("interpolation", np.full(n, interpolation, dtype=np.int32))


def read_keys(fc) -> tuple[np.ndarray, np.ndarray]:
    n = len(fc.keyframe_points)
    co = np.empty(2 * n, np.float32)
    fc.keyframe_points.foreach_get("co", co)
    return co[0::2], co[1::2]


def sample_fcurve(fc, frames: np.ndarray) -> np.ndarray:
    """The F-Curve's values at `frames`: its keys where every frame is a key (no evaluation: a
    curve passes through its keys whatever their interpolation), else one evaluation per frame
    (`FCurve.evaluate`, modifiers included; ~0.6 us a call, BLENDER_NOTES.md)."""
    kf, kv = read_keys(fc)
    if len(kf) and not fc.modifiers:
        pos = np.clip(np.searchsorted(kf, frames - 1e-3), 0, len(kf) - 1)
        if np.all(np.abs(kf[pos] - frames) < 1e-3):
            return kv[pos].astype(float)
    return np.array([fc.evaluate(float(f)) for f in frames], float)


def object_fcurves(obj) -> dict:
    """{(data_path, index): fcurve} of the object's active action, whatever the action API."""
    ad = obj.animation_data
    if ad is None or ad.action is None:
        return {}
    action = ad.action
    curves = []
    slot = getattr(ad, "action_slot", None)
    if hasattr(action, "layers") and slot is not None and len(action.layers):
        for layer in action.layers:
            for strip in layer.strips:
                bag = strip.channelbag(slot)
                if bag is not None:
                    curves.extend(bag.fcurves)
    elif hasattr(action, "fcurves"):
        curves = list(action.fcurves)
    return {(fc.data_path, fc.array_index): fc for fc in curves}


def action_bones(action) -> set[str]:
    """The pose bones `action` animates (`pose.bones["name"]...` F-Curves, in any of its slots),
    whatever the action API (4.2's `action.fcurves`; the channelbags of 4.4+ / 5.0)."""
    curves = []
    if hasattr(action, "layers") and len(action.layers):
        for layer in action.layers:
            for strip in layer.strips:
                for bag in getattr(strip, "channelbags", ()):
                    curves.extend(bag.fcurves)
    elif hasattr(action, "fcurves"):
        curves = list(action.fcurves)
    prefix = 'pose.bones["'
    return {fc.data_path[len(prefix):].split('"]', 1)[0] for fc in curves if fc.data_path.startswith(prefix)}
