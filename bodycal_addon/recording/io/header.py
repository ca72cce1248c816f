"""The header shared by the JSON file (FORMATS.md §2.1) and the CSV sidecar (§2.2): reading the
JSON text, then format, version, name, coords, devices, markers and the raw segments list."""

from __future__ import annotations

import json
from pathlib import Path

from ...core.errors import BodyCalError
from ..coords import check_coords, check_quaternions, to_internal
from ..model import DEVICE_KINDS, ROLES, Device, Recording
from ..segments import parse_segments

FORMAT_NAME = "bodycal-recording"

TOP_FIELDS = {"format", "version", "coords", "devices", "markers", "time", "poses", "points", "segments", "name",
               "extra"}
SIDECAR_FIELDS = TOP_FIELDS - {"time", "poses", "points"}


def load_json_file(path: Path, source: str, report_bools: bool = False):
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


def parse_header(doc, source: str, allowed: set, require_frames: bool) -> dict:
    """The header fields the JSON document and the CSV sidecar share (FORMATS.md §2.1), checked:
    only `allowed` fields, each of its type; one BodyCalError naming the field otherwise."""
    if not isinstance(doc, dict):
        raise BodyCalError("the file must hold a JSON object", source=source, hint="see FORMATS.md §2.1")
    fmt = doc.get("format")  # first: another JSON (a body model, a sidecar picked by mistake) says so
    if fmt != FORMAT_NAME:
        raise BodyCalError(f"is {fmt!r}, expected \"{FORMAT_NAME}\"", source=source, field="format",
                           hint="not a BodyCal recording")
    unknown = set(doc) - allowed
    if unknown:
        raise BodyCalError(f"unknown field(s) {sorted(unknown)}", source=source,
                           hint=f"allowed: {', '.join(sorted(allowed))}")
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


def assemble(header, source, time, devices, positions, rotations, valid, marker_names, markers, marker_valid,
             quaternions_checked: bool = False) -> Recording:
    """The Recording from parsed arrays in the file's coordinates: quaternions checked (unless the
    reader already did, with its own line numbers), converted to Z up, right-handed metres, the
    segments parsed, and a note when a conversion happened."""
    up, hand, units = header["coords"]
    if not quaternions_checked:
        check_quaternions(rotations, valid, time, devices, source)
    positions, rotations = to_internal(positions, rotations, up, hand, units)
    markers, _ = to_internal(markers, None, up, hand, units)
    segments = parse_segments(header["segments_raw"], time, source, devices, marker_names)
    rec = Recording(name=header["name"] or Path(source).name.split(".")[0], time=time, devices=devices,
                    positions=positions, rotations=rotations, valid=valid, marker_names=marker_names,
                    markers=markers, marker_valid=marker_valid, segments=segments, source=source)
    if (up, hand, units) != ("Z", "right", "m"):
        rec.notes.append(f"converted from {up} up, {hand}-handed, {units} to Z up, right-handed, metres")
    return rec
