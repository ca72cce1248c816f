"""C3D reader (pure numpy) on the real files in sample_data/markers and on files written in
every processor format, with physical checks that can fail."""

from __future__ import annotations

import zipfile

import numpy as np
import pytest

from bodycal_addon.core.errors import BodyCalError
from bodycal_addon.recording import io as rio
from bodycal_addon.recording.io import c3d
from bodycal_dev import c3d_writer


@pytest.fixture(scope="module")
def markers_dir():
    from bodycal_addon.core import paths

    d = paths.data_dir()
    assert d is not None, "sample_data/ missing"
    return d / "markers"


@pytest.fixture(scope="module")
def walk_c3d(markers_dir, tmp_path_factory):
    out = tmp_path_factory.mktemp("walk")
    with zipfile.ZipFile(markers_dir / "kineticstoolkit" / "walk.c3d.zip") as z:
        z.extractall(out)
    return out / "walk.c3d"


def _distance(rec, a, b):
    pa, va = rec.marker(a)
    pb, vb = rec.marker(b)
    ok = va & vb
    d = np.linalg.norm(pa[ok] - pb[ok], axis=1)
    return d, ok


def _plausible_metres(rec):
    pts = rec.markers[rec.marker_valid]
    assert np.isfinite(pts).all()
    assert (np.abs(pts[:, :2]) < 5.0).all() and (pts[:, 2] > -0.2).all() and (pts[:, 2] < 2.5).all()


def test_vicon_arm_file(markers_dir):
    raw = c3d.read_c3d(markers_dir / "ezc3d" / "Vicon.c3d")
    assert (raw.processor, raw.is_float, raw.rate, raw.frame_count, len(raw.labels)) == ("Intel", True, 100.0, 580, 51)
    assert raw.units == "mm" and raw.analog_per_frame == 760
    assert raw.labels[0] == "boite:gauche_ext" and not raw.valid.all()  # some points are occluded
    rec = rio.load_recording(markers_dir / "ezc3d" / "Vicon.c3d", fill_gaps_s=0.0)
    assert rec.frame_count == 580 and rec.fps == pytest.approx(100.0)
    assert rec.marker_names[0] == "gauche_ext" and "ASISr" in rec.marker_names  # subject prefix stripped
    np.testing.assert_array_equal(rec.marker_valid, raw.valid)
    _plausible_metres(rec)
    # The box ("boite") is rigid: its corner distances hold to a fraction of a millimetre.
    for a, b in (("gauche_ext", "droite_ext"), ("avant_gauche", "arriere_droit")):
        d, ok = _distance(rec, a, b)
        assert ok.sum() > 500 and 0.3 < d.mean() < 0.6 and d.std() < 0.0005


def test_qualisys_file(markers_dir):
    raw = c3d.read_c3d(markers_dir / "ezc3d" / "Qualisys.c3d")
    assert (raw.rate, raw.frame_count, raw.first_frame, len(raw.labels), raw.units) == (200.0, 340, 705, 55, "mm")
    assert len(raw.events) == 7 and raw.events[0][0] == "LHS" and raw.events[0][1] == pytest.approx(3.59, abs=1e-4)
    rec = rio.load_recording(markers_dir / "ezc3d" / "Qualisys.c3d")
    assert rec.time[0] == pytest.approx(704 / 200)  # the trial starts at frame 705
    assert not rec.segments  # gait events are not calibration steps
    _plausible_metres(rec)
    d, _ = _distance(rec, "L_IAS", "R_IAS")  # pelvis width: 0.2-0.3 m, nearly rigid
    assert 0.2 < d.mean() < 0.3 and d.std() < 0.004


def test_tennis_serve_in_metres(markers_dir):
    raw = c3d.read_c3d(markers_dir / "kineticstoolkit" / "kinematics_tennis_serve.c3d")
    assert (raw.rate, raw.frame_count, len(raw.labels), raw.units) == (50.0, 1092, 39, "m")
    rec = rio.load_recording(markers_dir / "kineticstoolkit" / "kinematics_tennis_serve.c3d")
    assert "LASI" in rec.marker_names and all(":" not in n for n in rec.marker_names)
    _plausible_metres(rec)
    d, _ = _distance(rec, "LASI", "RASI")
    assert 0.2 < d.mean() < 0.3 and d.std() < 0.004
    # Head markers well above the ankles all along the serve (even in the knee bend): Z is up.
    head, _ = rec.marker("LFHD")
    ankle, _ = rec.marker("LANK")
    assert (head[:, 2] - ankle[:, 2] > 0.8).all() and np.median(head[:, 2] - ankle[:, 2]) > 1.3


