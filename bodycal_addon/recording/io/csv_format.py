"""The CSV reader (FORMATS.md §2.2): one row per device or marker and frame, long format, with an
optional `name.json` sidecar for the header; parsed in chunks (numpy's parser for the common
case, a careful path that names the bad line otherwise) and converted to the internal frame."""

from __future__ import annotations

import io
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ...core.errors import BodyCalError, short_repr
from ..coords import UNITS, check_positions, check_quaternions
from ..model import Device, Recording
from .header import SIDECAR_FIELDS, assemble, load_json_file, parse_header

_CSV_COLUMNS = ("time", "name", "px", "py", "pz", "qw", "qx", "qy", "qz")


def read_csv(path) -> Recording:
    """Parse a FORMATS.md §2.2 long-format CSV (+ `name.json` sidecar when present)."""
    path = Path(path)
    source = path.name
    sidecar = path.with_suffix(".json")
    header = _csv_header(sidecar)
    rows = _read_rows(path, source)
    _check_names_and_times(rows, source)
    time = rows.split_frames()
    _check_poses(rows, header, source)
    header = _declare_names(header, rows)
    devices, marker_names = header["devices"], header["marker_names"]
    slots = _row_slots(rows, devices, marker_names, source, sidecar)
    frames = _CsvFrames.scatter(rows, slots, len(time), len(devices), len(marker_names))
    # The per-row arrays go before the conversion so that they and its copies are never all held
    # at once.
    del rows, slots
    check_quaternions(frames.rotations, frames.valid, time, devices, source, where_of=frames.where_of)
    rec = assemble(header, source, time, devices, frames.positions, frames.rotations, frames.valid, marker_names,
                   frames.markers, frames.marker_valid, quaternions_checked=True)
    if not sidecar.is_file():
        rec.notes.append(f"no sidecar {sidecar.name}: assumed Y up, right-handed, metres, "
                         f"{len(devices)} trackers without roles, {len(marker_names)} markers, no segments")
    return rec


def has_recording_header(path) -> bool:
    """Whether the file's first line is a recording's header (FORMATS.md §2.2: known columns, each
    once, time, name and the position among them): what tells a BodyCal CSV from any other CSV
    without reading it all."""
    try:
        with open(path, encoding="utf-8-sig", errors="replace") as f:
            first = f.readline(4096)
    except OSError:
        return False
    cols = [c.strip().lower() for c in first.split(",")]
    return len(set(cols)) == len(cols) and set(cols) <= set(_CSV_COLUMNS) and set(_CSV_COLUMNS[:5]) <= set(cols)


def _csv_header(sidecar: Path) -> dict:
    """The recording's header from the sidecar when there is one; else Y up, right-handed, metres,
    with the devices and markers left for `_declare_names` to find in the rows."""
    if sidecar.is_file():
        return parse_header(load_json_file(sidecar, sidecar.name), sidecar.name, SIDECAR_FIELDS,
                             require_frames=False)
    return {"name": None, "coords": ("Y", "right", "m"), "devices": None, "marker_names": None,
            "segments_raw": []}


@dataclass
class _CsvRows:
    """One entry per data row of the file: its line number, its name (an index into `uniq`, the
    stripped names in order of first appearance), time, position and quaternion (empty cells NaN);
    and, once `split_frames` ran, the frame each row belongs to."""

    line_no: np.ndarray
    uniq: list[str]
    name_idx: np.ndarray
    t_rows: np.ndarray
    p_vals: np.ndarray
    q_vals: np.ndarray
    new_frame: np.ndarray | None = None  # (rows,) the row starts a frame
    frame_of_row: np.ndarray | None = None

    def __post_init__(self):
        self.p_set, self.q_set = ~np.isnan(self.p_vals), ~np.isnan(self.q_vals)  # written nan / inf were refused

    def split_frames(self) -> np.ndarray:
        """Sets `new_frame` and `frame_of_row` (a frame is the rows of one time); returns the
        frames' times."""
        self.new_frame = np.concatenate([[True], np.diff(self.t_rows) > 0])
        self.frame_of_row = np.cumsum(self.new_frame) - 1
        return self.t_rows[self.new_frame]


def _read_rows(path: Path, source: str) -> _CsvRows:
    """Rows pass: checks the header line's columns (each known, once; time, name and the position
    required; the quaternion all or nothing), then parses every data row (`_csv_rows`)."""
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
    return _CsvRows(*_csv_rows(path, lines, chunks, cols, has_q, source))


def _check_names_and_times(rows: _CsvRows, source: str) -> None:
    """Refuses an empty name, a time that is not a finite number, and a time that goes back; names
    the first offending line."""
    line_no, t_rows = rows.line_no, rows.t_rows
    empty_name = [k for k, u in enumerate(rows.uniq) if u == ""]
    if empty_name:
        k = int(np.flatnonzero(rows.name_idx == empty_name[0])[0])
        raise BodyCalError("empty name", source=source, field="name", where=f"line {line_no[k]}")
    bad = np.flatnonzero(~np.isfinite(t_rows))
    if bad.size:
        raise BodyCalError("not a finite number", source=source, field="time", where=f"line {line_no[bad[0]]}")
    back = np.flatnonzero(np.diff(t_rows) < 0)
    if back.size:
        raise BodyCalError(f"time goes back ({t_rows[back[0]]} then {t_rows[back[0] + 1]})", source=source,
                           field="time", where=f"line {line_no[back[0] + 1]}",
                           hint="rows must be sorted by time, strictly increasing between frames")


