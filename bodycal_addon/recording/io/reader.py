"""`load_recording`: the one entry to the readers, picked by the file's suffix (a `.json` by its
first bytes: BodyCal's own or an A-Frame motion capture), then the shared post-processing
(`postprocess.finish_recording`)."""

from __future__ import annotations

import re
from pathlib import Path

from ...core.errors import BodyCalError
from ..model import Recording
from . import aframe, bsor, c3d
from .csv_format import has_recording_header, read_csv
from .hands import check_hands
from .header import FORMAT_NAME
from .json_format import read_json
from .postprocess import DEFAULT_FILL_GAPS_S, finish_recording

_SNIFF_BYTES = 65536  # how far into a .json the `"format"` field is looked for
_FORMAT_RE = re.compile(rb'"format"\s*:\s*"' + FORMAT_NAME.encode() + rb'"')


def _json_head(path: Path) -> bytes:
    try:
        with open(path, "rb") as f:
            return f.read(_SNIFF_BYTES)
    except OSError as exc:
        raise BodyCalError(f"cannot read: {exc.strerror}", source=path.name) from None


def read_any_json(path, hands: str = "geometry") -> Recording:
    """A `.json` recording: an A-Frame motion capture when it starts as one (and does not say
    BodyCal's format), else BodyCal's own (FORMATS.md §2.1; its reader names what is wrong)."""
    path = Path(path)
    head = _json_head(path)
    if aframe.looks_like_aframe(head) and not _FORMAT_RE.search(head):
        return aframe.read_aframe(path, hands)
    return read_json(path)


# The file types a recording is read from (FORMATS.md §2), by suffix: the importer's file filter
# and the command line read this table. A reader takes the path and how to tell the hands of a
# three-point kit (recording/io/hands.py: the formats that name no roles).
READERS = {".json": read_any_json, ".csv": lambda p, _hands: read_csv(p),
           ".c3d": lambda p, _hands: c3d.read_c3d_recording(p), ".bsor": bsor.read_bsor}
RECORDING_SUFFIXES = tuple(READERS)
# What the file browser lists: every `.json` (BodyCal's are named `*.bcrec.json`, FORMATS.md §2.1,
# and an A-Frame motion capture keeps its own name; any other JSON is refused with one line).
RECORDING_GLOBS = ("*.json", "*.csv", "*.c3d", "*.bsor")
JSON_SUFFIX = ".bcrec.json"


def load_recording(path, *, fill_gaps_s: float = DEFAULT_FILL_GAPS_S, identify_roles: bool = True,
                   raw: bool = False, hands: str = "geometry") -> Recording:
    """Read a recording (.bcrec.json / .json, .csv with an optional `name.json` sidecar, .c3d, an
    A-Frame motion capture .json, a Beat Saber .bsor replay) into the internal frame. Raises
    BodyCalError (one line naming file, field, frame/line) on bad input. `raw`: the file's own
    frames only, as checked and converted by its reader (no gap filled, no LED hand frame built, no
    role identified: what `bodycal stream` sends). `hands` (one of hands.HANDS): how the two controllers
    of an A-Frame or Beat Saber take become the hands (recording/io/hands.py); other formats name
    their roles."""
    path = Path(path)
    source = path.name
    if not path.is_file():
        raise BodyCalError("file not found", source=str(path))
    suffix = path.suffix.lower()
    if suffix not in READERS:
        raise BodyCalError(f"unknown recording type '{suffix}'", source=source,
                           hint="use .bcrec.json, .json, .csv, .c3d or .bsor")
    check_hands(hands, source)
    rec = READERS[suffix](path, hands)
    return rec if raw else finish_recording(rec, fill_gaps_s=fill_gaps_s, identify_roles=identify_roles)


def check_recording_file(path) -> None:
    """Refuse, with one line, a file that is not a recording by its look alone (a file dropped on
    Blender: FORMATS.md §2.5): a `.json` neither named `*.bcrec.json` nor saying
    `"format": "bodycal-recording"` near its start nor starting as an A-Frame motion capture, or a
    CSV sidecar; a CSV whose first line is not a recording's header; a C3D with no marker label
    BodyCal knows and no calibration step event; a `.bsor` without a Beat Saber replay's magic
    number. Reads no frame data (the import then reads the file and checks everything)."""
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
        head = _json_head(path)
        if not _FORMAT_RE.search(head) and not aframe.looks_like_aframe(head):
            raise BodyCalError(f'not a BodyCal recording (no "format": "{FORMAT_NAME}", not an A-Frame motion '
                               'capture)', source=name, hint=hint)
    elif suffix == ".csv":
        if not has_recording_header(path):
            raise BodyCalError("not a BodyCal recording (its first line is not time,name,px,py,pz[,qw,qx,qy,qz])",
                               source=name, hint=hint)
    elif suffix == ".c3d":
        known, steps = c3d.known_labels(path)
        if not known and not steps:
            raise BodyCalError("no marker label BodyCal knows (fingertips, hand LEDs) and no calibration step event",
                               source=name, hint=hint)
    elif suffix == ".bsor":
        with open(path, "rb") as f:
            if not bsor.is_bsor(f.read(4)):
                raise BodyCalError("not a Beat Saber replay (no BSOR magic number)", source=name, hint=hint)
    else:
        raise BodyCalError(f"unknown recording type '{suffix}'", source=name,
                           hint="use .bcrec.json, .json, .csv, .c3d or .bsor")
