"""Fuzzing the readers: random bytes and mutated valid files (JSON, CSV, C3D) either load or raise
BodyCalError with one line; nothing else ever escapes."""

from __future__ import annotations

import json
import pathlib
import tempfile

import numpy as np
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from recording_fixtures import recording_doc, tpose_recording

from bodycal_addon import recording_io as rio
from bodycal_addon.errors import BodyCalError
from bodycal_dev import c3d_writer

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
        rec = rio.load_recording(path)
    except BodyCalError as exc:
        assert "\n" not in str(exc) and str(exc)
        return None
    # Whatever loads is well formed.
    f = rec.frame_count
    assert rec.positions.shape == (f, len(rec.devices), 3) and rec.valid.shape == (f, len(rec.devices))
    assert np.isfinite(rec.positions).all() and np.isfinite(rec.markers).all()
    assert np.allclose(np.linalg.norm(rec.rotations, axis=-1), 1.0, atol=1e-6) if rec.rotations.size else True
    return rec


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


@FUZZ
@given(data=st.binary(max_size=2048), ext=st.sampled_from([".bcrec.json", ".csv", ".c3d"]))
def test_random_bytes(data, ext):
    _load("random" + ext, data)


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
def test_mutated_c3d(edits):
    _load("mut.c3d", _mutate_bytes(VALID_C3D, edits))


@FUZZ
@given(pos=st.integers(0, 1100), values=st.binary(min_size=1, max_size=4))
def test_mutated_c3d_header_and_parameters(pos, values):
    # Overwrite bytes in the header and parameter blocks, where the structure lives.
    buf = bytearray(VALID_C3D)
    buf[pos:pos + len(values)] = values
    _load("hdr.c3d", bytes(buf[:len(VALID_C3D)]))


def _paths_agree(text: str):
    lines = text.splitlines()
    cols = [c.strip().lower() for c in lines[0].split(",")]
    fast = rio._csv_fast(lines[1:], cols)
    if fast is None:
        return None
    try:
        slow = rio._csv_slow(lines[1:], cols, [True] * 4, "x.csv")
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
