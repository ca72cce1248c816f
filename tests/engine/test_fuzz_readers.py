"""Fuzzing the readers: random bytes and mutated valid files (JSON, CSV, C3D, A-Frame motion capture,
Beat Saber replays, body.json) either load or raise BodyCalError with one line naming the file;
nothing else ever escapes, and numpy never warns on the way (a warning would print lines before the
error's one line)."""

from __future__ import annotations

import json
import math
import pathlib
import re
import tempfile
import warnings

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from recording_fixtures import recording_doc, tpose_recording

from bodycal_addon.body.bodymodel import BodyModel
from bodycal_addon.core import paths
from bodycal_addon.core.errors import BodyCalError
from bodycal_addon.recording import io as rio
from bodycal_addon.recording.io import csv_format, header, json_format
from bodycal_dev import bsor_writer, c3d_writer

FUZZ = settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
_DIR = pathlib.Path(tempfile.mkdtemp(prefix="bodycal-fuzz-"))


def _valid_json_doc():
    rec = tpose_recording(seconds=0.2, profile="minimal", leds=True)
    rec.segments[0].start = 0.02
    doc = recording_doc(rec)
    doc["poses"]["head"][3] = None
    doc["segments"].append({"step": "touch", "start": 0.1, "end": 0.15, "point": "chin", "by": "index_tip_r"})
    return doc


VALID_DOC = _valid_json_doc()
VALID_JSON = json.dumps(VALID_DOC).encode()
_csv_rec = tpose_recording(seconds=0.1, profile="minimal", leds=True)
rio.save_recording(_csv_rec, _DIR / "base.csv")
VALID_CSV = (_DIR / "base.csv").read_bytes()
VALID_SIDECAR = (_DIR / "base.json").read_bytes()
VALID_C3D = c3d_writer.write_c3d(_DIR / "base.c3d", np.random.default_rng(0).uniform(-1e3, 1e3, (12, 3, 3)),
                          ["index_tip_r", "Bob:hand_led1_l", "X"], 100.0,
                          events=[("tpose", 0.01), ("motion", 0.05)]).read_bytes()



def _valid_aframe() -> dict:
    """The first 15 samples of a real A-Frame take (sample_data), its button events and gamepads kept."""
    doc = json.loads((paths.data_dir() / "real_vr" / "aframe_vive" / "grabLeft.json").read_text())
    for ent in doc.values():
        ent["poses"] = ent["poses"][:15]
        ent["events"] = ent.get("events", [])[:2]
    return doc


VALID_AFRAME_DOC = _valid_aframe()
VALID_AFRAME = json.dumps(VALID_AFRAME_DOC).encode()
_bsor_poses = np.tile([0.1, 1.7, 0.2, 0.0, 0.0, 0.0, 1.0], (12, 3, 1))
_bsor_poses[0] = 0.0  # the game's first frame
VALID_BSOR = bsor_writer.write_bsor(_DIR / "base.bsor", np.arange(12) / 90.0, _bsor_poses,
                                    {"player name": "Jürgen", "modifiers": "FS"}).read_bytes()


def _load(name: str, data: bytes, sidecar: bytes | None = None):
    path = _DIR / name
    path.write_bytes(data)
    side = path.with_suffix(".json")
    if path.suffix == ".csv":
        if sidecar is None:
            side.unlink(missing_ok=True)
        else:
            side.write_bytes(sidecar)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)  # numpy's overflow / invalid value warnings
            rec = rio.load_recording(path)
    except BodyCalError as exc:
        _one_line(exc, name.split(".")[0])  # the CSV or its sidecar
        return None
    # Whatever loads is well formed.
    f = rec.frame_count
    assert rec.positions.shape == (f, len(rec.devices), 3) and rec.valid.shape == (f, len(rec.devices))
    assert np.isfinite(rec.positions).all() and np.isfinite(rec.markers).all()
    assert np.allclose(np.linalg.norm(rec.rotations, axis=-1), 1.0, atol=1e-6) if rec.rotations.size else True
    return rec


def _one_line(exc: BodyCalError, name: str, field: str | None = None) -> str:
    text = str(exc)
    assert text and "\n" not in text, text
    assert name in text, f"the message does not name the file {name}: {text}"
    if field is not None:
        assert field in text, f"the message does not name the field {field}: {text}"
    return text