def test_vicon_walk_model_joint_centres(walk_c3d):
    raw = c3d.read_c3d(walk_c3d)
    assert (raw.rate, raw.frame_count, raw.first_frame, len(raw.labels)) == (100.0, 221, 153, 96)
    assert len(raw.events) == 8 and {e[2] for e in raw.events} == {"Left", "Right"}
    rec = rio.load_recording(walk_c3d)
    # Angles, forces, moments and powers stored as points are left out; the 58 positions stay.
    assert len(rec.marker_names) == 58 and "LKneeAngles" not in rec.marker_names and "LKJC" in rec.marker_names
    _plausible_metres(rec)
    # The model's knee and ankle joint centres ride on a rigid shank: constant length, 0.3-0.5 m.
    for side in "LR":
        d, ok = _distance(rec, f"{side}KJC", f"{side}AJC")
        assert ok.all() and 0.3 < d.mean() < 0.5 and d.std() < 0.003


# ---------------------------------------------------------------------------------------------
# Files written here: processor formats, integer data, labels, events


def _points(f=40, n=4, seed=0):
    rng = np.random.default_rng(seed)
    base = rng.uniform(-1000, 1000, (n, 3))
    return base + 50 * np.sin(np.arange(f)[:, None, None] / 7.0 + np.arange(n)[None, :, None])


def test_dec_float_known_value():
    # VAX F-float 1.0 = 0x4080 0000, stored as little-endian 16-bit words: 80 40 00 00.
    assert c3d._dec_to_ieee(np.array([[0x80, 0x40, 0, 0]], np.uint8))[0] == 1.0
    assert c3d._dec_to_ieee(np.array([[0x80, 0xC0, 0, 0]], np.uint8))[0] == -1.0
    x = np.array([0.5, -3.25, 1234.5678, 1e-3], np.float32)
    np.testing.assert_array_equal(c3d._dec_to_ieee(c3d_writer.ieee_to_dec(x)), x)


@pytest.mark.parametrize("processor", [c3d.INTEL, c3d.DEC, c3d.MIPS])
@pytest.mark.parametrize("integer", [False, True])
def test_processor_formats_round_trip(tmp_path, processor, integer):
    pts = _points()
    valid = np.ones(pts.shape[:2], bool)
    valid[5:9, 2] = False
    path = c3d_writer.write_c3d(tmp_path / "t.c3d", pts, ["A", "B", "C", "D"], 120.0, valid=valid, processor=processor,
                         integer=integer, scale=0.05)
    raw = c3d.read_c3d(path)
    assert raw.processor == c3d.PROCESSORS[processor] and raw.is_float is not integer
    assert raw.rate == 120.0 and raw.frame_count == 40 and raw.labels == ["A", "B", "C", "D"]
    np.testing.assert_array_equal(raw.valid, valid)
    tol = 0.025 if integer else 1e-3  # half an integer step of 0.05 mm, or float32
    np.testing.assert_allclose(raw.points[valid], pts[valid], atol=tol)
    assert (raw.points[~valid] == 0).all()


def test_marker_names_events_and_units(tmp_path):
    pts = _points(f=300, n=5)
    labels = ["Bob:Index_Tip_R", "bob:HAND_LED1_l", "Bob:RASI", "Other:RASI", "  "]
    events = [("tpose", 0.5), ("Foot Strike", 0.7), ("touch:wrist_top_l:index_tip_r", 1.0), ("bodycal:motion", 1.5)]
    path = c3d_writer.write_c3d(tmp_path / "s.c3d", pts / 10, labels, 100.0, units="cm", events=events)
    rec = rio.load_recording(path)
    assert rec.marker_names == ["index_tip_r", "hand_led1_l", "RASI", "Other:RASI", "point_4"]
    np.testing.assert_allclose(rec.markers[:, 2], pts[:, 2] / 1000, atol=1e-6)  # cm -> m, Z up unchanged
    assert [(s.label, s.start, s.end) for s in rec.segments] == [
        ("tpose", 0.5, 1.0), ("touch:wrist_top_l:index_tip_r", 1.0, 1.5), ("motion", 1.5, pytest.approx(2.99))]
    assert any("repeats" in n for n in rec.notes)


