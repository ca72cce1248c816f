"""`load_recording`: the one entry to the readers, picked by the file's suffix, then the shared
post-processing (`postprocess.finish_recording`)."""

from __future__ import annotations

from pathlib import Path

from ...core.errors import BodyCalError
from ..model import Recording
from . import c3d
from .csv_format import read_csv
from .json_format import read_json
from .postprocess import DEFAULT_FILL_GAPS_S, finish_recording

# The file types a recording is read from (FORMATS.md §2), by suffix: the importer's file filter
# and the command line read this table.
READERS = {".json": read_json, ".csv": read_csv, ".c3d": c3d.read_c3d_recording}
RECORDING_SUFFIXES = tuple(READERS)


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