def _mutate_bytes(data: bytes, edits) -> bytes:
    buf = bytearray(data)
    for kind, pos, value in edits:
        if not buf:
            break
        i = pos % len(buf)
        if kind == 0:
            buf[i] = value
        elif kind == 1:
            del buf[i]
        elif kind == 2:
            buf.insert(i, value)
        else:
            del buf[i:]
    return bytes(buf)


EDITS = st.lists(st.tuples(st.integers(0, 3), st.integers(0, 2 ** 31), st.integers(0, 255)), min_size=1, max_size=6)
JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers(-10 ** 20, 10 ** 20) | st.floats(allow_nan=True) | st.text(max_size=8),
    lambda inner: st.lists(inner, max_size=8) | st.dictionaries(st.text(max_size=6), inner, max_size=4),
    max_leaves=12)


def test_valid_samples_load():
    assert _load("ok.bcrec.json", VALID_JSON) is not None
    assert _load("ok.csv", VALID_CSV, VALID_SIDECAR) is not None
    assert _load("ok.c3d", VALID_C3D) is not None
    assert _load("ok.json", VALID_AFRAME).frame_count == 15
    assert _load("ok.bsor", VALID_BSOR).frame_count == 12


@FUZZ
@given(data=st.binary(max_size=2048), ext=st.sampled_from([".bcrec.json", ".csv", ".c3d", ".json", ".bsor"]))
@example(data=b'{"camera": {', ext=".json")
@example(data=VALID_BSOR[:4], ext=".bsor")
def test_random_bytes(data, ext):
    _load("random" + ext, data)


@FUZZ
@given(edits=EDITS)
def test_mutated_aframe_bytes(edits):
    _load("mut_aframe.json", _mutate_bytes(VALID_AFRAME, edits))



@FUZZ
@given(edits=EDITS)
def test_mutated_bsor_bytes(edits):
    _load("mut.bsor", _mutate_bytes(VALID_BSOR, edits))


@FUZZ
@given(pos=st.integers(0, 400), values=st.binary(min_size=1, max_size=4))
@example(pos=5 + 1 + 4 + 5 + 4 + 6, values=b"\x00\x00\x80\x7f")  # a count in the header made huge
def test_mutated_bsor_header_and_frames(pos, values):
    # Overwrite bytes in the header and the first frames, where the structure and the counts live.
    buf = bytearray(VALID_BSOR)
    buf[pos:pos + len(values)] = values
    _load("hdr.bsor", bytes(buf[:len(VALID_BSOR)]))


@FUZZ
@given(value=st.floats(width=32) | st.just(float("nan")), frame=st.integers(0, 11), device=st.integers(0, 2),
       field=st.integers(0, 7))
def test_any_float_in_a_replays_frame_loads_or_is_one_line(value, frame, device, field):
    poses = _bsor_poses.copy()
    time = np.arange(12) / 90.0
    if field == 7:
        time[frame] = value
    else:
        poses[frame, device, field] = value
    _load("float.bsor", bsor_writer.write_bsor(_DIR / "f.bsor", time, poses).read_bytes())


@FUZZ
@given(edits=EDITS)
def test_mutated_json_bytes(edits):
    _load("mut.bcrec.json", _mutate_bytes(VALID_JSON, edits))


def _paths(doc, prefix=()):
    out = [prefix]
    if isinstance(doc, dict):
        for k, v in doc.items():
            out += _paths(v, prefix + (k,))
    elif isinstance(doc, list):
        for k, v in enumerate(doc[:6]):
            out += _paths(v, prefix + (k,))
    return out


DOC_PATHS = [p for p in _paths(VALID_DOC) if p]
AFRAME_PATHS = [p for p in _paths(VALID_AFRAME_DOC) if p]


@FUZZ
@given(path=st.sampled_from(AFRAME_PATHS), value=JSON_VALUES, delete=st.booleans())
def test_mutated_aframe_structure(path, value, delete):
    doc = json.loads(VALID_AFRAME)
    target = doc
    for k in path[:-1]:
        target = target[k]
    if delete:
        del target[path[-1]]
    else:
        target[path[-1]] = value
    _load("struct_aframe.json", json.dumps(doc).encode())


