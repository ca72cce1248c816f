"""Read and write tracker recordings (FORMATS.md §2): JSON, CSV + sidecar, C3D.

Everything is converted ONCE, at load, to the internal frame (Blender's: right-handed, Z up,
metres). Conventions of the files (`coords`):

- `up="Y", handedness="right"` (SteamVR / OpenXR: x right, y up, -z forward): (x, y, z) -> (x, -z, y),
  a +90 degree turn about X, so the performer's forward (-z) becomes +Y.
- `up="Y", handedness="left"` (Unity: x right, y up, +z forward): (x, y, z) -> (x, z, y); the same
  physical scene lands where the SteamVR one does.
- `up="Z", handedness="right"`: unchanged. `up="Z", handedness="left"` (Unreal: x forward, y right,
  z up): (x, y, z) -> (x, -y, z).
- units `m`, `cm`, `mm` scale positions.

Device rotations: world positions go through the conversion matrix M; device-local frames keep
the OpenXR / Blender-camera convention (x right, y up, -z forward), so R' = M R for right-handed
files. A left-handed file also has left-handed device frames: they are mirrored along their local
z (R' = M R P, P = diag(1, 1, -1)) so that local -z stays the device's forward. A device-local point
l (with l' = P l) therefore maps to the same world point before and after conversion.

After reading, every recording goes through `finish_recording`: quaternions renormalised (within
1e-3) or rejected, untracked frames kept as invalid (their values hold the last tracked value so
that arrays never carry NaN), short gaps filled (linear / slerp), hand frames built from the LED
glove markers, and missing roles identified from the `tpose` segment (roles.py). What was done is
reported in `Recording.notes`.
"""

from __future__ import annotations

import io
import json
import math
import re
import warnings
from pathlib import Path

import numpy as np

from . import transforms as tf
from .errors import BodyCalError
from .recording import DEVICE_KINDS, ROLES, STEPS, Device, Recording, Segment

FORMAT_NAME = "bodycal-recording"
UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
UPS = ("Y", "Z")
HANDEDNESS = ("right", "left")
QUAT_TOLERANCE = 1e-3  # FORMATS.md §1: renormalise within 1e-3, reject beyond
DEFAULT_FILL_GAPS_S = 0.1
MAX_POSITION_M = 1e4  # FORMATS.md §1: a position 10 km or more from the origin is a damaged value

_AXIS_MAPS = {
    ("Y", "right"): np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]),
    ("Y", "left"): np.array([[1.0, 0, 0], [0, 0, 1], [0, 1, 0]]),
    ("Z", "right"): np.eye(3),
    ("Z", "left"): np.diag([1.0, -1.0, 1.0]),
}
_LOCAL_MIRROR = np.diag([1.0, 1.0, -1.0])

FINGERS = ("thumb", "index", "middle", "ring", "pinky")
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
LED_NAMES = tuple(f"hand_led{i}" for i in (1, 2, 3))


# ----------------------------------------------------------------------------------------------
# Coordinate conventions


def check_coords(coords, source: str) -> tuple[str, str, str]:
    """(up, handedness, units) from a `coords` object, with the FORMATS.md defaults."""
    if coords is None:
        coords = {}
    if not isinstance(coords, dict):
        raise BodyCalError("must be an object like {\"up\": \"Y\", \"handedness\": \"right\", \"units\": \"m\"}",
                           source=source, field="coords")
    unknown = set(coords) - {"up", "handedness", "units"}
    if unknown:
        raise BodyCalError(f"unknown field(s) {sorted(unknown)}", source=source, field="coords",
                           hint="allowed: up, handedness, units")
    up = coords.get("up", "Y")
    hand = coords.get("handedness", "right")
    units = coords.get("units", "m")
    if not isinstance(up, str) or up.upper() not in UPS:
        raise BodyCalError(f"'{up}' is not an up axis", source=source, field="coords.up", hint="use \"Y\" or \"Z\"")
    if not isinstance(hand, str) or hand.lower() not in HANDEDNESS:
        raise BodyCalError(f"'{hand}' is not a handedness", source=source, field="coords.handedness",
                           hint="use \"right\" or \"left\"")
    if not isinstance(units, str) or units.lower() not in UNITS:
        raise BodyCalError(f"'{units}' is not a unit", source=source, field="coords.units",
                           hint="use \"m\", \"cm\" or \"mm\"")
    return up.upper(), hand.lower(), units.lower()


def conversion(up: str, handedness: str, units: str) -> tuple[np.ndarray, np.ndarray]:
    """(M, P): internal = scale * M @ file for points; R_internal = M R_file P for device frames."""
    m = _AXIS_MAPS[(up, handedness)] * UNITS[units]
    p = _LOCAL_MIRROR if handedness == "left" else np.eye(3)
    return m, p


def to_internal(positions: np.ndarray, rotations: np.ndarray | None, up="Y", handedness="right", units="m"):
    """Convert positions (..., 3) and rotations (..., 4) from a file convention to the internal frame."""
    m, p = conversion(up, handedness, units)
    pos = np.asarray(positions, float) @ m.T
    if rotations is None:
        return pos, None
    rot = _convert_rotations(np.asarray(rotations, float), m / UNITS[units], p)
    return pos, rot


def from_internal(positions: np.ndarray, rotations: np.ndarray | None, up="Y", handedness="right", units="m"):
    """Inverse of `to_internal`."""
    m, p = conversion(up, handedness, units)
    minv = np.linalg.inv(m)
    pos = np.asarray(positions, float) @ minv.T
    if rotations is None:
        return pos, None
    a = m / UNITS[units]
    rot = _convert_rotations(np.asarray(rotations, float), a.T, p)  # R = A^T R' P (A, P orthogonal, P = P^T)
    return pos, rot


