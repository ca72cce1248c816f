"""The writer: a Recording as JSON (FORMATS.md §2.1) or as CSV + sidecar JSON (§2.2), in a
declared convention."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..coords import check_coords, from_internal
from ..model import Recording
from .header import FORMAT_NAME


def save_recording(rec: Recording, path, *, up: str = "Y", handedness: str = "right", units: str = "m",
                   extra: dict | None = None) -> list[Path]:
    """Write `rec` as JSON (FORMATS.md §2.1), or as CSV + sidecar JSON (§2.2) for a .csv path, in the
    declared convention. Untracked frames are written as null / empty fields; `extra` (JSON values)
    goes to the file's `extra` field, which readers keep out of the recording. Returns the files
    written."""
    path = Path(path)
    up, handedness, units = check_coords({"up": up, "handedness": handedness, "units": units}, str(path))
    header = _header(rec, up, handedness, units)
    if extra is not None:
        header["extra"] = extra
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