@FUZZ
@given(path=st.sampled_from(DOC_PATHS), value=JSON_VALUES, delete=st.booleans())
def test_mutated_json_structure(path, value, delete):
    doc = json.loads(VALID_JSON)
    target = doc
    for k in path[:-1]:
        target = target[k]
    if delete:
        del target[path[-1]]
    else:
        target[path[-1]] = value
    _load("struct.bcrec.json", json.dumps(doc).encode())


@FUZZ
@given(edits=EDITS, with_sidecar=st.booleans())
def test_mutated_csv(edits, with_sidecar):
    _load("mut.csv", _mutate_bytes(VALID_CSV, edits), VALID_SIDECAR if with_sidecar else None)


@FUZZ
@given(line=st.integers(1, 200), col=st.integers(0, 8),
       cell=st.sampled_from(["", "nan", "inf", "-1e999", "1e999", "x", "0", "-5", "1,2", "hmd", "0x10", " 3 "]))
def test_mutated_csv_cells(line, col, cell):
    lines = VALID_CSV.decode().splitlines()
    k = line % len(lines)
    cells = lines[k].split(",")
    cells[col % len(cells)] = cell
    lines[k] = ",".join(cells)
    _load("cell.csv", ("\n".join(lines) + "\n").encode(), VALID_SIDECAR)


@FUZZ
@given(edits=EDITS)
def test_mutated_sidecar(edits):
    _load("side.csv", VALID_CSV, _mutate_bytes(VALID_SIDECAR, edits))


@FUZZ
@given(edits=EDITS)
@example(edits=[(0, 190533527, 22)])  # found by a long run: a parameter with a zero and many 255 dimensions
@example(edits=[(2, 1461, 128), (2, 58558844, 1)])  # found by CI: a signalling NaN widened to float64 warned
def test_mutated_c3d(edits):
    _load("mut.c3d", _mutate_bytes(VALID_C3D, edits))


@FUZZ
@given(pos=st.integers(0, 1100), values=st.binary(min_size=1, max_size=4))
@example(pos=605, values=b"\x00\x00\x81\x7f")  # found by a local run: a parameter float made a signalling NaN
def test_mutated_c3d_header_and_parameters(pos, values):
    # Overwrite bytes in the header and parameter blocks, where the structure lives.
    buf = bytearray(VALID_C3D)
    buf[pos:pos + len(values)] = values
    _load("hdr.c3d", bytes(buf[:len(VALID_C3D)]))


def _paths_agree(text: str):
    lines = text.splitlines()
    cols = [c.strip().lower() for c in lines[0].split(",")]
    fast = csv_format._csv_fast(lines[1:], cols)
    if fast is None:
        return None
    try:
        slow = csv_format._csv_slow(lines[1:], cols, [True] * 4, "x.csv")
    except BodyCalError:
        raise AssertionError("the fast CSV path accepted what the careful path rejects") from None
    np.testing.assert_array_equal(fast[0], slow[0])
    assert [n.strip() for n in fast[1]] == slow[1]
    for a, b in zip(fast[2:], slow[2:]):
        np.testing.assert_array_equal(a, b)
    return fast


def test_fast_csv_path_is_taken_for_clean_files():
    assert _paths_agree(VALID_CSV.decode()) is not None


@FUZZ
@given(line=st.integers(1, 200), col=st.integers(0, 8),
       cell=st.sampled_from(["", " ", "nan", "NaN", "+inf", "1e999", "x", "0", "-5", "1.5e-3", " 3 ", "1.2.3", "0x10",
                             "1_000", "--1", "1e", ".5", "5.", "∞", "١"]))
def test_fast_csv_path_agrees_with_the_careful_one(line, col, cell):
    lines = VALID_CSV.decode().splitlines()
    k = line % len(lines[1:]) + 1
    cells = lines[k].split(",")
    cells[col % len(cells)] = cell
    lines[k] = ",".join(cells)
    _paths_agree("\n".join(lines) + "\n")


# ---------------------------------------------------------------------------------------------
# Every bad input gets one line naming the file (and the field)

