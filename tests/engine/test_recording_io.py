"""Recording readers and writers (FORMATS.md §2): every coordinate convention pinned with a known
pose, quaternions consistent with positions, validation errors naming file / field / frame or line,
dropouts, gap filling and LED hand frames."""

from __future__ import annotations

import json

import numpy as np
import pytest
from recording_fixtures import recording_doc, tpose_recording

from bodycal_addon.core import transforms as tf
from bodycal_addon.core.errors import BodyCalError
from bodycal_addon.recording import io as rio

IDENTITY = [1.0, 0.0, 0.0, 0.0]


def _one_device_doc(pose, coords, frames=3):
    return {
        "format": "bodycal-recording", "version": 1, "coords": coords,
        "devices": [{"name": "hmd", "kind": "hmd", "role": "head"}],
        "time": [k / 90 for k in range(frames)],
        "poses": {"hmd": [pose] * frames},
    }


def _load_doc(tmp_path, doc, name="rec.bcrec.json", **kw):
    path = tmp_path / name
    path.write_text(json.dumps(doc))
    return rio.load_recording(path, **kw)


# ---------------------------------------------------------------------------------------------
# Conventions


def test_steamvr_y_up_right_handed_known_pose(tmp_path):
    # SteamVR: x right, y up, -z forward. A headset 1.6 m up, 0.3 m in front of the origin, looking
    # forward with no rotation, lands 1.6 m up and 0.3 m along +Y: (x, y, z) -> (x, -z, y).
    rec = _load_doc(tmp_path, _one_device_doc([0.1, 1.6, -0.3] + IDENTITY, {"up": "Y", "handedness": "right",
                                                                               "units": "m"}))
    np.testing.assert_allclose(rec.positions[0, 0], [0.1, 0.3, 1.6], atol=1e-12)
    q = rec.rotations[0, 0]
    # Device frames keep the OpenXR convention (local -Z forward, +Y up): forward is world +Y, up +Z.
    np.testing.assert_allclose(tf.rotate(q, [0, 0, -1.0]), [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(tf.rotate(q, [0, 1.0, 0]), [0, 0, 1], atol=1e-12)
    np.testing.assert_allclose(tf.rotate(q, [1.0, 0, 0]), [1, 0, 0], atol=1e-12)
    assert any("Y up" in n for n in rec.notes)


def test_unity_left_handed_lands_where_steamvr_does(tmp_path):
    # Unity: x right, y up, +z forward (left-handed). The same physical pose as the SteamVR test.
    rec = _load_doc(tmp_path, _one_device_doc([0.1, 1.6, 0.3] + IDENTITY, {"up": "Y", "handedness": "left"}))
    np.testing.assert_allclose(rec.positions[0, 0], [0.1, 0.3, 1.6], atol=1e-12)
    q = rec.rotations[0, 0]
    # A Unity camera looks along its local +Z; mirrored to the right-handed device frame that is -Z.
    np.testing.assert_allclose(tf.rotate(q, [0, 0, -1.0]), [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(tf.rotate(q, [0, 1.0, 0]), [0, 0, 1], atol=1e-12)
    # Unity turned 90 degrees to its right (yaw about +Y, clockwise seen from above in a left-handed frame):
    # the headset looks along Unity +x, i.e. internal +X.
    s = np.sqrt(0.5)
    rec = _load_doc(tmp_path, _one_device_doc([0, 1.6, 0, s, 0, s, 0], {"up": "Y", "handedness": "left"}))
    np.testing.assert_allclose(tf.rotate(rec.rotations[0, 0], [0, 0, -1.0]), [1, 0, 0], atol=1e-12)


def test_z_up_conventions_and_units(tmp_path):
    rec = _load_doc(tmp_path, _one_device_doc([0.1, 0.3, 1.6] + IDENTITY, {"up": "Z", "handedness": "right"}))
    np.testing.assert_allclose(rec.positions[0, 0], [0.1, 0.3, 1.6])
    np.testing.assert_allclose(rec.rotations[0, 0], IDENTITY)
    assert not rec.notes
    rec = _load_doc(tmp_path, _one_device_doc([0.3, 0.1, 1.6] + IDENTITY, {"up": "Z", "handedness": "left"}))
    np.testing.assert_allclose(rec.positions[0, 0], [0.3, -0.1, 1.6])
    for units, factor in (("cm", 100.0), ("mm", 1000.0)):
        rec = _load_doc(tmp_path, _one_device_doc([10 * factor / 100, 160 * factor / 100, -30 * factor / 100]
                                                  + IDENTITY, {"units": units}))
        np.testing.assert_allclose(rec.positions[0, 0], [0.1, 0.3, 1.6], atol=1e-12)
        np.testing.assert_allclose(tf.rotate(rec.rotations[0, 0], [0, 0, -1.0]), [0, 1, 0], atol=1e-12)


@pytest.mark.parametrize("up", ["Y", "Z"])
@pytest.mark.parametrize("handedness", ["right", "left"])
@pytest.mark.parametrize("units", ["m", "cm", "mm"])
def test_device_local_point_maps_to_the_same_world_point(up, handedness, units):
    rng = np.random.default_rng(hash((up, handedness, units)) % 2 ** 32)
    p = rng.normal(size=(50, 3))
    q = tf.normalize(rng.normal(size=(50, 4)))
    local = rng.normal(size=(50, 3))
    world = p + tf.rotate(q, local)
    p2, q2 = rio.to_internal(p, q, up, handedness, units)
    m, mirror = rio.conversion(up, handedness, units)
    # The local point in the converted (right-handed, metric) device frame.
    local2 = local @ mirror.T * rio.UNITS[units]
    np.testing.assert_allclose(p2 + tf.rotate(q2, local2), world @ m.T, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(q2, axis=-1), 1.0, atol=1e-12)
    assert np.linalg.det(m) > 0 or handedness == "left"
    back_p, back_q = rio.from_internal(p2, q2, up, handedness, units)
    np.testing.assert_allclose(back_p, p, atol=1e-12)
    np.testing.assert_allclose(back_q, q, atol=1e-12)  # same sign: tracks stay continuous


@pytest.mark.parametrize("ext", ["bcrec.json", "csv"])
@pytest.mark.parametrize("coords", [("Y", "right", "m"), ("Y", "left", "cm"), ("Z", "left", "mm"), ("Z", "right", "m")])
def test_save_load_round_trip(tmp_path, ext, coords):
    rec = tpose_recording(leds=True, seconds=1.0)
    rec.valid[10:40, 3] = False
    rec.marker_valid[5:30, 2] = False
    rec = rio.finish_recording(rec, fill_gaps_s=0.0)
    written = rio.save_recording(rec, tmp_path / f"rec.{ext}", up=coords[0], handedness=coords[1], units=coords[2])
    assert len(written) == (2 if ext == "csv" else 1)
    back = rio.load_recording(written[0], fill_gaps_s=0.0)
    assert [(d.name, d.kind, d.role) for d in back.devices] == [(d.name, d.kind, d.role) for d in rec.devices]
    assert back.marker_names == rec.marker_names
    np.testing.assert_allclose(back.time, rec.time, atol=1e-9)
    np.testing.assert_array_equal(back.valid, rec.valid)
    np.testing.assert_array_equal(back.marker_valid, rec.marker_valid)
    np.testing.assert_allclose(back.positions, rec.positions, atol=1e-6)
    np.testing.assert_allclose(back.rotations, rec.rotations, atol=1e-6)
    np.testing.assert_allclose(back.markers, rec.markers, atol=1e-6)
    assert [(s.label, s.start, s.end) for s in back.segments] == [(s.label, s.start, s.end) for s in rec.segments]


# ---------------------------------------------------------------------------------------------
# Quaternions


def test_quaternions_renormalised_within_tolerance(tmp_path):
    rec = _load_doc(tmp_path, _one_device_doc([0, 1.6, 0, 1.0008, 0, 0, 0], {}))
    np.testing.assert_allclose(np.linalg.norm(rec.rotations[:, 0], axis=-1), 1.0, atol=1e-12)


@pytest.mark.parametrize("quat, words", [
    ([1.01, 0, 0, 0], "not unit length"),
    ([0, 0, 0, 0], "zero"),
    ([0.5, 0.5, 0.5, 0.4], "not unit length"),
])
def test_bad_quaternions_rejected_with_frame(tmp_path, quat, words):
    doc = _one_device_doc([0, 1.6, 0] + IDENTITY, {}, frames=5)
    doc["poses"]["hmd"][3] = [0, 1.6, 0] + quat
    with pytest.raises(BodyCalError) as info:
        _load_doc(tmp_path, doc)
    msg = str(info.value)
    assert msg.startswith("rec.bcrec.json: poses.hmd: frame 3: quaternion is") and words in msg
    assert "\n" not in msg


# ---------------------------------------------------------------------------------------------
# Validation (JSON)


def _valid_doc():
    return recording_doc(tpose_recording(seconds=0.5, profile="minimal"))


def _mutate(path_keys, value):
    def apply(doc):
        target = doc
        for k in path_keys[:-1]:
            target = target[k]
        if value is _DELETE:
            del target[path_keys[-1]]
        else:
            target[path_keys[-1]] = value
        return doc
    return apply


_DELETE = object()

JSON_CASES = [
    (_mutate(["format"], "other"), ["format", "expected"]),
    (_mutate(["version"], 2), ["version", "unsupported"]),
    (_mutate(["surprise"], 1), ["unknown field", "surprise"]),
    (_mutate(["coords", "up"], "X"), ["coords.up"]),
    (_mutate(["coords", "units"], "inch"), ["coords.units"]),
    (_mutate(["coords", "handedness"], "middle"), ["coords.handedness"]),
    (_mutate(["devices", 1, "kind"], "glove"), ["devices[1].kind", "unknown kind"]),
    (_mutate(["devices", 1, "role"], "tail"), ["devices[1].role", "unknown role"]),
    (_mutate(["devices", 2, "role"], "hand_l"), ["devices[2].role", "hand_l"]),
    (_mutate(["devices", 2, "name"], "head"), ["duplicate device name", "head"]),
    (_mutate(["devices", 0, "color"], "red"), ["devices[0]", "unknown field"]),
    (_mutate(["devices", 0, "name"], _DELETE), ["devices[0].name", "missing"]),
    (_mutate(["time"], _DELETE), ["time", "missing"]),
    (_mutate(["time", 7], 0.01), ["time", "frame 7", "increase"]),
    (_mutate(["time", 4], "soon"), ["time", "frame 4", "not a number"]),
    (_mutate(["poses", "ghost"], []), ["poses", "unknown device", "ghost"]),
    (_mutate(["poses", "pelvis"], _DELETE), ["poses", "no data", "pelvis"]),
    (lambda d: d["poses"]["pelvis"].pop() and d, ["poses.pelvis", "entries", "time has"]),
    (_mutate(["poses", "foot_l", 9], [0, 0, 0, 1, 0, 0]), ["poses.foot_l", "frame 9", "7 numbers"]),
    (_mutate(["poses", "foot_l", 9, 2], "x"), ["poses.foot_l", "frame 9", "not a number"]),
    (_mutate(["poses", "foot_l", 9, 2], None), ["poses.foot_l", "frame 9", "not a number: None"]),
    (_mutate(["poses", "foot_l", 9, 2], float("inf")), ["poses.foot_l", "frame 9", "infinite"]),
    (_mutate(["poses", "foot_l", 9, 2], float("nan")), ["poses.foot_l", "frame 9", "NaN"]),
    (_mutate(["segments", 0, "step"], "dance"), ["segments[0].step", "unknown step"]),
    (_mutate(["segments", 0, "end"], 99.0), ["segments[0]", "outside the recording"]),
    (_mutate(["segments", 0, "start"], 0.4), ["segments[0]", "before it starts"]),
    (_mutate(["segments", 0], {"step": "touch", "start": 0.1, "end": 0.2, "point": "nose"}),
     ["segments[0].point", "unknown touch point"]),
    (_mutate(["segments", 0], {"step": "touch", "start": 0.1, "end": 0.2, "point": "chin", "by": "toe"}),
     ["segments[0].by", "unknown toucher"]),
    (_mutate(["markers"], [{"name": "index_tip_r"}, {"name": "index_tip_r"}]), ["duplicate marker name"]),
    (_mutate(["markers"], [{"name": "head"}]), ["both a device and a marker"]),
    (_mutate(["markers"], [{"name": "index_tip_r"}]), ["points", "no data", "index_tip_r"]),
]


@pytest.mark.parametrize("mutate, words", JSON_CASES, ids=[" ".join(w) for _, w in JSON_CASES])
def test_json_validation_errors_name_file_field_and_frame(tmp_path, mutate, words):
    doc = mutate(_valid_doc())
    with pytest.raises(BodyCalError) as info:
        _load_doc(tmp_path, doc)
    msg = str(info.value)
    assert msg.startswith("rec.bcrec.json"), msg
    for w in words:
        assert w in msg, (w, msg)
    assert "\n" not in msg


def test_unreadable_json_files(tmp_path):
    path = tmp_path / "broken.bcrec.json"
    path.write_text('{"format": "bodycal-recording",\n "version": 1,\n "time": [0, 1')
    with pytest.raises(BodyCalError, match=r"broken.bcrec.json: line 3 column \d+: invalid JSON"):
        rio.load_recording(path)
    path.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(BodyCalError, match="not UTF-8"):
        rio.load_recording(path)
    with pytest.raises(BodyCalError, match="file not found"):
        rio.load_recording(tmp_path / "missing.json")
    with pytest.raises(BodyCalError, match="unknown recording type"):
        (tmp_path / "rec.txt").write_text("x")
        rio.load_recording(tmp_path / "rec.txt")


# ---------------------------------------------------------------------------------------------
# Dropouts and gaps


def test_dropouts_kept_invalid_and_short_gaps_filled(tmp_path):
    doc = _valid_doc()  # 45 frames at 90 Hz
    poses = doc["poses"]["pelvis"]
    truth = np.array(poses, float)
    for k in (10, 11, 12):  # 3 frames: the gap spans 4/90 s < 0.1 s
        poses[k] = None
    for k in range(20, 35):  # 15 frames: 16/90 s > 0.1 s, stays a dropout
        poses[k] = None
    rec = _load_doc(tmp_path, doc)
    i = rec.device_index("pelvis")
    assert rec.valid[10:13, i].all()  # filled
    assert not rec.valid[20:35, i].any() and rec.valid[35:, i].all()
    # Positions on the cubic Hermite curve from frame 9 to 13 at the device's own velocity there
    # (one-frame differences 8->9 and 13->14); rotations unit, near the slerp (the fixture's wobble
    # is a slow yaw: within a degree of it).
    dt = 1 / 90
    v0, v1 = (truth[9, :3] - truth[8, :3]) / dt, (truth[14, :3] - truth[13, :3]) / dt
    for k in (10, 11, 12):
        s = (k - 9) / 4
        h = (2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2)
        want = h[0] * truth[9, :3] + h[1] * 4 * dt * v0 + h[2] * truth[13, :3] + h[3] * 4 * dt * v1
        np.testing.assert_allclose(rec.positions[k, i], want, atol=1e-9)
        assert abs(np.linalg.norm(rec.rotations[k, i]) - 1) < 1e-12
        off = tf.quat_angle(tf.quat_mul(tf.quat_conj(tf.slerp(truth[9, 3:], truth[13, 3:], s)), rec.rotations[k, i]))
        assert np.degrees(off) < 1.0
    # Untracked frames hold the last tracked value (never NaN).
    np.testing.assert_allclose(rec.positions[20:35, i], np.tile(truth[19, :3], (15, 1)))
    assert any("filled 1 gaps" in n and "3 frames" in n for n in rec.notes)
    kept = _load_doc(tmp_path, doc, fill_gaps_s=0.0)
    assert not kept.valid[10:13, i].any()


def test_leading_dropout_takes_first_tracked_value(tmp_path):
    doc = _valid_doc()
    first = doc["poses"]["head"][5]
    for k in range(5):
        doc["poses"]["head"][k] = None
    rec = _load_doc(tmp_path, doc)
    assert not rec.valid[:5, 0].any()
    np.testing.assert_allclose(rec.positions[:5, 0], np.tile(first[:3], (5, 1)))


# ---------------------------------------------------------------------------------------------
# LED hand frames


def test_hand_frames_built_from_leds(tmp_path):
    rec = tpose_recording(leds=True, seconds=1.0, yaw=0.7)
    rec = _load_doc(tmp_path, recording_doc(rec))
    for s, sign in (("l", 1.0), ("r", -1.0)):
        i = rec.device_index(f"hand_{s}")
        d = rec.devices[i]
        assert d.kind == "rigid_body" and d.role == f"hand_{s}"
        leds = [rec.marker(f"hand_led{k}_{s}")[0] for k in (1, 2, 3)]
        np.testing.assert_allclose(rec.positions[:, i], sum(leds) / 3, atol=1e-12)
        q = rec.rotations[:, i]
        y = tf.rotate(q, [0, 1.0, 0])
        z = tf.rotate(q, [0, 0, 1.0])
        np.testing.assert_allclose(y, tf.normalize(leds[1] - leds[0]), atol=1e-9)
        # Z out of the back of the hand: up, for palms down in a T-pose, on both hands.
        assert (z[:, 2] > 0.99).all()
        # Y toward the fingers: away from the body on each side.
        left = np.array([np.cos(0.7), np.sin(0.7), 0])
        assert (sign * (y @ left) > 0.99).all()
    assert sum("from LEDs" in n for n in rec.notes) == 2


def test_led_frame_not_built_when_hand_pose_exists(tmp_path):
    rec = tpose_recording(leds=True, seconds=0.5)
    doc = recording_doc(rec)
    doc["devices"].append({"name": "glove_l", "kind": "rigid_body", "role": "hand_l"})
    doc["poses"]["glove_l"] = [[0, 0, 1, 1, 0, 0, 0]] * len(doc["time"])
    back = _load_doc(tmp_path, doc)
    assert [d.name for d in back.devices if d.role == "hand_l"] == ["glove_l"]
    assert back.has_role("hand_r")


# ---------------------------------------------------------------------------------------------
# CSV


CSV_HEADER = "time,name,px,py,pz,qw,qx,qy,qz\n"


def test_csv_without_sidecar_assumes_defaults(tmp_path):
    path = tmp_path / "take.csv"
    path.write_text(CSV_HEADER + "0.0,hmd,0.1,1.6,-0.3,1,0,0,0\n0.0,index_tip_r,0.1,1.0,0.2,,,,\n"
                    "0.5,hmd,0.1,1.6,-0.3,1,0,0,0\n0.5,index_tip_r,,,,,,,\n")
    rec = rio.load_recording(path)
    assert [(d.name, d.kind, d.role) for d in rec.devices] == [("hmd", "tracker", None)]
    assert rec.marker_names == ["index_tip_r"]
    np.testing.assert_allclose(rec.positions[0, 0], [0.1, 0.3, 1.6])
    np.testing.assert_allclose(rec.markers[0, 0], [0.1, -0.2, 1.0])
    assert rec.marker_valid[:, 0].tolist() == [True, False]
    assert not rec.segments
    assert any("no sidecar" in n for n in rec.notes)


def test_csv_missing_rows_are_dropouts(tmp_path):
    path = tmp_path / "take.csv"
    path.write_text(CSV_HEADER + "0.0,a,0,0,0,1,0,0,0\n0.0,b,0,0,0,1,0,0,0\n1.0,a,0,0,0,1,0,0,0\n"
                    "2.0,a,0,0,0,1,0,0,0\n2.0,b,0,0,0,1,0,0,0\n")
    rec = rio.load_recording(path)
    assert rec.valid[:, 1].tolist() == [True, False, True]


CSV_CASES = [
    ("time,name,px,py\n0,a,0,0\n", "line 1: missing column 'pz'"),
    ("time,name,px,py,pz,qw,qx,qy,qz,speed\n", "line 1: unknown column 'speed'"),
    ("time,name,px,py,pz,qw,qx\n", "line 1: missing column 'qy'"),
    (CSV_HEADER + "0,a,0,0,0,1,0,0,0\n0.1,a,0,zero,0,1,0,0,0\n", "py: line 3: not a number: 'zero'"),
    (CSV_HEADER + "0,a,0,0,0,1,0,0,0\n0.1,a,0,nan,0,1,0,0,0\n", "py: line 3: not a number"),
    (CSV_HEADER + "0,a,0,0,0,1,0,0,0\n0.1,a,0,1e999,0,1,0,0,0\n", "line 3: NaN or infinite"),
    (CSV_HEADER + "0,a,0,0,0,1,0,0,0\n0.2,a,0,0,0,1,0,0,0\n0.1,a,0,0,0,1,0,0,0\n", "time: line 4: time goes back"),
    (CSV_HEADER + "0,a,0,0,0,1,0,0,0\n0,a,0,0,0,1,0,0,0\n", "line 3: second row for 'a'"),
    (CSV_HEADER + "0,a,0,0,0,1,0,0\n", "line 2: 8 fields, the header has 9"),
    (CSV_HEADER + "0,a,0,0,0,1,0,,0\n", "line 2: some fields of the pose are empty"),
    (CSV_HEADER + "0,a,0,0,0,0,0,0,0\n", "poses.a: line 2: quaternion is zero"),
    (CSV_HEADER + "0,a,0,0,0,1,0,0,0\n\n0.1,a,0,0,0,2,0,0,0\n", "poses.a: line 4: quaternion is not unit"),
    (CSV_HEADER + "0,,0,0,0,1,0,0,0\n", "name: line 2: empty name"),
    (CSV_HEADER, "line 2: no data rows"),
    ("", "line 1: empty file"),
]


@pytest.mark.parametrize("text, expected", CSV_CASES, ids=[c[1] for c in CSV_CASES])
def test_csv_validation_errors_name_line(tmp_path, text, expected):
    path = tmp_path / "take.csv"
    path.write_text(text)
    with pytest.raises(BodyCalError) as info:
        rio.load_recording(path)
    msg = str(info.value)
    assert msg.startswith("take.csv: ") and expected in msg, msg


def test_csv_with_sidecar_checks_names_and_kinds(tmp_path):
    rec = tpose_recording(seconds=0.3, profile="minimal", leds=True)
    rio.save_recording(rec, tmp_path / "take.csv")
    text = (tmp_path / "take.csv").read_text()
    (tmp_path / "take.csv").write_text(text.replace(",hand_led1_l,", ",stranger,", 1))
    with pytest.raises(BodyCalError, match=r"take.csv: name: line \d+: unknown name 'stranger'"):
        rio.load_recording(tmp_path / "take.csv")
    lines = text.splitlines()
    k = next(i for i, ln in enumerate(lines) if ",hand_led1_l," in ln)
    lines[k] = lines[k].rstrip(",") + ",1,0,0,0"
    (tmp_path / "take.csv").write_text("\n".join(lines) + "\n")
    with pytest.raises(BodyCalError, match=rf"take.csv: line {k + 1}: marker 'hand_led1_l' has a quaternion"):
        rio.load_recording(tmp_path / "take.csv")
    sidecar = json.loads((tmp_path / "take.json").read_text())
    sidecar["devices"][0]["kind"] = "wand"
    (tmp_path / "take.json").write_text(json.dumps(sidecar))
    (tmp_path / "take.csv").write_text(text)
    with pytest.raises(BodyCalError, match=r"take.json: devices\[0\].kind: unknown kind 'wand'"):
        rio.load_recording(tmp_path / "take.csv")


# ---------------------------------------------------------------------------------------------
# The synthetic performer (bodycal_dev.synthetic) through the readers


def _synthetic_session(**kw):
    from bodycal_dev import synthetic
    perf = synthetic.make_performer(build="average", seed=1)
    return synthetic, synthetic.record_session(perf, calibration=["tpose", "palms_together"], motions=("clap",),
                                               seed=1, **kw)


def test_synthetic_session_round_trip_with_dropouts(tmp_path):
    synthetic, (rec, truth) = _synthetic_session(profile="full", dropout_rate=0.02)
    assert not rec.valid.all()  # dropouts happened
    rec_path, _ = synthetic.write_session(tmp_path, "s", rec, truth)
    back = rio.load_recording(rec_path, fill_gaps_s=0.0)
    assert [(d.name, d.kind, d.role) for d in back.devices] == [(d.name, d.kind, d.role) for d in rec.devices]
    np.testing.assert_array_equal(back.valid, rec.valid)
    np.testing.assert_allclose(back.positions[rec.valid], rec.positions[rec.valid], atol=1e-6)
    same = np.sign((back.rotations * rec.rotations).sum(-1, keepdims=True))
    np.testing.assert_allclose((back.rotations * same)[rec.valid], rec.rotations[rec.valid], atol=1e-6)
    assert [s.label for s in back.segments] == [s.label for s in rec.segments]
    filled = rio.load_recording(rec_path)  # default: gaps under 0.1 s filled
    assert filled.valid.sum() > rec.valid.sum() and any("filled" in n for n in filled.notes)


def test_synthetic_glove_frames_rebuilt_from_leds(tmp_path):
    _synthetic, (rec, _truth) = _synthetic_session(profile="full", noise_mm=0.0, wobble_mm=0.0)
    gloves = [i for i, d in enumerate(rec.devices) if d.role in ("hand_l", "hand_r")]
    keep = [i for i in range(len(rec.devices)) if i not in gloves]
    doc = recording_doc(rec)
    for i in gloves:
        del doc["poses"][rec.devices[i].name]
    doc["devices"] = [doc["devices"][i] for i in keep]
    path = tmp_path / "no_gloves.bcrec.json"
    path.write_text(json.dumps(doc))
    back = rio.load_recording(path)
    for i in gloves:
        role = rec.devices[i].role
        p, q, ok = back.pose(role)
        assert back.devices[back.device_index(role)].kind == "rigid_body" and ok.all()
        np.testing.assert_allclose(p, rec.positions[:, i], atol=1e-9)
        np.testing.assert_allclose(np.degrees(tf.quat_angle(tf.quat_mul(tf.quat_conj(q), rec.rotations[:, i]))), 0,
                                   atol=1e-5)


def test_only_recordings_pass_the_drop_check(tmp_path):
    """A file dropped on Blender is imported only when it is a recording by its look (FORMATS.md
    §2.5): a `*.bcrec.json` or a JSON saying its format, a CSV with a recording's header (with or
    without its sidecar), a C3D with a marker label or a step event BodyCal knows. Anything else
    is one line naming the file, and nothing else is read."""
    from bodycal_dev.c3d_writer import write_c3d

    rec = tpose_recording(seconds=0.5)
    ok = [tmp_path / "take.bcrec.json", tmp_path / "export.json", tmp_path / "take.csv", tmp_path / "bare.csv"]
    ok[0].write_text(json.dumps(recording_doc(rec)))
    ok[1].write_text(json.dumps(recording_doc(rec)))
    rio.save_recording(rec, ok[2])  # + take.json, its sidecar
    ok[3].write_text(" Time, name,px,py,pz\n0.0,index_tip_r,0,1,0\n")
    pts = np.zeros((10, 2, 3))
    ok.append(write_c3d(tmp_path / "gloves.c3d", pts, ["Subject:INDEX_TIP_R", "elbow"], 100.0))
    ok.append(write_c3d(tmp_path / "steps.c3d", pts, ["LASI", "RASI"], 100.0, events=[("tpose", 0.02)]))
    for path in ok:
        rio.check_recording_file(path)
        assert rio.load_recording(path).frame_count > 0, path.name

    refused = {
        "user.body.json": ('{"format": "bodycal-body", "version": 1}', 'no "format": "bodycal-recording"'),
        "take.json": (None, "is the sidecar of take.csv"),
        "sheet.csv": ("subject,height\nann,1.7\n", "its first line is not time,name"),
        "points.csv": ("time,name,px,py\n", "its first line is not time,name"),
        "vicon.c3d": (None, "no marker label BodyCal knows"),
    }
    write_c3d(tmp_path / "vicon.c3d", pts, ["LASI", "RASI"], 100.0, events=[("Foot Strike", 0.02)])
    for name, (text, words) in refused.items():
        if text is not None:
            (tmp_path / name).write_text(text)
        with pytest.raises(BodyCalError) as err:
            rio.check_recording_file(tmp_path / name)
        assert words in err.value.line() and name in err.value.line() and "\n" not in err.value.line()
    with pytest.raises(BodyCalError, match="not a C3D file"):
        (tmp_path / "fake.c3d").write_bytes(b"\0" * 600)
        rio.check_recording_file(tmp_path / "fake.c3d")


def test_the_file_browser_lists_recordings_only():
    """Every .json is listed (an A-Frame motion capture keeps its own name, FORMATS.md §2.6); a JSON
    that is not a recording says so in one line when picked (below)."""
    from fnmatch import fnmatch

    shown = ["take.bcrec.json", "TAKE.BCREC.JSON", "take.csv", "take.c3d", "tracked-recording.json", "replay.bsor"]
    hidden = ["take.blend", "avatar.glb", "notes.txt", "take.bvh"]
    assert all(any(fnmatch(n.lower(), g) for g in rio.RECORDING_GLOBS) for n in shown)
    assert not any(fnmatch(n.lower(), g) for n in hidden for g in rio.RECORDING_GLOBS)


def test_a_json_picked_that_is_not_a_recording_says_so(tmp_path):
    (tmp_path / "user.body.json").write_text('{"format": "bodycal-body", "version": 1, "joints": {}}')
    with pytest.raises(BodyCalError) as err:
        rio.load_recording(tmp_path / "user.body.json")
    assert err.value.line() == ("user.body.json: format: is 'bodycal-body', expected \"bodycal-recording\" "
                                "(not a BodyCal recording)")
