"""Calibration segments of a recording (FORMATS.md §2.4): the `segments` list of the JSON file
and the CSV sidecar, and C3D events turned into segments, checked against the recording's time
span, the calibration steps, the touch points and what may touch them."""

from __future__ import annotations

import math
import re

import numpy as np

from ..body.skeleton import FINGERS
from ..core.errors import BodyCalError, short_repr
from .model import STEPS, Segment

_SIDE = r"(l|r)"
# Touch points of FORMATS.md §2.4.
_TOUCH_POINT_RE = re.compile(
    r"^(?:"
    rf"wrist_top_{_SIDE}|wrist_bottom_{_SIDE}|mcp_(?:{'|'.join(FINGERS)})_{_SIDE}|palm_[1-9][0-9]*_{_SIDE}"
    rf"|sole_[1-9][0-9]*_{_SIDE}|ankle_in_{_SIDE}|ankle_out_{_SIDE}"
    rf"|(?:elbow|knee)_(?:in|out)_{_SIDE}|(?:shoulder|hip)_(?:front|back)_{_SIDE}"
    r"|ear_l|ear_r|upper_lip|chin|jaw_l|jaw_r|skull_top|skull_left|skull_right|skull_back|skull_base_l|skull_base_r"
    r"|sternum|chest_l|chest_r|belly_ul|belly_ur|belly_ll|belly_lr|belly_c[1-4]|back_ul|back_ur|back_low"
    r")$")
# What may touch: a fingertip, a palm centre or a controller tip (or any device / marker by name).
_TOUCH_BY_RE = re.compile(rf"^(?:(?:{'|'.join(FINGERS)})_tip_{_SIDE}|palm_{_SIDE}|controller_tip_{_SIDE})$")


def parse_segments(items, time, source, devices, marker_names) -> list[Segment]:
    """Segments from their raw list (dicts of step, start, end[, point, by]); one line naming the
    file and `segments[k]` for the first bad entry."""
    segments = []
    t0, t1 = float(time[0]), float(time[-1])
    tol = 0.5 * (float(np.median(np.diff(time))) if len(time) > 1 else 0.0) + 1e-9
    names = {d.name for d in devices} | {d.role for d in devices if d.role} | set(marker_names)
    for k, item in enumerate(items):
        fld = f"segments[{k}]"
        if not isinstance(item, dict):
            raise BodyCalError("must be an object {step, start, end[, point, by]}", source=source, field=fld)
        unknown = set(item) - {"step", "start", "end", "point", "by"}
        if unknown:
            raise BodyCalError(f"unknown field(s) {sorted(unknown)}", source=source, field=fld)
        step = item.get("step")
        if step not in STEPS:
            raise BodyCalError(f"unknown step {step!r}", source=source, field=f"{fld}.step",
                               hint=f"use one of {', '.join(STEPS)}")
        start, end = item.get("start"), item.get("end")
        for key, v in (("start", start), ("end", end)):
            if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
                raise BodyCalError(f"must be a time in seconds, got {short_repr(v)}", source=source,
                                   field=f"{fld}.{key}")
        if end <= start:
            raise BodyCalError(f"ends ({end}) before it starts ({start})", source=source, field=fld)
        if start < t0 - tol or end > t1 + tol:
            raise BodyCalError(f"{step} {start}..{end} s is outside the recording ({t0:g}..{t1:g} s)", source=source,
                               field=fld, hint="fix the segment times")
        point, by = item.get("point"), item.get("by")
        if step == "touch":
            if not isinstance(point, str) or not _TOUCH_POINT_RE.match(point):
                raise BodyCalError(f"unknown touch point {point!r}", source=source, field=f"{fld}.point",
                                   hint="see FORMATS.md §2.4 for the touch points")
        elif point is not None and not isinstance(point, str):
            raise BodyCalError("must be a string", source=source, field=f"{fld}.point")
        if by is not None and (not isinstance(by, str) or not (_TOUCH_BY_RE.match(by) or by in names)):
            raise BodyCalError(f"unknown toucher {by!r}", source=source, field=f"{fld}.by",
                               hint="a fingertip (index_tip_r), palm_<s>, controller_tip_<s> or a marker name")
        segments.append(Segment(step=step, start=float(start), end=float(end), point=point, by=by))
    return segments


# ----------------------------------------------------------------------------------------------


def check_segment(step, point, by, start, end) -> Segment:
    """A calibration step as a live source announces it or a wizard marks it, checked as a file's
    segment would be (recording/segments.py); one BodyCalError otherwise."""
    item = {"step": step, "start": start, "end": end}
    if point:
        item["point"] = point
    if by:
        item["by"] = by
    numbers = all(isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in (start, end))
    span = np.array([start, end], float) if numbers else np.zeros(2)  # else parse_segments names the bad time
    # Any name may touch here (the devices and markers of a stream are not all known yet); the
    # recorder checks the touchers again against what it recorded (recorder.py).
    return parse_segments([item], span, "segment", [], [by] if isinstance(by, str) else [])[0]