def test_y_up_files_and_many_labels(tmp_path):
    pts = _points(f=10, n=300)
    labels = [f"m{k}" for k in range(300)]
    path = c3d_writer.write_c3d(tmp_path / "y.c3d", pts, labels, 60.0, units="m", y_screen="+Y")
    rec = rio.load_recording(path)
    assert rec.marker_names == labels  # LABELS2 holds the labels after 255
    np.testing.assert_allclose(rec.markers[0, 0], [pts[0, 0, 0], -pts[0, 0, 2], pts[0, 0, 1]], atol=1e-4)


def test_broken_files_raise_one_line(tmp_path):
    good = c3d_writer.write_c3d(tmp_path / "g.c3d", _points(), list("ABCD"), 100.0)
    data = good.read_bytes()
    cases = {
        "short.c3d": (data[:300], "not a C3D file"),
        "key.c3d": (data[:1] + b"\x00" + data[2:], "not a C3D file"),
        "truncated.c3d": (data[:-100], "data section holds 38 frames, the header says 40"),
        "proc.c3d": (data[:512 + 3] + b"\x07" + data[512 + 4:], "unknown processor type 7"),
    }
    for name, (blob, words) in cases.items():
        (tmp_path / name).write_bytes(blob)
        with pytest.raises(BodyCalError) as info:
            rio.load_recording(tmp_path / name)
        assert str(info.value).startswith(name) and words in str(info.value), str(info.value)
    path = c3d_writer.write_c3d(tmp_path / "units.c3d", _points(), list("ABCD"), 100.0, units="ft")
    with pytest.raises(BodyCalError, match="units.c3d: POINT:UNITS: unknown units 'ft'"):
        rio.load_recording(path)
    path = c3d_writer.write_c3d(tmp_path / "ev.c3d", _points(), list("ABCD"), 100.0, events=[("touch:nose", 0.1)])
    with pytest.raises(BodyCalError, match=r"ev.c3d: segments\[0\].point: unknown touch point 'nose'"):
        rio.load_recording(path)


@pytest.mark.parametrize("key, value, extra, words", [
    ("POINT:USED", float("nan"), {}, "POINT:USED: nan is not a count"),
    ("POINT:DATA_START", float("inf"), {}, "POINT:DATA_START: inf is not a count"),
    ("EVENT:USED", float("-inf"), {}, "EVENT:USED: -inf is not a count"),
    ("EVENT:USED", 2.5, {}, "EVENT:USED: 2.5 is not a count"),
    ("ANALOG:RATE", float("nan"), {"ANALOG:USED": 2.0}, "ANALOG:RATE: nan is not a finite number"),
    ("ANALOG:RATE", -1000.0, {"ANALOG:USED": 2.0}, "ANALOG:RATE: analog rate -1000 Hz is not usable"),
    ("POINT:RATE", 1e30, {}, "POINT:RATE: frame rate 1e+30 Hz is not plausible"),
])
def test_non_finite_parameters_are_one_line(tmp_path, key, value, extra, words):
    # Used to escape as ValueError / OverflowError from int(nan) / int(inf).
    path = c3d_writer.write_c3d(tmp_path / "p.c3d", _points(), list("ABCD"), 100.0, events=[("tpose", 0.1)],
                                float_params={key: value, **extra})
    with pytest.raises(BodyCalError) as info:
        rio.load_recording(path)
    text = str(info.value)
    assert text.startswith(f"p.c3d: {words}") and "\n" not in text, text


def test_float_parameters_that_are_counts_still_read(tmp_path):
    # Some exporters write counts as floats: a whole finite value is taken as the count.
    path = c3d_writer.write_c3d(tmp_path / "f.c3d", _points(), list("ABCD"), 100.0, events=[("tpose", 0.1)],
                                float_params={"POINT:USED": 4.0, "EVENT:USED": 1.0})
    raw = c3d.read_c3d(path)
    assert raw.labels == list("ABCD") and len(raw.events) == 1


def test_far_marker_positions_refused(tmp_path):
    pts = _points()
    pts[7, 2] = [0.0, 1e38, 0.0]  # float32 holds it; 1e35 m is no marker in a room
    path = c3d_writer.write_c3d(tmp_path / "far.c3d", pts, list("ABCD"), 100.0)
    with pytest.raises(BodyCalError, match=r"^far.c3d: marker 'C': frame 8: position .* 10000 m or more"):
        rio.load_recording(path)