C3D_PARAMS = {  # parameter -> what else the file needs for it to be read
    "POINT:USED": {}, "POINT:DATA_START": {}, "POINT:RATE": {}, "POINT:SCALE": {}, "EVENT:USED": {},
    "ANALOG:USED": {"ANALOG:RATE": 1000.0}, "ANALOG:RATE": {"ANALOG:USED": 1.0},
}
_C3D_POINTS = np.random.default_rng(1).uniform(-1e3, 1e3, (12, 3, 3))


@FUZZ
@given(key=st.sampled_from(sorted(C3D_PARAMS)), value=st.sampled_from([math.nan, math.inf, -math.inf]))
def test_c3d_non_finite_parameters_are_one_line(key, value):
    path = c3d_writer.write_c3d(_DIR / "nonfinite.c3d", _C3D_POINTS, ["a", "b", "c"], 100.0,
                                events=[("tpose", 0.01)], float_params={key: value, **C3D_PARAMS[key]})
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)
            rio.load_recording(path)
    except BodyCalError as exc:
        _one_line(exc, "nonfinite.c3d", key)
    else:
        raise AssertionError(f"{key} = {value} was accepted")


@FUZZ
@given(key=st.sampled_from(sorted(C3D_PARAMS)), value=st.floats(allow_nan=False, allow_infinity=False, width=32))
def test_c3d_any_float_parameter_loads_or_is_one_line(key, value):
    path = c3d_writer.write_c3d(_DIR / "anyfloat.c3d", _C3D_POINTS, ["a", "b", "c"], 100.0,
                                events=[("tpose", 0.01)], float_params={key: value, **C3D_PARAMS[key]})
    _load("anyfloat.c3d", path.read_bytes())


def _body_load(name: str, data: bytes):
    path = _DIR / name
    path.write_bytes(data)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)
            return BodyModel.load(path)
    except BodyCalError as exc:
        _one_line(exc, name)
        return None


@FUZZ
@given(data=st.binary(max_size=4096))
@example(data=b"BLENDER-v405REND" + bytes(range(256)))  # a .blend's first bytes
@example(data="\u00e9t\u00e9".encode("latin-1"))  # not UTF-8
@example(data=b'{"format": "bodycal-body", "version": 1, "kind": "user", "name": "\xff"}')
def test_body_json_random_bytes_are_one_line(data):
    _body_load("random.body.json", data)


@FUZZ
@given(depth=st.integers(1, 120_000), kind=st.sampled_from(["list", "object", "extra"]))
@example(depth=100_000, kind="list")
@example(depth=100_000, kind="object")
@example(depth=100_000, kind="extra")
def test_body_json_any_nesting_depth_is_one_line(depth, kind):
    if kind == "list":
        text = "[" * depth + "]" * depth
    elif kind == "object":
        text = '{"a":' * depth + "1" + "}" * depth
    else:  # a valid model carrying a deep extra field
        text = ('{"format": "bodycal-body", "version": 1, "kind": "user", "name": "n", "deep": '
                + "[" * depth + "]" * depth + "}")
    model = _body_load("deep.body.json", text.encode())
    assert model is None or kind == "extra" and depth <= 64


VALID_BODY = {
    "format": "bodycal-body", "version": 1, "kind": "user", "name": "s", "reference_time": 1.25,
    "joints": {"shoulder_l": {"world": [0.18, 0.02, 1.42], "frame": "upperarm_l", "local": [0.0, -0.03, 0.11]}},
    "bones": {"forearm_l": {"head": "elbow_l", "tail": "wrist_l", "length": 0.26, "right": [1, 0, 0],
                            "radius_head": 0.045, "radius_tail": 0.03, "right_local": [1, 0, 0],
                            "right_frame": "forearm_l"}},
    "surface": [{"id": "sphere:skull", "type": "sphere", "bone": "head", "center": [0, 0.02, 0.09], "radius": 0.095}],
    "offsets": {"wrist_l": {"tracker": "hand_l", "v0": [0, 0, 0.1], "r0_tracker": [1, 0, 0, 0],
                            "r0_joint": [1, 0, 0, 0]}},
    "calibration": {"steps_used": ["tpose"], "quality": {"tpose": {"rms_mm": 2.1}}},
    "tpose": {"head": [0, 0, 1.6, 1, 0, 0, 0]}, "eye_height": 1.6,
    "palm_planes": {"hand_l": {"point": [0, 0, 0], "normal": [0, 0, 1]}},
}


