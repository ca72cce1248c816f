"""`load_recording`: the one entry to the readers, picked by the file's suffix, then the shared
post-processing (`postprocess.finish_recording`)."""

from __future__ import annotations

import re
from pathlib import Path

from ...core.errors import BodyCalError
from ..model import Recording
from . import c3d
from .csv_format import has_recording_header, read_csv
from .header import FORMAT_NAME
from .json_format import read_json
from .postprocess import DEFAULT_FILL_GAPS_S, finish_recording

# The file types a recording is read from (FORMATS.md §2), by suffix: the importer's file filter
# and the command line read this table.
READERS = {".json": read_json, ".csv": read_csv, ".c3d": c3d.read_c3d_recording}
RECORDING_SUFFIXES = tuple(READERS)
# What the file browser lists: a recording's JSON is named `*.bcrec.json` (FORMATS.md §2.1); any
# `.json` is still read when its path is given.
RECORDING_GLOBS = ("*.bcrec.json", "*.csv", "*.c3d")
JSON_SUFFIX = ".bcrec.json"
_SNIFF_BYTES = 65536  # how far into a .json the `"format"` field is looked for
_FORMAT_RE = re.compile(rb'"format"\s*:\s*"' + FORMAT_NAME.encode() + rb'"')


def load_recording(path, *, fill_gaps_s: float = DEFAULT_FILL_GAPS_S, identify_roles: bool = True,
                   raw: bool = False) -> Recording:
    """Read a recording (.bcrec.json / .json, .csv with an optional `name.json` sidecar, .c3d) into
    the internal frame. Raises BodyCalError (one line naming file, field, frame/line) on bad input.
    `raw`: the file's own frames only, as checked and converted by its reader (no gap filled, no
    LED hand frame built, no role identified: what `bodycal stream` sends)."""
    path = Path(path)
    source = path.name
    if not path.is_file():
        raise BodyCalError("file not found", source=str(path))
    suffix = path.suffix.lower()
    if suffix not in READERS:
        raise BodyCalError(f"unknown recording type '{suffix}'", source=source,
                           hint="use .bcrec.json, .json, .csv or .c3d")
    rec = READERS[suffix](path)
    return rec if raw else finish_recording(rec, fill_gaps_s=fill_gaps_s, identify_roles=identify_roles)


def check_recording_file(path) -> None:
    """Refuse, with one line, a file that is not a recording by its look alone (a file dropped on
    Blender: FORMATS.md §2.5): a `.json` neither named `*.bcrec.json` nor saying
    `"format": "bodycal-recording"` near its start, or a CSV sidecar; a CSV whose first line is not
    a recording's header; a C3D with no marker label BodyCal knows and no calibration step event.
    Reads no frame data (the import then reads the file and checks everything)."""
    path = Path(path)
    name, suffix = path.name, path.suffix.lower()
    hint = "File > Import > BodyCal recording reads it anyway"
    if not path.is_file():
        raise BodyCalError("file not found", source=str(path))
    if suffix == ".json":
        if path.with_suffix(".csv").is_file():
            raise BodyCalError(f"is the sidecar of {path.with_suffix('.csv').name}", source=name,
                               hint="drop the .csv")
        if name.lower().endswith(JSON_SUFFIX):
            return
        with open(path, "rb") as f:
            head = f.read(_SNIFF_BYTES)
        if not _FORMAT_RE.search(head):
            raise BodyCalError(f'not a BodyCal recording (no "format": "{FORMAT_NAME}")', source=name, hint=hint)
    elif suffix == ".csv":
        if not has_recording_header(path):
            raise BodyCalError("not a BodyCal recording (its first line is not time,name,px,py,pz[,qw,qx,qy,qz])",
                               source=name, hint=hint)
    elif suffix == ".c3d":
        known, steps = c3d.known_labels(path)
        if not known and not steps:
            raise BodyCalError("no marker label BodyCal knows (fingertips, hand LEDs) and no calibration step event",
                               source=name, hint=hint)
    else:
        raise BodyCalError(f"unknown recording type '{suffix}'", source=name, hint="use .bcrec.json, .csv or .c3d")