def _check_poses(rows: _CsvRows, header: dict, source: str) -> None:
    """Refuses a pose with some fields empty and others not, a quaternion without a position, a
    NaN or infinite value, and positions beyond the header's units' bounds (`check_positions`)."""
    line_no, p_vals, q_vals, p_set, q_set = rows.line_no, rows.p_vals, rows.q_vals, rows.p_set, rows.q_set
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


def _declare_names(header: dict, rows: _CsvRows) -> dict:
    """The header with its devices and markers: the sidecar's; without one, a name with a quaternion
    on any row is a tracker (in order of first appearance), any other a marker."""
    if header["devices"] is not None:
        return header
    dev_mask = np.zeros(len(rows.uniq), bool)
    dev_mask[rows.name_idx[rows.q_set.all(1)]] = True
    devices = [Device(name=u, kind="tracker", role=None) for k, u in enumerate(rows.uniq) if dev_mask[k]]
    marker_names = [u for k, u in enumerate(rows.uniq) if not dev_mask[k]]
    return dict(header, devices=devices, marker_names=marker_names)


def _row_slots(rows: _CsvRows, devices: list[Device], marker_names: list[str], source: str,
               sidecar: Path) -> tuple[np.ndarray, np.ndarray]:
    """(kind of each row: 0 device, 1 marker; its device or marker index). Refuses an undeclared
    name, a device row without a quaternion, a marker row with one, and a second row for a name
    in one frame."""
    uniq, name_idx, line_no = rows.uniq, rows.name_idx, rows.line_no
    slot = {d.name: ("d", i) for i, d in enumerate(devices)}
    slot.update({n: ("m", j) for j, n in enumerate(marker_names)})
    kind_of = np.array([{"d": 0, "m": 1, "?": 2}[slot.get(u, ("?", -1))[0]] for u in uniq], np.int8)
    index_of = np.array([slot.get(u, ("?", -1))[1] for u in uniq], dtype=np.int64)
    row_kind = kind_of[name_idx]  # one byte a row: 0 device, 1 marker, 2 undeclared
    bad = np.flatnonzero(row_kind == 2)
    if bad.size:
        raise BodyCalError(f"unknown name '{uniq[name_idx[bad[0]]]}'", source=source, field="name",
                           where=f"line {line_no[bad[0]]}", hint=f"declare it in {sidecar.name}")
    bad = np.flatnonzero((row_kind == 0) & rows.p_set.all(1) & ~rows.q_set.all(1))
    if bad.size:
        raise BodyCalError(f"device '{uniq[name_idx[bad[0]]]}' has no quaternion", source=source,
                           where=f"line {line_no[bad[0]]}")
    bad = np.flatnonzero((row_kind == 1) & rows.q_set.any(1))
    if bad.size:
        raise BodyCalError(f"marker '{uniq[name_idx[bad[0]]]}' has a quaternion", source=source,
                           where=f"line {line_no[bad[0]]}", hint="marker rows leave qw,qx,qy,qz empty")
    # One row per name and frame.
    key = rows.frame_of_row * len(uniq) + name_idx
    order = np.argsort(key, kind="stable")
    dup = np.flatnonzero(np.diff(key[order]) == 0)
    if dup.size:
        k = order[dup[0] + 1]
        raise BodyCalError(f"second row for '{uniq[name_idx[k]]}' at time {rows.t_rows[k]}", source=source,
                           where=f"line {line_no[k]}")
    return row_kind, index_of[name_idx]


@dataclass
class _CsvFrames:
    """The rows laid out by frame: device poses and markers, which are set, and for the quaternion
    check's messages the line of each device's row (0: none) and of each frame's first row."""

    positions: np.ndarray  # (F, D, 3)
    rotations: np.ndarray  # (F, D, 4), identity where untracked
    valid: np.ndarray  # (F, D)
    markers: np.ndarray  # (F, M, 3)
    marker_valid: np.ndarray  # (F, M)
    dev_line: np.ndarray  # (F, D) int32, 4 bytes a row
    frame_lines: np.ndarray  # (F,)

    @classmethod
    def scatter(cls, rows: _CsvRows, slots: tuple[np.ndarray, np.ndarray], f: int, n_devices: int,
                n_markers: int) -> _CsvFrames:
        """Frames pass: every device row with a pose and every marker row with a position into its
        frame and slot (`_row_slots`)."""
        row_kind, row_index = slots
        frame_of_row = rows.frame_of_row
        positions = np.zeros((f, n_devices, 3))
        rotations = np.tile(np.array([1.0, 0, 0, 0]), (f, n_devices, 1))
        valid = np.zeros((f, n_devices), bool)
        d_rows = (row_kind == 0) & rows.q_set.all(1)
        positions[frame_of_row[d_rows], row_index[d_rows]] = rows.p_vals[d_rows]
        rotations[frame_of_row[d_rows], row_index[d_rows]] = rows.q_vals[d_rows]
        valid[frame_of_row[d_rows], row_index[d_rows]] = True
        markers = np.zeros((f, n_markers, 3))
        marker_valid = np.zeros((f, n_markers), bool)
        m_rows = (row_kind == 1) & rows.p_set.all(1)
        markers[frame_of_row[m_rows], row_index[m_rows]] = rows.p_vals[m_rows]
        marker_valid[frame_of_row[m_rows], row_index[m_rows]] = True
        dev_line = np.zeros((f, n_devices), np.int32)
        dev_line[frame_of_row[d_rows], row_index[d_rows]] = rows.line_no[d_rows]
        return cls(positions, rotations, valid, markers, marker_valid, dev_line, rows.line_no[rows.new_frame])

    def where_of(self, frame, dev) -> str:
        return f"line {self.dev_line[frame, dev] or self.frame_lines[frame]}"


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
                raise BodyCalError(f"not a number: {short_repr(str(cells[k]))}", source=source, field=fld,
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