def _number_paths(doc, prefix=""):
    if isinstance(doc, dict):
        return [p for k, v in doc.items() for p in _number_paths(v, f"{prefix}.{k}" if prefix else k)]
    if isinstance(doc, list):
        return [p for k, v in enumerate(doc) for p in _number_paths(v, f"{prefix}[{k}]")]
    return [prefix] if isinstance(doc, int | float) and not isinstance(doc, bool) and prefix != "version" else []


BODY_NUMBERS = _number_paths(VALID_BODY)


def _set_path(doc, path: str, value):
    keys = [int(k) if k.isdigit() else k for k in path.replace("[", ".").replace("]", "").split(".")]
    target = doc
    for k in keys[:-1]:
        target = target[k]
    target[keys[-1]] = value


def test_valid_body_loads():
    path = _DIR / "ok.body.json"
    path.write_text(json.dumps(VALID_BODY))
    assert BodyModel.load(path).bones["forearm_l"].length == 0.26


@FUZZ
@given(path=st.sampled_from(BODY_NUMBERS), token=st.sampled_from(["NaN", "Infinity", "-Infinity", "1e999", "-1e999"]))
def test_body_json_non_finite_anywhere_names_the_body_file_and_field(path, token):
    doc = json.loads(json.dumps(VALID_BODY))
    _set_path(doc, path, "@@")
    text = json.dumps(doc).replace('"@@"', token)
    (_DIR / "nonfinite.body.json").write_text(text)
    with pytest.raises(BodyCalError) as info:
        BodyModel.load(_DIR / "nonfinite.body.json")
    _one_line(info.value, "nonfinite.body.json", path)


@FUZZ
@given(path=st.sampled_from(BODY_NUMBERS), value=st.sampled_from([True, False, "1", "0.5", "1e3", 1e308, -1e308]))
def test_body_json_lax_numbers_refused(path, value):
    # true / false and numeric strings are not numbers; 1e308 m is no position, offset or length.
    if isinstance(value, float) and path in ("reference_time",) or path.startswith("calibration"):
        return  # a time (any finite value) and the free-form calibration report are not bounded
    doc = json.loads(json.dumps(VALID_BODY))
    _set_path(doc, path, value)
    (_DIR / "lax.body.json").write_text(json.dumps(doc))
    with pytest.raises(BodyCalError) as info:
        BodyModel.load(_DIR / "lax.body.json")
    _one_line(info.value, "lax.body.json", re.sub(r"\[\d+\]$", "", path))  # a vector is named whole


@FUZZ
@given(frame=st.integers(0, 20), col=st.integers(0, 6), value=st.sampled_from([1e308, -1e308, 1e4, -2e4, True, False]),
       fmt=st.sampled_from(["json", "csv"]))
def test_recording_lax_values_refused(frame, col, value, fmt):
    # 1e308 (or 10 km and more) is no position in a room; JSON true / false are not numbers.
    if fmt == "json":
        doc = json.loads(VALID_JSON)
        name = next(iter(doc["poses"]))
        rows = doc["poses"][name]
        k = next(k % len(rows) for k in range(frame, frame + len(rows)) if rows[k % len(rows)] is not None)
        rows[k][col if isinstance(value, bool) else col % 3] = value
        path = _DIR / "lax.bcrec.json"
        path.write_text(json.dumps(doc))
        field = f"poses.{name}"
    else:
        if isinstance(value, bool):
            return  # CSV cells are text: "True" is simply not a number (covered by the cell fuzz)
        lines = VALID_CSV.decode().splitlines()
        k = 1 + frame % (len(lines) - 1)
        cells = lines[k].split(",")
        cells[2 + col % 3] = repr(value)
        lines[k] = ",".join(cells)
        path = _DIR / "lax.csv"
        path.write_text("\n".join(lines) + "\n")
        (_DIR / "lax.json").write_bytes(VALID_SIDECAR)
        field = f"line {k + 1}"
    with pytest.raises(BodyCalError) as info:
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)
            rio.load_recording(path)
    _one_line(info.value, path.name, field)


