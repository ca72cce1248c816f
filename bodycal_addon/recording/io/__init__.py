"""Read and write tracker recordings (FORMATS.md §2): JSON, CSV + sidecar, C3D; read the
three-point kits' own files: A-Frame motion capture JSON, Beat Saber replays (.bsor).

Everything is converted ONCE, at load, to the internal frame (Blender's: right-handed, Z up,
metres); the conventions of the files (`coords`) and their conversion are in `coords.py`.

After reading, every recording goes through `finish_recording`: quaternions renormalised (within
1e-3) or rejected, untracked frames kept as invalid (their values hold the last tracked value so
that arrays never carry NaN), short gaps filled (linear / slerp), hand frames built from the LED
glove markers, and missing roles identified from the `tpose` segment (roles.py). What was done is
reported in `Recording.notes`.

One reader per format over shared leaves (none of which imports this package):
- `json_format.py`: the JSON reader (§2.1); `header.py`: the header it shares with the CSV sidecar.
- `csv_format.py`: the CSV reader (§2.2); `c3d.py`: the C3D reader (§2.3).
- `aframe.py`: the A-Frame motion-capture reader (§2.6); `bsor.py`: the Beat Saber replay reader
  (§2.7); `hands.py`: which of their two controllers is which hand.
- `reader.py`: `load_recording`, which picks the reader by suffix (a `.json` by its first bytes);
  `writer.py`: `save_recording`; `postprocess.py`: `finish_recording`.
- Leaves in `recording/`: `coords.py` (conventions, conversion, damaged values), `segments.py`
  (calibration segments, §2.4), `gaps.py` (gap filling, holding untracked values), `led_gloves.py`
  (LED hand frames).
"""

from __future__ import annotations

from ..coords import (
    HANDEDNESS,
    MAX_POSITION_M,
    QUAT_TOLERANCE,
    UNITS,
    UPS,
    check_coords,
    check_positions,
    check_quaternions,
    conversion,
    from_internal,
    to_internal,
)
from ..gaps import fill_gaps, hold_untracked
from ..led_gloves import LED_NAMES, add_led_hand_frames, led_hand_frame
from ..segments import parse_segments
from .aframe import read_aframe
from .bsor import read_bsor
from .csv_format import read_csv
from .hands import HANDS
from .header import FORMAT_NAME
from .json_format import check_time, read_json
from .postprocess import DEFAULT_FILL_GAPS_S, finish_recording
from .reader import JSON_SUFFIX, RECORDING_GLOBS, check_recording_file, load_recording
from .writer import save_recording

__all__ = [
    "DEFAULT_FILL_GAPS_S", "FORMAT_NAME", "HANDEDNESS", "HANDS", "JSON_SUFFIX", "LED_NAMES", "MAX_POSITION_M",
    "QUAT_TOLERANCE", "RECORDING_GLOBS", "UNITS", "UPS", "add_led_hand_frames", "check_coords", "check_positions",
    "check_quaternions", "check_recording_file", "check_time", "conversion", "fill_gaps", "finish_recording",
    "from_internal", "hold_untracked", "led_hand_frame", "load_recording", "parse_segments", "read_aframe",
    "read_bsor", "read_csv", "read_json", "save_recording", "to_internal",
]

