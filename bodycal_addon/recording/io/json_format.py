"""The JSON reader (FORMATS.md §2.1): time, per-device poses and per-marker points, one entry per
frame (null when untracked), checked and converted to the internal frame."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ...core.errors import BodyCalError, short_repr
from ..coords import UNITS, check_positions
from ..model import Recording
from .header import TOP_FIELDS, assemble, load_json_file, parse_header


def read_json(path) -> Recording:
    """Parse a FORMATS.md §2.1 file; arrays are converted to the internal frame but not yet
    gap-filled or role-identified (see `finish_recording`)."""
    path = Path(path)
    source = path.name
    doc, has_bools = load_json_file(path, source, report_bools=True)
    header = parse_header(doc, source, TOP_FIELDS, require_frames=True)
    time = _parse_time(doc.get("time"), source, has_bools)
    f = len(time)
    devices, marker_names = header["devices"], header["marker_names"]
    poses = doc.get("poses")
    points = doc.get("points", {} if not marker_names else None)
    if not isinstance(poses, dict):
        raise BodyCalError("missing or not an object {device name: [pose per frame]}", source=source, field="poses")
    if not isinstance(points, dict):
        raise BodyCalError("missing or not an object {marker name: [point per frame]}", source=source, field="points")
    _check_keys(poses, [d.name for d in devices], source, "poses", "device")
    _check_keys(points, marker_names, source, "points", "marker")
    positions = np.zeros((f, len(devices), 3))
    rotations = np.zeros((f, len(devices), 4))
    valid = np.zeros((f, len(devices)), bool)
    for i, d in enumerate(devices):
        arr, ok = _parse_frames(poses[d.name], 7, f, source, f"poses.{d.name}", has_bools)
        positions[:, i], rotations[:, i], valid[:, i] = arr[:, :3], arr[:, 3:], ok
    markers = np.zeros((f, len(marker_names), 3))
    marker_valid = np.zeros((f, len(marker_names)), bool)
    for j, name in enumerate(marker_names):
        markers[:, j], marker_valid[:, j] = _parse_frames(points[name], 3, f, source, f"points.{name}", has_bools)
    scale = UNITS[header["coords"][2]]
    check_positions(positions, valid, scale, source, [f"poses.{d.name}" for d in devices], lambda k, _i: f"frame {k}")
    check_positions(markers, marker_valid, scale, source, [f"points.{n}" for n in marker_names],
                    lambda k, _i: f"frame {k}")
    return assemble(header, source, time, devices, positions, rotations, valid, marker_names, markers,
                    marker_valid)


def _check_keys(obj: dict, expected: list[str], source: str, fld: str, what: str) -> None:
    wanted = set(expected)  # a set: a list made this quadratic in the number of devices
    extra = [k for k in obj if k not in wanted]
    if extra:
        raise BodyCalError(f"unknown {what} '{extra[0]}'", source=source, field=fld,
                           hint=f"declare it in \"{what}s\"")
    missing = [n for n in expected if n not in obj]
    if missing:
        raise BodyCalError(f"no data for {what} '{missing[0]}'", source=source, field=fld,
                           hint="give one entry per frame (null when untracked)")


def _parse_time(values, source: str, has_bools: bool = True) -> np.ndarray:
    if not isinstance(values, list) or not values:
        raise BodyCalError("missing or empty (one time in seconds per frame)", source=source, field="time")
    if has_bools:
        _refuse_bools(values, source, "time")
    t = _numeric(values, source, "time")
    if t.ndim != 1:
        raise BodyCalError("must be a flat list of numbers", source=source, field="time")
    check_time(t, source, "time", "frame")
    return t


def check_time(t: np.ndarray, source: str, fld: str, unit: str, offset: int = 0) -> None:
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise BodyCalError(f"not a finite number: {t[bad[0]]}", source=source, field=fld,
                           where=f"{unit} {bad[0] + offset}")
    step = np.diff(t)
    bad = np.flatnonzero(step <= 0)
    if bad.size:
        k = bad[0] + 1
        raise BodyCalError(f"time must increase strictly ({t[k - 1]} then {t[k]})", source=source, field=fld,
                           where=f"{unit} {k + offset}")


def _numeric(values, source: str, fld: str) -> np.ndarray:
    try:
        arr = np.array(values)
    except (ValueError, TypeError, OverflowError):
        arr = None
    if arr is None or arr.dtype.kind not in "if":
        for k, v in enumerate(values):
            if isinstance(v, bool) or not isinstance(v, int | float):
                raise BodyCalError(f"not a number: {v!r:.40}", source=source, field=fld, where=f"frame {k}")
        raise BodyCalError("not numbers", source=source, field=fld)
    return arr.astype(float)


def _refuse_bools(values: list, source: str, fld: str) -> None:
    """numpy reads JSON true / false as 1 / 0 inside a list of numbers: refuse them by name."""
    for k, v in enumerate(values):
        row = v if isinstance(v, list) else (v,)
        if any(x is True or x is False for x in row):
            raise BodyCalError(f"not a number: {short_repr(v)}", source=source, field=fld, where=f"frame {k}",
                               hint="true / false are not numbers")


def _parse_frames(values, width: int, frames: int, source: str, fld: str,
                  has_bools: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """(F, width) floats and (F,) tracked mask from a per-frame list of [numbers] or null."""
    if not isinstance(values, list):
        raise BodyCalError("must be a list with one entry per frame", source=source, field=fld)
    if len(values) != frames:
        raise BodyCalError(f"has {len(values)} entries but time has {frames}", source=source, field=fld,
                           hint="one entry per frame, null when untracked")
    if has_bools:
        _refuse_bools(values, source, fld)
    arr = _try_block(values, width)
    if arr is None:  # dropouts (null) or bad entries: replace nulls, then locate the culprit if still bad
        nan_row = [math.nan] * width
        filled = [nan_row if v is None else v for v in values]
        arr = _try_block(filled, width)
        if arr is None:
            _raise_bad_entry(values, width, source, fld)
        ok = np.array([v is not None for v in values], bool)
    else:
        ok = np.ones(frames, bool)
    if frames == 0:
        return np.zeros((0, width)), ok
    bad = ok & ~np.isfinite(arr).all(axis=1)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise BodyCalError(f"NaN or infinite value {values[k]}", source=source, field=fld, where=f"frame {k}",
                           hint="write null for an untracked frame")
    arr = np.where(ok[:, None], arr, 0.0)
    return arr, ok


def _try_block(values, width):
    try:
        arr = np.array(values)
    except (ValueError, TypeError, OverflowError):
        return None
    if arr.dtype.kind not in "if" or arr.ndim != 2 or arr.shape[1] != width:
        return None
    return arr.astype(float)


def _raise_bad_entry(values, width, source, fld):
    for k, v in enumerate(values):
        if v is None:
            continue
        if not isinstance(v, list) or len(v) != width:
            raise BodyCalError(f"expected a list of {width} numbers or null, got {short_repr(v)}", source=source,
                               field=fld, where=f"frame {k}")
        for x in v:
            if isinstance(x, bool) or not isinstance(x, int | float):
                raise BodyCalError(f"not a number: {short_repr(x)}", source=source, field=fld, where=f"frame {k}")
            if isinstance(x, int) and abs(x) > 1e300:
                raise BodyCalError("number out of range", source=source, field=fld, where=f"frame {k}")
    raise BodyCalError("unreadable values", source=source, field=fld)