def test_recording_time_true_refused():
    doc = json.loads(VALID_JSON)
    assert doc["time"][0] == 0
    doc["time"][0] = False  # numpy reads it as 0.0: the old reader accepted it
    (_DIR / "booltime.bcrec.json").write_text(json.dumps(doc))
    with pytest.raises(BodyCalError) as info:
        rio.load_recording(_DIR / "booltime.bcrec.json")
    _one_line(info.value, "booltime.bcrec.json", "time")


def test_c3d_far_positions_refused():
    pts = _C3D_POINTS.copy()
    pts[4, 1] = [2e7, 0, 0]  # 20 km in mm
    path = c3d_writer.write_c3d(_DIR / "far.c3d", pts, ["a", "b", "c"], 100.0)
    with pytest.raises(BodyCalError) as info:
        rio.load_recording(path)
    _one_line(info.value, "far.c3d", "marker 'b'")
    assert "frame 5" in str(info.value)


class _CountingName(str):
    """A device / marker name that counts its equality comparisons (hash lookups compare only on a
    hash match; scanning a list compares with every earlier name)."""

    compares = 0

    def __eq__(self, other):
        type(self).compares += 1
        return str.__eq__(self, other)

    __hash__ = str.__hash__


@pytest.mark.parametrize("n", [2000])
def test_device_and_marker_parsing_is_linear(n):
    # Structural, not timed: the name checks compare each name with O(1) others, not with all
    # earlier ones (the quadratic scan took 55 s for 40k devices).
    names = [_CountingName(f"LHR-{k:05d}") for k in range(n)]
    _CountingName.compares = 0
    devices = header._parse_devices([{"name": nm, "kind": "tracker", "role": None} for nm in names], "x.bcrec.json")
    markers = header._parse_markers([{"name": _CountingName(f"m{k}")} for k in range(n)], "x.bcrec.json")
    json_format._check_keys({nm: None for nm in names}, [d.name for d in devices], "x.bcrec.json", "poses", "device")
    json_format._check_keys({nm: None for nm in markers}, markers, "x.bcrec.json", "points", "marker")
    assert len(devices) == n and len(markers) == n
    assert _CountingName.compares <= 8 * n, f"{_CountingName.compares} name comparisons for {n} names"


def _csv_outcome(path):
    try:
        rec = rio.load_recording(path)
    except BodyCalError as exc:
        return str(exc)
    return rec.time, rec.positions, rec.rotations, rec.valid, rec.markers, rec.marker_valid, \
        [d.name for d in rec.devices], rec.marker_names


@FUZZ
@given(chunk=st.integers(1, 600), line=st.integers(1, 200), col=st.integers(0, 8),
       cell=st.sampled_from(["", "nan", "x", "1e999", "5", "hmd", "LHR-00", "1e5"]), blank=st.integers(0, 200),
       sidecar=st.booleans())
def test_csv_read_in_chunks_is_the_same_as_at_once(chunk, line, col, cell, blank, sidecar):
    # The CSV is parsed a chunk at a time (memory): whatever the chunk size, a file loads to the
    # same arrays or fails with the same line as when read at once.
    lines = VALID_CSV.decode().splitlines()
    k = 1 + line % (len(lines) - 1)
    cells = lines[k].split(",")
    cells[col % len(cells)] = cell
    lines[k] = ",".join(cells)
    lines.insert(1 + blank % (len(lines) - 1), "")
    path = _DIR / "chunks.csv"
    path.write_text("\r\n".join(lines) + "\r\n")
    if sidecar:
        (_DIR / "chunks.json").write_bytes(VALID_SIDECAR)
    else:
        (_DIR / "chunks.json").unlink(missing_ok=True)
    whole = _csv_outcome(path)
    default = csv_format._CSV_CHUNK_BYTES
    try:
        csv_format._CSV_CHUNK_BYTES = chunk
        chunked = _csv_outcome(path)
    finally:
        csv_format._CSV_CHUNK_BYTES = default
    if isinstance(whole, str):
        assert chunked == whole
    else:
        assert not isinstance(chunked, str), chunked
        for a, b in zip(whole, chunked):
            np.testing.assert_array_equal(a, b)