def _convert_rotations(q: np.ndarray, a: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Quaternions of A R P (A, P orthogonal, det(A P) = +1), by quaternion products only, so that
    the sign of the input (and the continuity of a track) is kept."""
    q = np.array(q, float)
    if np.linalg.det(p) < 0:
        # A R P = (A P)(P R P); for the mirror P = diag(1, 1, -1), P R P = (-P) R (-P)^-1 with -P a half
        # turn about z, whose quaternion keeps w and turns the vector part: (w, -x, -y, z).
        q *= np.array([1.0, -1.0, -1.0, 1.0])
        a = a @ p
    if np.allclose(a, np.eye(3)):
        return q
    return tf.quat_mul(tf.matrix_to_quat(a), q)


def check_positions(values: np.ndarray, valid: np.ndarray, unit_scale: float, source: str, fields, where_of) -> None:
    """Refuse a tracked position (file units, (F, N, 3)) at MAX_POSITION_M or more from the origin
    once in metres: one line naming the file, `fields[n]` and `where_of(frame, n)`. Compared in the
    file's units, so no arithmetic ever runs on the absurd value (no overflow warnings)."""
    if values.size == 0:
        return
    limit = MAX_POSITION_M / unit_scale
    with np.errstate(invalid="ignore"):
        bad = valid & ~(np.abs(values) < limit).all(axis=-1)
    if bad.any():
        f, i = (int(x) for x in np.argwhere(bad)[0])
        raise BodyCalError(f"position {_short(values[f, i].tolist())} is {MAX_POSITION_M:g} m or more from the origin",
                           source=source, field=fields[i], where=where_of(f, i),
                           hint="positions are in the declared units from the room's origin; the value is damaged")


# ----------------------------------------------------------------------------------------------
# Public entry points


def load_recording(path, *, fill_gaps_s: float = DEFAULT_FILL_GAPS_S, identify_roles: bool = True) -> Recording:
    """Read a recording (.bcrec.json / .json, .csv with an optional `name.json` sidecar, .c3d) into
    the internal frame. Raises BodyCalError (one line naming file, field, frame/line) on bad input."""
    path = Path(path)
    source = path.name
    if not path.is_file():
        raise BodyCalError("file not found", source=str(path))
    suffix = path.suffix.lower()
    if suffix == ".json":
        rec = read_json(path)
    elif suffix == ".csv":
        rec = read_csv(path)
    elif suffix == ".c3d":
        from . import c3d

        rec = c3d.read_c3d_recording(path)
    else:
        raise BodyCalError(f"unknown recording type '{suffix}'", source=source,
                           hint="use .bcrec.json, .json, .csv or .c3d")
    return finish_recording(rec, fill_gaps_s=fill_gaps_s, identify_roles=identify_roles)


def save_recording(rec: Recording, path, *, up: str = "Y", handedness: str = "right", units: str = "m") -> list[Path]:
    """Write `rec` as JSON (FORMATS.md §2.1), or as CSV + sidecar JSON (§2.2) for a .csv path, in the
    declared convention. Untracked frames are written as null / empty fields. Returns the files written."""
    path = Path(path)
    up, handedness, units = check_coords({"up": up, "handedness": handedness, "units": units}, str(path))
    header = _header(rec, up, handedness, units)
    pos, rot = from_internal(rec.positions, rec.rotations, up, handedness, units)
    mk, _ = from_internal(rec.markers, None, up, handedness, units)
    if path.suffix.lower() == ".csv":
        sidecar = path.with_suffix(".json")
        sidecar.write_text(json.dumps(header, indent=1))
        _write_csv(path, rec, pos, rot, mk)
        return [path, sidecar]
    doc = dict(header)
    doc["time"] = np.round(rec.time, 9).tolist()
    doc["poses"] = {}
    for i, d in enumerate(rec.devices):
        rows = np.concatenate([np.round(pos[:, i], 7), np.round(rot[:, i], 8)], axis=1).tolist()
        for f in np.flatnonzero(~rec.valid[:, i]):
            rows[f] = None
        doc["poses"][d.name] = rows
    doc["points"] = {}
    for j, name in enumerate(rec.marker_names):
        rows = np.round(mk[:, j], 7).tolist()
        for f in np.flatnonzero(~rec.marker_valid[:, j]):
            rows[f] = None
        doc["points"][name] = rows
    path.write_text(json.dumps(doc, separators=(",", ":")))
    return [path]


def _header(rec: Recording, up, handedness, units) -> dict:
    segs = []
    for s in rec.segments:
        d = {"step": s.step, "start": float(s.start), "end": float(s.end)}
        if s.point:
            d["point"] = s.point
        if s.by:
            d["by"] = s.by
        segs.append(d)
    return {
        "format": FORMAT_NAME,
        "version": 1,
        "name": rec.name,
        "coords": {"up": up, "handedness": handedness, "units": units},
        "devices": [{"name": d.name, "kind": d.kind, "role": d.role} for d in rec.devices],
        "markers": [{"name": n} for n in rec.marker_names],
        "segments": segs,
    }


def _write_csv(path: Path, rec: Recording, pos, rot, mk) -> None:
    """The same numbers as the JSON writer (times to 1e-9 s, positions to 1e-7, quaternions to
    1e-8), each written as the shortest text that reads back to that float: a recording saved as
    CSV and as JSON loads back identical (a touch held for exactly its minimum time stayed exactly
    that long in one and a few nanoseconds short in the other)."""
    lines = ["time,name,px,py,pz,qw,qx,qy,qz"]
    times = [repr(t) for t in np.round(rec.time, 9).tolist()]
    dev_cells = []
    for i, d in enumerate(rec.devices):
        block = np.concatenate([np.round(pos[:, i], 7), np.round(rot[:, i], 8)], axis=1)
        cells = [",".join(map(repr, row)) for row in block.tolist()]
        dev_cells.append((d.name, cells, rec.valid[:, i]))
    mk_cells = []
    for j, name in enumerate(rec.marker_names):
        cells = [",".join(map(repr, row)) + ",,,," for row in np.round(mk[:, j], 7).tolist()]
        mk_cells.append((name, cells, rec.marker_valid[:, j]))
    for f, t in enumerate(times):
        for name, cells, valid in dev_cells:
            lines.append(f"{t},{name},{cells[f]}" if valid[f] else f"{t},{name},,,,,,,")
        for name, cells, valid in mk_cells:
            if valid[f]:
                lines.append(f"{t},{name},{cells[f]}")
    path.write_text("\n".join(lines) + "\n")


# ----------------------------------------------------------------------------------------------
# JSON

_TOP_FIELDS = {"format", "version", "coords", "devices", "markers", "time", "poses", "points", "segments", "name",
               "extra"}
_SIDECAR_FIELDS = _TOP_FIELDS - {"time", "poses", "points"}


def _load_json_file(path: Path, source: str, report_bools: bool = False):
    """The parsed document (and, with `report_bools`, whether the text holds `true` / `false` at all:
    only then do the per-frame arrays need the slower look for booleans posing as numbers)."""
    try:
        text = path.read_bytes().decode("utf-8")
    except UnicodeDecodeError as exc:
        raise BodyCalError(f"not UTF-8 text (byte {exc.start})", source=source) from None
    except OSError as exc:
        raise BodyCalError(f"cannot read: {exc.strerror}", source=source) from None
    try:
        doc = json.loads(text)
    except json.JSONDecodeError as exc:
        raise BodyCalError(f"invalid JSON: {exc.msg}", source=source, where=f"line {exc.lineno} column {exc.colno}",
                           hint="is the file complete?") from None
    except RecursionError:
        raise BodyCalError("invalid JSON: nested too deeply", source=source) from None
    if report_bools:
        return doc, "true" in text or "false" in text
    return doc


def read_json(path) -> Recording:
    """Parse a FORMATS.md §2.1 file; arrays are converted to the internal frame but not yet
    gap-filled or role-identified (see `finish_recording`)."""
    path = Path(path)
    source = path.name
    doc, has_bools = _load_json_file(path, source, report_bools=True)
    header = _parse_header(doc, source, _TOP_FIELDS, require_frames=True)
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
    return _assemble(header, source, time, devices, positions, rotations, valid, marker_names, markers,
                     marker_valid)


def _assemble(header, source, time, devices, positions, rotations, valid, marker_names, markers, marker_valid):
    up, hand, units = header["coords"]
    _check_quaternions(rotations, valid, time, devices, source)
    positions, rotations = to_internal(positions, rotations, up, hand, units)
    markers, _ = to_internal(markers, None, up, hand, units)
    segments = _parse_segments(header["segments_raw"], time, source, devices, marker_names)
    rec = Recording(name=header["name"] or Path(source).name.split(".")[0], time=time, devices=devices,
                    positions=positions, rotations=rotations, valid=valid, marker_names=marker_names,
                    markers=markers, marker_valid=marker_valid, segments=segments, source=source)
    if (up, hand, units) != ("Z", "right", "m"):
        rec.notes.append(f"converted from {up} up, {hand}-handed, {units} to Z up, right-handed, metres")
    return rec


def _parse_header(doc, source: str, allowed: set, require_frames: bool) -> dict:
    if not isinstance(doc, dict):
        raise BodyCalError("the file must hold a JSON object", source=source, hint="see FORMATS.md §2.1")
    unknown = set(doc) - allowed
    if unknown:
        raise BodyCalError(f"unknown field(s) {sorted(unknown)}", source=source,
                           hint=f"allowed: {', '.join(sorted(allowed))}")
    fmt = doc.get("format")
    if fmt != FORMAT_NAME:
        raise BodyCalError(f"is {fmt!r}, expected \"{FORMAT_NAME}\"", source=source, field="format")
    version = doc.get("version")
    if version != 1 or isinstance(version, bool):
        raise BodyCalError(f"unsupported version {version!r}", source=source, field="version",
                           hint="this reader reads 1")
    name = doc.get("name")
    if name is not None and not isinstance(name, str):
        raise BodyCalError("must be a string", source=source, field="name")
    coords = check_coords(doc.get("coords"), source)
    devices = _parse_devices(doc.get("devices", []), source)
    marker_names = _parse_markers(doc.get("markers", []), source)
    dup = set(d.name for d in devices) & set(marker_names)
    if dup:
        raise BodyCalError(f"'{sorted(dup)[0]}' is both a device and a marker", source=source, field="markers",
                           hint="names must be unique")
    segs = doc.get("segments", [])
    if not isinstance(segs, list):
        raise BodyCalError("must be a list", source=source, field="segments")
    return {"name": name, "coords": coords, "devices": devices, "marker_names": marker_names, "segments_raw": segs}


def _parse_devices(items, source: str) -> list[Device]:
    if not isinstance(items, list):
        raise BodyCalError("must be a list of {name, kind, role}", source=source, field="devices")
    devices, roles, seen = [], {}, set()
    for k, item in enumerate(items):
        fld = f"devices[{k}]"
        if not isinstance(item, dict):
            raise BodyCalError("must be an object {name, kind, role}", source=source, field=fld)
        unknown = set(item) - {"name", "kind", "role", "extra"}
        if unknown:
            raise BodyCalError(f"unknown field(s) {sorted(unknown)}", source=source, field=fld)
        name, kind, role = item.get("name"), item.get("kind"), item.get("role")
        if not isinstance(name, str) or not name.strip():
            raise BodyCalError("missing or empty name", source=source, field=f"{fld}.name")
        if kind not in DEVICE_KINDS:
            raise BodyCalError(f"unknown kind {kind!r}", source=source, field=f"{fld}.kind",
                               hint=f"use one of {', '.join(DEVICE_KINDS)}")
        if role is not None and role not in ROLES:
            raise BodyCalError(f"unknown role {role!r}", source=source, field=f"{fld}.role",
                               hint=f"use null or one of {', '.join(ROLES)}")
        if name in seen:
            raise BodyCalError(f"duplicate device name '{name}'", source=source, field=f"{fld}.name")
        if role is not None and role in roles:
            raise BodyCalError(f"role '{role}' is given to both '{roles[role]}' and '{name}'", source=source,
                               field=f"{fld}.role")
        if role is not None:
            roles[role] = name
        seen.add(name)
        devices.append(Device(name=name, kind=kind, role=role))
    return devices


def _parse_markers(items, source: str) -> list[str]:
    if not isinstance(items, list):
        raise BodyCalError("must be a list of {name}", source=source, field="markers")
    names, seen = [], set()
    for k, item in enumerate(items):
        fld = f"markers[{k}]"
        if not isinstance(item, dict):
            raise BodyCalError("must be an object {name}", source=source, field=fld)
        unknown = set(item) - {"name", "extra"}
        if unknown:
            raise BodyCalError(f"unknown field(s) {sorted(unknown)}", source=source, field=fld)
        name = item.get("name")
        if not isinstance(name, str) or not name.strip():
            raise BodyCalError("missing or empty name", source=source, field=f"{fld}.name")
        if name in seen:
            raise BodyCalError(f"duplicate marker name '{name}'", source=source, field=f"{fld}.name")
        seen.add(name)
        names.append(name)
    return names


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
            raise BodyCalError(f"not a number: {_short(v)}", source=source, field=fld, where=f"frame {k}",
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
            raise BodyCalError(f"expected a list of {width} numbers or null, got {_short(v)}", source=source,
                               field=fld, where=f"frame {k}")
        for x in v:
            if isinstance(x, bool) or not isinstance(x, int | float):
                raise BodyCalError(f"not a number: {_short(x)}", source=source, field=fld, where=f"frame {k}")
            if isinstance(x, int) and abs(x) > 1e300:
                raise BodyCalError("number out of range", source=source, field=fld, where=f"frame {k}")
    raise BodyCalError("unreadable values", source=source, field=fld)


def _short(v) -> str:
    s = repr(v)
    return s if len(s) <= 40 else s[:37] + "..."


def _check_quaternions(rotations, valid, time, devices, source, unit="frame", where_of=None):
    """Renormalise quaternions within QUAT_TOLERANCE of unit length, reject the others (in place)."""
    if rotations.size == 0:
        return
    with np.errstate(over="ignore", invalid="ignore"):  # a damaged 1e300 component: refused below, no warning
        norm = np.linalg.norm(rotations, axis=-1)
        bad = valid & ~(np.abs(norm - 1.0) <= QUAT_TOLERANCE)
    if bad.any():
        f, i = (int(x) for x in np.argwhere(bad)[0])
        what = "zero" if norm[f, i] < 1e-9 else f"not unit length (|q| = {norm[f, i]:.6g})"
        where = where_of(f, i) if where_of else f"{unit} {f}"
        raise BodyCalError(f"quaternion is {what}", source=source, field=f"poses.{devices[i].name}", where=where,
                           hint="write w, x, y, z of a unit quaternion")
    ok = valid & (norm > 0)
    rotations[ok] /= norm[ok][:, None]
    rotations[~valid] = (1.0, 0.0, 0.0, 0.0)


def _parse_segments(items, time, source, devices, marker_names) -> list[Segment]:
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
                raise BodyCalError(f"must be a time in seconds, got {_short(v)}", source=source, field=f"{fld}.{key}")
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
# CSV

_CSV_COLUMNS = ("time", "name", "px", "py", "pz", "qw", "qx", "qy", "qz")


def read_csv(path) -> Recording:
    """Parse a FORMATS.md §2.2 long-format CSV (+ `name.json` sidecar when present)."""
    path = Path(path)
    source = path.name
    sidecar = path.with_suffix(".json")
    if sidecar.is_file():
        header = _parse_header(_load_json_file(sidecar, sidecar.name), sidecar.name, _SIDECAR_FIELDS,
                               require_frames=False)
    else:
        header = {"name": None, "coords": ("Y", "right", "m"), "devices": None, "marker_names": None,
                  "segments_raw": []}
    chunks = _csv_chunks(path, source)
    lines = next(chunks, [])
    if not lines or not lines[0].strip():
        raise BodyCalError("empty file; the header line time,name,px,py,pz,qw,qx,qy,qz is required", source=source,
                           where="line 1")
    cols = [c.strip().lower() for c in lines[0].split(",")]
    unknown = [c for c in cols if c not in _CSV_COLUMNS]
    if unknown:
        raise BodyCalError(f"unknown column '{unknown[0]}'", source=source, where="line 1",
                           hint="columns are time,name,px,py,pz,qw,qx,qy,qz")
    for c in cols:
        if cols.count(c) > 1:
            raise BodyCalError(f"duplicate column '{c}'", source=source, where="line 1")
    missing = [c for c in _CSV_COLUMNS[:5] if c not in cols]
    has_q = [c in cols for c in _CSV_COLUMNS[5:]]
    if any(has_q) and not all(has_q):
        missing += [c for c, h in zip(_CSV_COLUMNS[5:], has_q) if not h]
    if missing:
        raise BodyCalError(f"missing column '{missing[0]}'", source=source, where="line 1",
                           hint="columns are time,name,px,py,pz,qw,qx,qy,qz")
    line_no, uniq, name_idx, t_rows, p_vals, q_vals = _csv_rows(path, lines, chunks, cols, has_q, source)
    del lines
    p_set, q_set = ~np.isnan(p_vals), ~np.isnan(q_vals)  # empty cells; written nan / inf were refused
    empty_name = [k for k, u in enumerate(uniq) if u == ""]
    if empty_name:
        k = int(np.flatnonzero(name_idx == empty_name[0])[0])
        raise BodyCalError("empty name", source=source, field="name", where=f"line {line_no[k]}")
    bad = np.flatnonzero(~np.isfinite(t_rows))
    if bad.size:
        raise BodyCalError("not a finite number", source=source, field="time", where=f"line {line_no[bad[0]]}")
    back = np.flatnonzero(np.diff(t_rows) < 0)
    if back.size:
        raise BodyCalError(f"time goes back ({t_rows[back[0]]} then {t_rows[back[0] + 1]})", source=source,
                           field="time", where=f"line {line_no[back[0] + 1]}",
                           hint="rows must be sorted by time, strictly increasing between frames")
    new_frame = np.concatenate([[True], np.diff(t_rows) > 0])
    frame_of_row = np.cumsum(new_frame) - 1
    time = t_rows[new_frame]
    f = len(time)
    partial_p = p_set.any(1) & ~p_set.all(1)
    partial_q = q_set.any(1) & ~q_set.all(1)
    bad = np.flatnonzero(partial_p | partial_q)
    if bad.size:
        raise BodyCalError("some fields of the pose are empty, others not", source=source,
                           where=f"line {line_no[bad[0]]}", hint="leave all fields empty for an untracked frame")
    bad = np.flatnonzero(q_set.all(1) & ~p_set.all(1))
    if bad.size:
        raise BodyCalError("quaternion without a position", source=source, where=f"line {line_no[bad[0]]}")
    finite = np.isfinite(p_vals).all(1) & np.isfinite(q_vals).all(1)
    bad = np.flatnonzero((p_set.all(1) & ~np.isfinite(p_vals).all(1)) | (q_set.all(1) & ~finite))
    if bad.size:
        raise BodyCalError("NaN or infinite value", source=source, where=f"line {line_no[bad[0]]}",
                           hint="leave the fields empty for an untracked frame")
    check_positions(p_vals[:, None], p_set.all(1)[:, None], UNITS[header["coords"][2]], source,
                    ["px,py,pz"], lambda k, _i, lines=line_no: f"line {lines[k]}")

    is_pose_row = q_set.all(1)
    if header["devices"] is None:  # no sidecar: names with a quaternion anywhere are trackers
        dev_mask = np.zeros(len(uniq), bool)
        dev_mask[name_idx[is_pose_row]] = True
        devices = [Device(name=u, kind="tracker", role=None) for k, u in enumerate(uniq) if dev_mask[k]]
        marker_names = [u for k, u in enumerate(uniq) if not dev_mask[k]]
        header = dict(header, devices=devices, marker_names=marker_names)
    devices, marker_names = header["devices"], header["marker_names"]
    slot = {d.name: ("d", i) for i, d in enumerate(devices)}
    slot.update({n: ("m", j) for j, n in enumerate(marker_names)})
    kind_of = np.array([{"d": 0, "m": 1, "?": 2}[slot.get(u, ("?", -1))[0]] for u in uniq], np.int8)
    index_of = np.array([slot.get(u, ("?", -1))[1] for u in uniq], dtype=np.int64)
    row_kind = kind_of[name_idx]  # one byte a row: 0 device, 1 marker, 2 undeclared
    bad = np.flatnonzero(row_kind == 2)
    if bad.size:
        raise BodyCalError(f"unknown name '{uniq[name_idx[bad[0]]]}'", source=source, field="name",
                           where=f"line {line_no[bad[0]]}", hint=f"declare it in {sidecar.name}")
    bad = np.flatnonzero((row_kind == 0) & p_set.all(1) & ~q_set.all(1))
    if bad.size:
        raise BodyCalError(f"device '{uniq[name_idx[bad[0]]]}' has no quaternion", source=source,
                           where=f"line {line_no[bad[0]]}")
    bad = np.flatnonzero((row_kind == 1) & q_set.any(1))
    if bad.size:
        raise BodyCalError(f"marker '{uniq[name_idx[bad[0]]]}' has a quaternion", source=source,
                           where=f"line {line_no[bad[0]]}", hint="marker rows leave qw,qx,qy,qz empty")
    # One row per name and frame.
    key = frame_of_row * len(uniq) + name_idx
    order = np.argsort(key, kind="stable")
    dup = np.flatnonzero(np.diff(key[order]) == 0)
    if dup.size:
        k = order[dup[0] + 1]
        raise BodyCalError(f"second row for '{uniq[name_idx[k]]}' at time {t_rows[k]}", source=source,
                           where=f"line {line_no[k]}")
    del key, order, dup

    row_index = index_of[name_idx]
    positions = np.zeros((f, len(devices), 3))
    rotations = np.tile(np.array([1.0, 0, 0, 0]), (f, len(devices), 1))
    valid = np.zeros((f, len(devices)), bool)
    d_rows = (row_kind == 0) & is_pose_row
    positions[frame_of_row[d_rows], row_index[d_rows]] = p_vals[d_rows]
    rotations[frame_of_row[d_rows], row_index[d_rows]] = q_vals[d_rows]
    valid[frame_of_row[d_rows], row_index[d_rows]] = True
    markers = np.zeros((f, len(marker_names), 3))
    marker_valid = np.zeros((f, len(marker_names)), bool)
    m_rows = (row_kind == 1) & p_set.all(1)
    markers[frame_of_row[m_rows], row_index[m_rows]] = p_vals[m_rows]
    marker_valid[frame_of_row[m_rows], row_index[m_rows]] = True
    # The line of each device's row per frame (4 bytes a row); the per-row arrays go before the
    # conversion so that they and its copies are never all held at once.
    frame_lines = line_no[new_frame]
    dev_line = np.zeros((f, len(devices)), np.int32)
    dev_line[frame_of_row[d_rows], row_index[d_rows]] = line_no[d_rows]
    del line_no, name_idx, t_rows, p_vals, q_vals, p_set, q_set, row_kind, row_index, frame_of_row, d_rows, m_rows
    del new_frame, is_pose_row, partial_p, partial_q, finite, bad

    def where_of(frame, dev):
        return f"line {dev_line[frame, dev] or frame_lines[frame]}"

    _check_quaternions(rotations, valid, time, devices, source, where_of=where_of)
    rec = _assemble_converted(header, source, time, devices, positions, rotations, valid, marker_names, markers,
                              marker_valid)
    if not sidecar.is_file():
        rec.notes.append(f"no sidecar {sidecar.name}: assumed Y up, right-handed, metres, "
                         f"{len(devices)} trackers without roles, {len(marker_names)} markers, no segments")
    return rec


_CSV_CHUNK_BYTES = 1 << 20  # text parsed at a time: the file is never held whole, as bytes or as text


def _csv_chunks(path: Path, source: str):
    """The file's lines (str.splitlines, as for the whole text), a chunk of about _CSV_CHUNK_BYTES at
    a time; chunks end at a \\n, which is a line break however the lines are counted."""
    offset = 0
    with path.open("rb") as fh:
        while True:
            blob = b"".join(fh.readlines(_CSV_CHUNK_BYTES))
            if not blob:
                return
            try:
                text = blob.decode("utf-8-sig" if offset == 0 else "utf-8")
            except UnicodeDecodeError as exc:
                raise BodyCalError(f"not UTF-8 text (byte {offset + exc.start})", source=source) from None
            offset += len(blob)
            del blob
            yield text.splitlines()


def _count_lines(path: Path) -> int:
    n = 1
    with path.open("rb") as fh:
        for block in iter(lambda: fh.read(_CSV_CHUNK_BYTES), b""):
            n += block.count(b"\n")
    return n


def _csv_rows(path: Path, first: list[str], chunks, cols: list[str], has_q: list[bool], source: str):
    """Parse every data row, chunk by chunk, into arrays allocated once for the file's line count:
    (line numbers, unique stripped names, name index per row, time, positions, quaternions), empty
    cells NaN. Per row 72 bytes, less than the row's text; names are held once each."""
    n_max = _count_lines(path)
    line_no = np.empty(n_max, np.int32 if n_max < 2 ** 31 else np.int64)
    name_idx = np.empty(n_max, np.int32)
    t_rows = np.empty(n_max)
    p_vals = np.empty((n_max, 3))
    q_vals = np.empty((n_max, 4))
    uniq: list[str] = []
    slot: dict[str, int] = {}  # stripped name -> index in uniq
    lookup: dict[str, int] = {}  # name as written -> index in uniq
    rows, body, first_line = 0, first[1:], 2
    while True:
        parsed = _csv_fast(body, cols, first_line) if all(has_q) else None
        if parsed is None:
            parsed = _csv_slow(body, cols, has_q, source, first_line)
        ln, names, t, p, _p_set, q, _q_set = parsed
        for raw in dict.fromkeys(names):  # in order of first appearance (the devices' order without a sidecar)
            if raw not in lookup:
                lookup[raw] = slot.setdefault(raw.strip(), len(slot))
                if lookup[raw] == len(uniq):
                    uniq.append(raw.strip())
        k = len(ln)
        if rows + k > n_max:  # cannot happen (splitlines finds at least the \n breaks); never silently
            raise BodyCalError("more rows than lines", source=source)
        line_no[rows:rows + k] = ln
        name_idx[rows:rows + k] = np.fromiter(map(lookup.__getitem__, names), np.int32, count=k)
        t_rows[rows:rows + k], p_vals[rows:rows + k], q_vals[rows:rows + k] = t, p, q
        rows += k
        first_line += len(body)
        body = next(chunks, None)
        if body is None:
            break
    if rows == 0:
        raise BodyCalError("no data rows after the header", source=source, where="line 2")
    return line_no[:rows], uniq, name_idx[:rows], t_rows[:rows], p_vals[:rows], q_vals[:rows]


def _csv_fast(body: list[str], cols: list[str], first_line: int = 2):
    """The common case at C speed (numpy's loadtxt parser): standard column order, no blank lines,
    no written nan/inf. Returns None whenever anything is unusual; the careful path then finds it.
    The name column is split off in Python (a fixed-width numpy string column cost 512 bytes a
    row); loadtxt reads only the numbers."""
    if cols != list(_CSV_COLUMNS) or not body or not all(body):
        return None
    n = len(body)
    commas = len(cols) - 1
    if not all(ln.count(",") == commas for ln in body):  # loadtxt with usecols would let a row differ
        return None
    text = "\n".join(body)
    low = text.lower()
    if "nan" in low or "inf" in low or "#" in text:
        return None  # written nan / inf are errors, told apart from empty cells by the careful path
    filled = text.replace(",,", ",nan,").replace(",,", ",nan,").replace(",\n", ",nan\n")
    if filled.endswith(","):
        filled += "nan"
    if filled.startswith(",") or "\n," in filled:
        return None  # an empty time
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            vals = np.loadtxt(io.StringIO(filled), delimiter=",", dtype=float, comments=None, ndmin=2,
                              usecols=(0, 2, 3, 4, 5, 6, 7, 8), quotechar=None)
    except (ValueError, TypeError, OverflowError):
        return None
    del filled, low, text
    if vals.shape != (n, 8):
        return None
    names = [ln.split(",", 2)[1] for ln in body]
    if "" in names:
        return None  # an empty name cell: the careful path reports it
    is_set = ~np.isnan(vals)
    line_no = np.arange(first_line, first_line + n, dtype=np.int64)
    return line_no, names, vals[:, 0], vals[:, 1:4], is_set[:, 1:4], vals[:, 4:8], is_set[:, 4:8]


def _csv_slow(body: list[str], cols: list[str], has_q: list[bool], source: str, first_line: int = 2):
    # Keep the line numbers of the file (1-based; the header is line 1), skip blank lines.
    line_no = np.array([k + first_line for k, ln in enumerate(body) if ln.strip()], dtype=np.int64)
    rows = [ln.split(",") for ln in body if ln.strip()]
    if not rows:  # blank lines only in this chunk; a file without any row is refused by the caller
        empty = np.zeros((0, 3)), np.zeros((0, 3), bool), np.zeros((0, 4)), np.zeros((0, 4), bool)
        return line_no, [], np.zeros(0), *empty
    ncol = len(cols)
    lens = np.fromiter((len(r) for r in rows), dtype=np.int64, count=len(rows))
    bad = np.flatnonzero(lens != ncol)
    if bad.size:
        k = bad[0]
        raise BodyCalError(f"{lens[k]} fields, the header has {ncol}", source=source, where=f"line {line_no[k]}")
    columns = dict(zip(cols, zip(*rows)))
    t_rows = _csv_floats(columns["time"], source, "time", line_no, allow_empty=False)[0]
    xyz = [_csv_floats(columns[c], source, c, line_no) for c in ("px", "py", "pz")]
    p_vals = np.stack([v for v, _ in xyz], axis=1)
    p_set = np.stack([s for _, s in xyz], axis=1)
    if all(has_q):
        qs = [_csv_floats(columns[c], source, c, line_no) for c in ("qw", "qx", "qy", "qz")]
        q_vals = np.stack([v for v, _ in qs], axis=1)
        q_set = np.stack([s for _, s in qs], axis=1)
    else:
        q_vals = np.full((len(rows), 4), np.nan)
        q_set = np.zeros((len(rows), 4), bool)
    return line_no, [c.strip() for c in columns["name"]], t_rows, p_vals, p_set, q_vals, q_set


def _assemble_converted(header, source, time, devices, positions, rotations, valid, marker_names, markers,
                        marker_valid):
    # Quaternions were already checked (with CSV line numbers); skip the second check.
    up, hand, units = header["coords"]
    positions, rotations = to_internal(positions, rotations, up, hand, units)
    markers, _ = to_internal(markers, None, up, hand, units)
    segments = _parse_segments(header["segments_raw"], time, source, devices, marker_names)
    rec = Recording(name=header["name"] or Path(source).name.split(".")[0], time=time, devices=devices,
                    positions=positions, rotations=rotations, valid=valid, marker_names=marker_names,
                    markers=markers, marker_valid=marker_valid, segments=segments, source=source)
    if (up, hand, units) != ("Z", "right", "m"):
        rec.notes.append(f"converted from {up} up, {hand}-handed, {units} to Z up, right-handed, metres")
    return rec


def _csv_floats(cells, source, fld, line_no, allow_empty=True) -> tuple[np.ndarray, np.ndarray]:
    """(values, set) of one CSV column; empty cells are NaN with set=False."""
    arr = np.array(cells)
    stripped = np.char.strip(arr) if arr.dtype.kind == "U" else arr
    empty = stripped == ""
    if empty.any():
        if not allow_empty:
            k = int(np.flatnonzero(empty)[0])
            raise BodyCalError("empty value", source=source, field=fld, where=f"line {line_no[k]}")
        stripped = np.where(empty, "nan", stripped)
    try:
        vals = stripped.astype(float)
    except (ValueError, OverflowError):
        vals = None
    if vals is None or _has_text_nan(stripped, empty):
        for k, c in enumerate(stripped):
            if empty[k]:
                continue
            try:
                v = float(c)
            except ValueError:
                v = None
            if v is None or _is_word(c):
                raise BodyCalError(f"not a number: {_short(str(cells[k]))}", source=source, field=fld,
                                   where=f"line {line_no[k]}")
        raise BodyCalError("not numbers", source=source, field=fld)
    return vals, ~empty


def _is_word(c: str) -> bool:
    # float() accepts "nan", "inf", "infinity": in a CSV these are not numbers we can trust, and
    # numpy would parse them silently.
    return c.strip().lower().lstrip("+-") in ("nan", "inf", "infinity")


def _has_text_nan(stripped, empty) -> bool:
    low = np.char.lower(stripped[~empty])
    return bool(np.isin(np.char.lstrip(low, "+-"), ["nan", "inf", "infinity"]).any())


# ----------------------------------------------------------------------------------------------
# Post-processing shared by every reader


def finish_recording(rec: Recording, *, fill_gaps_s: float = DEFAULT_FILL_GAPS_S,
                     identify_roles: bool = True) -> Recording:
    """Hold untracked values, fill short gaps, build LED hand frames, identify missing roles."""
    if rec.markers is None or rec.markers.size == 0 and rec.markers.shape[1:] != (len(rec.marker_names), 3):
        rec.markers = np.zeros((len(rec.time), len(rec.marker_names), 3))
        rec.marker_valid = np.zeros((len(rec.time), len(rec.marker_names)), bool)
    if fill_gaps_s and fill_gaps_s > 0:
        n_dev, frames_dev = fill_gaps(rec.time, rec.positions, rec.valid, fill_gaps_s, rec.rotations)
        n_mk, frames_mk = fill_gaps(rec.time, rec.markers, rec.marker_valid, fill_gaps_s)
        if n_dev or n_mk:
            rec.notes.append(f"filled {n_dev + n_mk} gaps shorter than {fill_gaps_s:g} s ({frames_dev + frames_mk} "
                             f"frames: positions linear, rotations slerp)")
    hold_untracked(rec.positions, rec.valid, rec.rotations)
    hold_untracked(rec.markers, rec.marker_valid)
    add_led_hand_frames(rec)
    unknown = [d.name for d in rec.devices if d.role is None]
    if identify_roles and unknown and rec.segments_of("tpose"):
        from .roles import apply_roles

        apply_roles(rec)
    elif unknown:
        rec.notes.append(f"no role for {', '.join(unknown)} and no tpose segment to identify them from "
                         "(mark the T-pose on the timeline or give roles in the file)")
    return rec


def _gap_bounds(valid: np.ndarray):
    """For every frame and column: index of the last valid frame at or before, and of the first
    valid frame at or after (-1 / F when none)."""
    f = valid.shape[0]
    idx = np.arange(f)[:, None]
    prev = np.maximum.accumulate(np.where(valid, idx, -1), axis=0)
    nxt = np.minimum.accumulate(np.where(valid, idx, f)[::-1], axis=0)[::-1]
    return prev, nxt


def fill_gaps(time, values, valid, max_gap_s, rotations=None) -> tuple[int, int]:
    """Fill (in place) runs of invalid frames bounded by valid frames less than `max_gap_s` apart:
    positions linearly, rotations by slerp. Returns (gaps filled, frames filled)."""
    if values.shape[1] == 0 or len(time) < 3:
        return 0, 0
    prev, nxt = _gap_bounds(valid)
    f = len(time)
    inner = (~valid) & (prev >= 0) & (nxt < f)
    span = np.where(inner, time[np.clip(nxt, 0, f - 1)] - time[np.clip(prev, 0, f - 1)], np.inf)
    fill = inner & (span < max_gap_s)
    if not fill.any():
        return 0, 0
    fi, ci = np.nonzero(fill)
    p0, p1 = prev[fi, ci], nxt[fi, ci]
    alpha = (time[fi] - time[p0]) / (time[p1] - time[p0])
    values[fi, ci] = values[p0, ci] + alpha[:, None] * (values[p1, ci] - values[p0, ci])
    if rotations is not None:
        rotations[fi, ci] = tf.slerp(rotations[p0, ci], rotations[p1, ci], alpha)
    starts = fill & ~np.concatenate([np.zeros((1, fill.shape[1]), bool), fill[:-1]], axis=0)
    valid[fill] = True
    return int(starts.sum()), int(fill.sum())


def hold_untracked(values, valid, rotations=None) -> None:
    """Untracked frames take the last tracked value (the first tracked one before it), so arrays
    never carry NaN or jumps to the origin; `valid` still says they were not tracked."""
    if values.shape[1] == 0 or values.shape[0] == 0:
        return
    prev, nxt = _gap_bounds(valid)
    src = np.where(prev >= 0, prev, nxt)
    fi, ci = np.nonzero(~valid & (src < valid.shape[0]))
    values[fi, ci] = values[src[fi, ci], ci]
    if rotations is not None:
        rotations[fi, ci] = rotations[src[fi, ci], ci]
        never = ~valid.any(axis=0)
        rotations[:, never] = (1.0, 0.0, 0.0, 0.0)


def led_hand_frame(led1, led2, led3):
    """Hand frame from the three LEDs on the back of the glove (arrays (..., 3)): origin = mean,
    Y = led1 -> led2 (toward the middle finger base), Z = (led2 - led1) x (led3 - led1) (out of the back
    of the hand), X = Y x Z. Returns (origin, quaternion, ok) where ok is False for degenerate LEDs."""
    led1, led2, led3 = (np.asarray(v, float) for v in (led1, led2, led3))
    a, b = led2 - led1, led3 - led1
    y = tf.normalize(a)
    z = np.cross(a, b)
    z = tf.normalize(z - (z * y).sum(-1, keepdims=True) * y)
    x = np.cross(y, z)
    ok = (np.linalg.norm(a, axis=-1) > 1e-6) & (np.linalg.norm(np.cross(a, b), axis=-1) > 1e-9)
    m = np.stack([x, y, z], axis=-1)
    m = np.where(ok[..., None, None], m, np.eye(3))
    return (led1 + led2 + led3) / 3.0, tf.matrix_to_quat(m), ok


def add_led_hand_frames(rec: Recording) -> None:
    """Add a rigid_body device with role hand_<s> built from hand_led1..3_<s> when no hand_<s> pose exists."""
    for s in ("l", "r"):
        role = f"hand_{s}"
        if rec.has_role(role):
            continue
        names = [f"{n}_{s}" for n in LED_NAMES]
        if not all(n in rec.marker_names for n in names):
            continue
        idx = [rec.marker_names.index(n) for n in names]
        origin, quat, ok = led_hand_frame(*(rec.markers[:, j] for j in idx))
        ok = ok & rec.marker_valid[:, idx].all(axis=1)
        name = role if all(d.name != role for d in rec.devices) else f"{role}_leds"
        rec.devices.append(Device(name=name, kind="rigid_body", role=role))
        rec.positions = np.concatenate([rec.positions, origin[:, None]], axis=1)
        rec.rotations = np.concatenate([rec.rotations, quat[:, None]], axis=1)
        rec.valid = np.concatenate([rec.valid, ok[:, None]], axis=1)
        hold_untracked(rec.positions[:, -1:], rec.valid[:, -1:], rec.rotations[:, -1:])
        rec.notes.append(f"built the {role} frame from LEDs {', '.join(names)} (device '{name}', "
                         f"{int(ok.sum())} of {len(ok)} frames)")
