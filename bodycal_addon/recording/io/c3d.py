"""C3D marker files in pure numpy (FORMATS.md §2.3; the C3D file format user guide, c3d.org).

Layout: 512-byte blocks. Block 1 is the header (16-bit words: points, analog values per frame,
first/last frame, scale, data start block, frame rate). The parameter section starts at the block
named by the header's first byte; its 4-byte preamble names the processor type (84 Intel, 85 DEC,
86 MIPS), which fixes byte order and float format for the whole file. Groups and parameters follow
as linked records. Point data: per frame, (x, y, z, residual word) per point, then the analog
samples; int16 scaled by POINT:SCALE when the scale is positive, float32 when negative. A negative
residual word marks a point as invalid.

DEC floats are VAX F-floats: 16-bit words swapped relative to IEEE little-endian, exponent bias
128 with a 0.1f mantissa, i.e. the IEEE reading of the swapped bytes is 4 times too large.

The writer of the same subset, for tests, is `bodycal_dev.c3d_writer` (not shipped).
"""

from __future__ import annotations

import math
import re
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ...core.errors import BodyCalError
from ..coords import check_positions, to_internal
from ..model import STEPS, Recording
from ..segments import parse_segments

INTEL, DEC, MIPS = 84, 85, 86
PROCESSORS = {INTEL: "Intel", DEC: "DEC", MIPS: "MIPS"}
UNIT_SCALE = {"mm": 0.001, "cm": 0.01, "m": 1.0}
MAX_RATE_HZ = 1e6  # a sample rate beyond this is a damaged field, not a capture system
MARKER_RE = re.compile(r"^(?:(?:thumb|index|middle|ring|pinky)_tip|hand_led[123])_[lr]$")


@dataclass
class C3DData:
    """Raw content of a C3D file: points in the file's units and axes."""

    source: str
    processor: str
    rate: float
    first_frame: int
    points: np.ndarray  # (F, N, 3) file units
    valid: np.ndarray  # (F, N) residual >= 0
    residuals: np.ndarray  # (F, N)
    labels: list[str]
    units: str
    scale: float
    is_float: bool
    events: list[tuple[str, float, str]] = field(default_factory=list)  # (label, seconds, context)
    parameters: dict = field(default_factory=dict)  # {"GROUP:NAME": value}
    analog_per_frame: int = 0

    @property
    def frame_count(self) -> int:
        return self.points.shape[0]

    @property
    def time(self) -> np.ndarray:
        return (self.first_frame - 1 + np.arange(self.frame_count)) / self.rate

    def param(self, key: str, default=None):
        return self.parameters.get(key.upper(), default)


def _dec_to_ieee(raw: np.ndarray) -> np.ndarray:
    """uint8 (..., 4) VAX F-floats -> float32."""
    swapped = raw[..., [2, 3, 0, 1]].copy()
    return swapped.view("<f4")[..., 0] / np.float32(4.0)


class _Reader:
    def __init__(self, data: bytes, source: str):
        self.data = data
        self.source = source
        self.proc = INTEL
        self.endian = "<"

    def err(self, msg, field=None, where=None, hint=None):
        return BodyCalError(msg, source=self.source, field=field, where=where, hint=hint)

    def need(self, offset, size, what):
        if offset < 0 or offset + size > len(self.data):
            raise self.err(f"file ends inside the {what} (byte {offset})", hint="the file is truncated or not a C3D")

    def i8(self, off):
        self.need(off, 1, "parameter section")
        return struct.unpack_from("b", self.data, off)[0]

    def u8(self, off):
        self.need(off, 1, "parameter section")
        return self.data[off]

    def i16(self, off):
        self.need(off, 2, "parameter section")
        return struct.unpack_from(self.endian + "h", self.data, off)[0]

    def u16(self, off):
        self.need(off, 2, "header")
        return struct.unpack_from(self.endian + "H", self.data, off)[0]

    def floats(self, off, count) -> np.ndarray:
        self.need(off, 4 * count, "parameter section")
        raw = np.frombuffer(self.data, np.uint8, 4 * count, off).reshape(count, 4)
        # A damaged parameter may be a signalling NaN, which warns when widened: it stays a NaN,
        # and the checks of the parameter that uses it report it in one line.
        with np.errstate(invalid="ignore", over="ignore"):
            if self.proc == DEC:
                return _dec_to_ieee(raw).astype(float)
            return raw.copy().view(self.endian + "f4")[:, 0].astype(float)

    def f32(self, off):
        return float(self.floats(off, 1)[0])


def _text(raw: bytes) -> str:
    return raw.decode("latin-1").replace("\x00", " ").strip()


def _parse_parameters(r: _Reader, start: int, nblocks: int) -> dict:
    params: dict = {}
    groups: dict[int, str] = {}
    pending: list[tuple[int, str, object]] = []
    off = start + 4
    end = min(len(r.data), start + max(nblocks, 1) * 512) if nblocks else len(r.data)
    end = max(end, min(len(r.data), start + 512))
    seen = 0
    while off + 2 <= end:
        seen += 1
        if seen > 100000:
            raise r.err("parameter section does not end", field="parameters")
        nchars = r.i8(off)
        if nchars == 0:
            break
        gid = r.i8(off + 1)
        n = abs(nchars)
        r.need(off + 2, n + 2, "parameter section")
        name = _text(r.data[off + 2:off + 2 + n]).upper()
        link = off + 2 + n
        nxt = r.i16(link)
        body = link + 2
        if gid < 0:
            groups[-gid] = name
        elif gid > 0:
            dtype = r.i8(body)
            ndim = r.u8(body + 1)
            dims = [r.u8(body + 2 + k) for k in range(ndim)]
            data_off = body + 2 + ndim
            count = math.prod(dims)  # exact (np.prod of many dimensions would overflow)
            r.need(data_off, count * max(abs(dtype), 1), "parameter section")
            if dtype == -1:
                r.need(data_off, count, "parameter section")
                raw = r.data[data_off:data_off + count]
                if ndim <= 1:
                    value = _text(raw)
                else:
                    width = dims[0]
                    value = [_text(raw[k * width:(k + 1) * width]) for k in range(count // width if width else 0)]
            elif dtype == 1:
                r.need(data_off, count, "parameter section")
                value = np.frombuffer(r.data, np.int8, count, data_off).astype(int)
            elif dtype == 2:
                r.need(data_off, 2 * count, "parameter section")
                value = np.frombuffer(r.data, r.endian + "i2", count, data_off).astype(int)
            elif dtype == 4:
                value = r.floats(data_off, count)
            else:
                raise r.err(f"parameter {name} has an unknown data type {dtype}", field="parameters",
                            where=f"byte {off}")
            if dtype != -1 and ndim > 1 and count > 0:
                value = value.reshape(dims[::-1])
            pending.append((gid, name, value))
        if nxt == 0:
            break
        if nxt < 0:
            raise r.err("broken parameter link", field="parameters", where=f"byte {link}")
        off = link + nxt
    for gid, name, value in pending:
        params[f"{groups.get(gid, f'GROUP{gid}')}:{name}"] = value
    return params


def _scalar(params, key, default=None):
    v = params.get(key)
    if v is None or isinstance(v, str | list):
        return default
    v = np.asarray(v).ravel()
    return v[0].item() if v.size else default


def _count(r: _Reader, params, key, default):
    """A count or block number (16-bit, unsigned as in C3D's int16 words): refused with one line when
    the file stores it as a non-finite, fractional or out-of-range number."""
    v = _scalar(params, key, default)
    if v is None:
        return None
    if isinstance(v, float) and not (math.isfinite(v) and v == round(v) and -32768 <= v <= 65535):
        raise r.err(f"{v:g} is not a count", field=key, hint="a whole number from 0 to 65535; the file is damaged")
    return int(v) & 0xFFFF


def _real(r: _Reader, params, key, default):
    """A real-valued scalar parameter; NaN or infinite is refused with one line naming it."""
    v = _scalar(params, key, default)
    if v is None:
        return None
    v = float(v)
    if not math.isfinite(v):
        raise r.err(f"{v} is not a finite number", field=key, hint="the file is damaged")
    return v


def _labels(params, n: int) -> list[str]:
    labels: list[str] = []
    for key in ["POINT:LABELS"] + [f"POINT:LABELS{k}" for k in range(2, 100)]:
        v = params.get(key)
        if v is None:
            if key != "POINT:LABELS":
                break
            continue
        labels += [v] if isinstance(v, str) else [str(x) for x in v]
    labels = labels[:n]
    labels += [f"point_{k}" for k in range(len(labels), n)]
    return [lab if lab else f"point_{k}" for k, lab in enumerate(labels)]


@dataclass
class _PointLayout:
    """Where a C3D file's point data lies and how to read it: the header's words, overridden by
    the POINT, ANALOG and TRIAL parameters."""

    n_points: int
    analog: int  # analog samples per frame, stored after each frame's points
    first: int  # first frame number
    n_frames: int
    scale: float  # POINT:SCALE; negative: the points are float32
    rate: float  # frames per second
    data_block: int  # first 512-byte block of the point data (1-based)

    @property
    def is_float(self) -> bool:
        return self.scale < 0


def read_c3d(path) -> C3DData:
    """Read a C3D file's header, parameters, points and events (raw, in the file's units and axes)."""
    r, params = _open(path)
    layout = _point_layout(r, params)
    points = _read_points(r, layout)
    xyz, valid, resid_word = _valid_points(points, layout.is_float)
    return C3DData(source=r.source, processor=PROCESSORS[r.proc], rate=layout.rate, first_frame=layout.first,
                   points=xyz, valid=valid, residuals=np.where(valid, resid_word, -1.0),
                   labels=_labels(params, layout.n_points), units=_units(params), scale=layout.scale,
                   is_float=layout.is_float, events=_events(r, params), parameters=params,
                   analog_per_frame=layout.analog)


def _open(path) -> tuple[_Reader, dict]:
    """Opening pass: reads the file, checks the header's signature and the parameter section's
    processor type (which sets the reader's byte order and float format) and parses the
    parameters. Returns the reader over the whole file and {"GROUP:NAME": value}."""
    path = Path(path)
    source = path.name
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise BodyCalError(f"cannot read: {exc.strerror}", source=str(path)) from None
    r = _Reader(data, source)
    if len(data) < 512:
        raise r.err(f"only {len(data)} bytes: not a C3D file (the header alone is 512)")
    if data[1] != 0x50:
        raise r.err("not a C3D file (byte 2 of the header is not 0x50)")
    pblock = data[0]
    if pblock < 2:
        raise r.err(f"parameter section at block {pblock}", field="header", hint="the file is not a valid C3D")
    pstart = (pblock - 1) * 512
    r.need(pstart, 4, "parameter section")
    proc = data[pstart + 3]
    if proc not in PROCESSORS:
        raise r.err(f"unknown processor type {proc}", field="parameters",
                    hint="expected 84 (Intel), 85 (DEC), 86 (MIPS)")
    r.proc = proc
    r.endian = ">" if proc == MIPS else "<"
    return r, _parse_parameters(r, pstart, data[pstart + 2])


def _point_layout(r: _Reader, params: dict) -> _PointLayout:
    """Layout pass: the header's words, each overridden by its parameter when the file has it
    (the analog samples per frame from ANALOG:USED and ANALOG:RATE), then checked: a usable rate
    and scale, a frame range (`_frame_range`) and a data block after the header."""
    n_points = r.u16(2)
    analog = r.u16(4)
    first, last = r.u16(6), r.u16(8)
    scale = r.f32(12)
    data_block = r.u16(16)
    rate = r.f32(20)
    n_points = _count(r, params, "POINT:USED", n_points)
    scale = _real(r, params, "POINT:SCALE", scale)
    rate = _real(r, params, "POINT:RATE", rate)
    data_block = _count(r, params, "POINT:DATA_START", data_block)
    analog_used = _count(r, params, "ANALOG:USED", None)
    analog_rate = _real(r, params, "ANALOG:RATE", None)
    if analog_used and analog_rate is not None and math.isfinite(rate) and rate > 0:
        if not 0 < analog_rate <= MAX_RATE_HZ:
            raise r.err(f"analog rate {analog_rate:g} Hz is not usable", field="ANALOG:RATE",
                        hint=f"a positive rate up to {MAX_RATE_HZ:g} Hz")
        analog = int(round(analog_used * analog_rate / rate))
    if not np.isfinite(rate) or rate <= 0:
        raise r.err(f"frame rate {rate} is not positive", field="POINT:RATE")
    if rate > MAX_RATE_HZ:
        raise r.err(f"frame rate {rate:g} Hz is not plausible", field="POINT:RATE",
                    hint=f"at most {MAX_RATE_HZ:g} Hz")
    if not np.isfinite(scale) or scale == 0:
        raise r.err(f"point scale {scale} is not usable", field="POINT:SCALE")
    first, n_frames = _frame_range(r, params, first, last)
    if data_block < 2:
        raise r.err(f"data section at block {data_block}", field="POINT:DATA_START")
    return _PointLayout(n_points, analog, first, n_frames, scale, rate, data_block)


def _frame_range(r: _Reader, params: dict, first: int, last: int) -> tuple[int, int]:
    """(first frame, frame count) from the header's 16-bit first and last frame, or from
    TRIAL:ACTUAL_START_FIELD / ACTUAL_END_FIELD when both hold a usable 32-bit range."""
    n_frames = last - first + 1
    start_field = params.get("TRIAL:ACTUAL_START_FIELD")
    end_field = params.get("TRIAL:ACTUAL_END_FIELD")
    if end_field is not None and start_field is not None and np.size(end_field) >= 2 and np.size(start_field) >= 2:
        # 32-bit frame numbers for long trials (the header's 16-bit last frame saturates).
        s = (int(np.ravel(start_field)[0]) & 0xFFFF) + 65536 * (int(np.ravel(start_field)[1]) & 0xFFFF)
        e = (int(np.ravel(end_field)[0]) & 0xFFFF) + 65536 * (int(np.ravel(end_field)[1]) & 0xFFFF)
        if e >= s > 0:
            first, n_frames = s, e - s + 1
    if n_frames <= 0:
        raise r.err(f"last frame {last} before first frame {first}", field="header")
    return first, n_frames


def _read_points(r: _Reader, layout: _PointLayout) -> np.ndarray:
    """Points pass: (frames, points, 4) x, y, z (scaled to the file's units) and the residual word
    of every point, from the data section; refuses a data section shorter than the layout says."""
    data, n_frames, n_points = r.data, layout.n_frames, layout.n_points
    width = 4 if layout.is_float else 2
    per_frame = 4 * n_points + layout.analog
    dstart = (layout.data_block - 1) * 512
    need = dstart + n_frames * per_frame * width
    if need > len(data):
        have = max(0, (len(data) - dstart) // max(per_frame * width, 1))
        raise r.err(f"data section holds {have} frames, the header says {n_frames}", field="data",
                    hint="the file is truncated")
    if n_points == 0:
        return np.zeros((n_frames, 0, 4))
    if layout.is_float:
        raw = np.frombuffer(data, np.uint8, n_frames * per_frame * 4, dstart).reshape(n_frames, per_frame, 4)
        raw = raw[:, :4 * n_points]
        # A damaged file's words may be signalling NaNs, which warn when widened: they become
        # invalid points below (not finite), as any NaN does.
        with np.errstate(invalid="ignore", over="ignore"):
            if r.proc == DEC:
                vals = _dec_to_ieee(raw)
            else:
                vals = np.ascontiguousarray(raw).view(r.endian + "f4")[..., 0]
            return vals.astype(float).reshape(n_frames, n_points, 4)
    vals = np.frombuffer(data, r.endian + "i2", n_frames * per_frame, dstart).reshape(n_frames, per_frame)
    points = vals[:, :4 * n_points].astype(float).reshape(n_frames, n_points, 4)
    points[..., :3] *= abs(layout.scale)
    return points


def _valid_points(points: np.ndarray, is_float: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(x, y, z with invalid points zeroed, valid, residual word): a point is valid when its
    residual word is not negative and its coordinates are finite."""
    residual = points[..., 3]
    if is_float:
        # The residual word of float files is a float holding an int16 (camera mask in the high byte).
        resid_word = np.where(np.isfinite(residual), residual, -1.0)
    else:
        resid_word = residual
    valid = (resid_word >= 0) & np.isfinite(points[..., :3]).all(-1)
    return np.where(valid[..., None], points[..., :3], 0.0), valid, resid_word


def _units(params: dict) -> str:
    """POINT:UNITS in lower case; millimetres when absent or blank."""
    units = params.get("POINT:UNITS", "mm")
    if not isinstance(units, str):
        units = units[0] if isinstance(units, list) and units else "mm"
    return units.strip().lower() or "mm"


def _events(r: _Reader, params: dict) -> list[tuple[str, float, str]]:
    """The EVENT group as (label, seconds, context), as many as EVENT:USED and the labels and
    times the file holds allow."""
    events = []
    used = _count(r, params, "EVENT:USED", 0)
    if used > 0:
        labels = params.get("EVENT:LABELS", [])
        labels = [labels] if isinstance(labels, str) else list(labels)
        contexts = params.get("EVENT:CONTEXTS", [])
        contexts = [contexts] if isinstance(contexts, str) else list(contexts)
        times = params.get("EVENT:TIMES")
        if times is not None and not isinstance(times, str | list):
            t = np.asarray(times, float).reshape(-1, 2) if np.size(times) >= 2 * used else None
            if t is not None:
                for k in range(min(used, len(labels), len(t))):
                    ctx = contexts[k] if k < len(contexts) else ""
                    events.append((labels[k], float(t[k, 0] * 60.0 + t[k, 1]), ctx))
    return events


def known_labels(path) -> tuple[int, int]:
    """(marker labels BodyCal knows, calibration step events) of a C3D file, from its header and
    parameters only (no point data read): what tells a C3D recording BodyCal can use from any other
    C3D. Raises BodyCalError (one line) when it is not a readable C3D file."""
    r, params = _open(path)
    labels = _labels(params, _count(r, params, "POINT:USED", r.u16(2)) or 0)
    known = sum(1 for label in labels if MARKER_RE.match(match_marker_name(label)))
    steps = len(event_segments(_events(r, params), math.inf))
    return known, steps


def match_marker_name(label: str) -> str:
    """FORMATS marker name for a C3D label (case-insensitive, `subject:` prefix ignored), else the
    label without its prefix."""
    bare = label.rsplit(":", 1)[-1].strip()
    low = bare.lower()
    return low if MARKER_RE.match(low) else bare


def event_segments(events, t_end: float) -> list[dict]:
    """Segments from events whose label is a step (`step[:point[:by]]`, optional `bodycal:` prefix):
    each runs to the next step event (or the end of the recording), like timeline markers."""
    steps = []
    for label, t, _ctx in events:
        text = label.strip()
        if text.lower().startswith("bodycal:"):
            text = text[len("bodycal:"):]
        parts = text.split(":")
        if parts[0].lower() in STEPS:
            steps.append((t, parts[0].lower(), parts[1] if len(parts) > 1 and parts[1] else None,
                          parts[2] if len(parts) > 2 and parts[2] else None))
    steps.sort(key=lambda s: s[0])
    out = []
    for k, (t, step, point, by) in enumerate(steps):
        end = steps[k + 1][0] if k + 1 < len(steps) else t_end
        if end <= t:
            continue
        d = {"step": step, "start": t, "end": end}
        if point:
            d["point"] = point
        if by:
            d["by"] = by
        out.append(d)
    return out


def read_c3d_recording(path) -> Recording:
    """A marker-only Recording from a C3D file, in the internal frame (metres, Z up)."""
    c = read_c3d(path)
    if c.units not in UNIT_SCALE:
        raise BodyCalError(f"unknown units '{c.units}'", source=c.source, field="POINT:UNITS", hint="mm, cm or m")
    y_screen = c.param("POINT:Y_SCREEN")
    up = "Y" if isinstance(y_screen, str) and y_screen.strip().upper() in ("+Y", "Y") else "Z"
    # Model outputs stored as points (angles, forces, moments, powers) are not positions.
    not_points = set()
    for key in ("POINT:ANGLES", "POINT:FORCES", "POINT:MOMENTS", "POINT:POWERS"):
        v = c.param(key)
        not_points.update([v] if isinstance(v, str) else (v if isinstance(v, list) else []))
    keep = [k for k, label in enumerate(c.labels) if label not in not_points]
    names, notes, taken = [], [], set()
    if len(keep) < len(c.labels):
        notes.append(f"left out {len(c.labels) - len(keep)} model outputs stored as points (angles, forces, ...)")
    for k in keep:
        label = c.labels[k]
        name = match_marker_name(label)
        if name in taken:  # a set: a list made this quadratic in the number of labels
            name = label.strip()
            while name in taken:
                name = f"{name}_{k}"
            notes.append(f"marker label '{label}' repeats: kept as '{name}'")
        taken.add(name)
        names.append(name)
    check_positions(c.points[:, keep], c.valid[:, keep], UNIT_SCALE[c.units], c.source,
                    [f"marker {c.labels[k]!r}" for k in keep], lambda f, _i: f"frame {c.first_frame + f}")
    pts, _ = to_internal(c.points[:, keep], None, up, "right", c.units)
    time = c.time
    segs = parse_segments(event_segments(c.events, float(time[-1])), time, c.source, [], names)
    n = c.frame_count
    rec = Recording(name=Path(c.source).stem, time=time, devices=[], positions=np.zeros((n, 0, 3)),
                    rotations=np.zeros((n, 0, 4)), valid=np.zeros((n, 0), bool), marker_names=names,
                    markers=pts, marker_valid=c.valid[:, keep].copy(), segments=segs, source=c.source)
    matched = sum(1 for nm in names if MARKER_RE.match(nm))
    rec.notes.append(f"C3D ({c.processor}, {'float' if c.is_float else 'integer'}): {len(names)} markers "
                     f"({matched} matched to BodyCal names), {n} frames at {c.rate:g} Hz, units {c.units}, {up} up")
    if c.events:
        rec.notes.append(f"{len(segs)} of {len(c.events)} events are calibration steps")
    rec.notes += notes
    return rec


# ----------------------------------------------------------------------------------------------
# Writer (tests)

