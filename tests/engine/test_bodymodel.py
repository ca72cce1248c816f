"""The body model schema of FORMATS.md §3: round trip and clear errors."""

import json

import numpy as np
import pytest

from bodycal_addon.body.bodymodel import BodyModel, BoneInfo, Joint, Offset, SurfaceElement, SurfacePoint
from bodycal_addon.core.errors import BodyCalError

EXAMPLE = {
    "format": "bodycal-body", "version": 1, "kind": "user", "name": "session-2026-11-22", "reference_time": 1.25,
    "joints": {"shoulder_l": {"world": [0.18, 0.02, 1.42], "frame": "upperarm_l", "local": [0.0, -0.03, 0.11]}},
    "bones": {"forearm_l": {"head": "elbow_l", "tail": "wrist_l", "length": 0.26, "right": [1, 0, 0],
                            "radius_head": 0.045, "radius_tail": 0.03}},
    "surface": [
        {"id": "capsule:forearm_l", "type": "capsule", "bone": "forearm_l"},
        {"id": "sphere:skull", "type": "sphere", "bone": "head", "center": [0, 0.02, 0.09], "radius": 0.095},
        {"id": "mesh:torso", "type": "mesh", "bone": "spine_*",
         "points": {"chest_l": {"bone": "spine_09", "local": [0.1, -0.12, 0.0]},
                    "sternum": {"bone": "spine_09", "local": [0.0, -0.12, 0.0]},
                    "belly_ul": {"bone": "spine_04", "local": [0.1, -0.15, 0.0]}},
         "triangles": [["sternum", "chest_l", "belly_ul"]]},
    ],
    "calibration": {"steps_used": ["tpose", "swing_shoulder_l"], "defaulted": {}, "missing": [],
                    "quality": {"swing_shoulder_l": {"rms_mm": 2.1, "kept": 141, "of": 150}}},
    "producer_note": "kept",
}


def test_formats_example_round_trips(tmp_path):
    model = BodyModel.from_dict(EXAMPLE)
    assert model.joints["shoulder_l"].frame == "upperarm_l"
    assert model.bones["forearm_l"].radius_tail == 0.03
    assert model.element("sphere:skull").radius == 0.095
    path = model.save(tmp_path / "user.body.json")
    again = json.loads(path.read_text())
    assert again == EXAMPLE


def test_built_model_with_offsets_saves_and_loads(tmp_path):
    m = BodyModel("avatar", "procedural")
    m.joints["wrist_l"] = Joint(np.array([0.7, 0, 1.4]), "lowerarm_l", np.array([0, 0.25, 0]))
    m.joints["elbow_l"] = Joint(np.array([0.45, 0, 1.4]), "forearm_l", np.array([0, 0.01, 0]),
                                {"upperarm_l": np.array([0.0, 0.27, 0.01])})
    m.bones["forearm_l"] = BoneInfo("elbow_l", "wrist_l", 0.25, np.array([0, 0, 1.0]), 0.04, 0.035)
    m.surface.append(SurfaceElement("mesh:palm_l", "mesh", "hand_l",
                                    points={"a": SurfacePoint("hand_l", np.zeros(3))}))
    m.offsets["ankle_l"] = Offset("foot_l", np.array([0, 0.02, -0.05]), np.array([1.0, 0, 0, 0]),
                                  np.array([0.0, 1, 0, 0]))
    back = BodyModel.load(m.save(tmp_path / "a.body.json"))
    np.testing.assert_allclose(back.world("wrist_l"), [0.7, 0, 1.4])
    assert list(back.joints["elbow_l"].frames) == ["forearm_l", "upperarm_l"]
    np.testing.assert_allclose(back.joints["elbow_l"].frames["upperarm_l"], [0, 0.27, 0.01])
    np.testing.assert_allclose(back.offsets["ankle_l"].r0_joint, [0, 1, 0, 0])
    assert back.element("mesh:palm_l").points["a"].bone == "hand_l"


@pytest.mark.parametrize("mutate, field", [
    (lambda d: d.update(format="other"), "format"),
    (lambda d: d.update(kind="robot"), "kind"),
    (lambda d: d["joints"]["shoulder_l"].update(world=[0, "x", 1]), "joints.shoulder_l.world"),
    (lambda d: d["joints"]["shoulder_l"].update(world=[0, float("nan"), 1]), "joints.shoulder_l.world"),
    (lambda d: d["bones"]["forearm_l"].pop("length"), "bones.forearm_l"),
    (lambda d: d["surface"][2].update(triangles=[["sternum", "nope", "chest_l"]]), "surface[2].triangles"),
    (lambda d: d["surface"][0].update(type="cube"), "surface[0].type"),
    (lambda d: d["surface"][0].update(axis_head=[0, 0.01]), "surface[0].axis_head"),
])
def test_bad_body_models_name_the_field(mutate, field):
    data = json.loads(json.dumps(EXAMPLE))
    mutate(data)
    with pytest.raises(BodyCalError) as err:
        BodyModel.from_dict(data, source="x.body.json")
    assert f"x.body.json: {field}" in str(err.value)


def test_unreadable_file_is_one_clear_line(tmp_path):
    bad = tmp_path / "bad.body.json"
    bad.write_text("{not json")
    with pytest.raises(BodyCalError) as err:
        BodyModel.load(bad)
    assert "not valid JSON" in str(err.value) and "\n" not in str(err.value)


def test_capsule_axis_offsets_round_trip(tmp_path):
    data = json.loads(json.dumps(EXAMPLE))
    model = BodyModel.from_dict(data)
    cap = model.element("capsule:forearm_l")
    np.testing.assert_allclose(cap.axis_offsets(), 0.0)  # absent: the axis runs joint to joint
    cap.set_axis_offsets([0.001, 0.0, -0.02], [0.0, 0.0, -0.015])
    back = BodyModel.load(model.save(tmp_path / "m.body.json"))
    np.testing.assert_allclose(back.element("capsule:forearm_l").axis_offsets(), [[0.001, 0, -0.02], [0, 0, -0.015]])


def test_exact_json_carries_every_float_as_it_is_and_files_keep_seven_decimals():
    """What a live worker process is sent (live/worker.py): a model made in memory (not to
    7 decimals) read back from its exact JSON has every number bit for bit; a file still rounds."""
    data = json.loads(json.dumps(EXAMPLE))
    model = BodyModel.from_dict(data)
    third = np.array([1 / 3, 2 / 3, -1 / 7])
    model.joints["shoulder_l"].world = third.copy()
    model.bones["forearm_l"].length = 0.26 + 1e-12
    model.element("sphere:skull").center = third / 10
    model.offsets["hip_l"] = Offset("pelvis", third, np.array([1, 1e-9, 0, 0.0]), np.array([0.6, 0.8, 0, 1 / 3]))
    model.reference_time = 1 / 3
    back = BodyModel.from_dict(json.loads(model.to_json(exact=True)), exact=True)
    assert back.joints["shoulder_l"].world.tolist() == third.tolist()
    assert back.bones["forearm_l"].length == 0.26 + 1e-12 and back.reference_time == 1 / 3
    assert back.element("sphere:skull").center.tolist() == (third / 10).tolist()
    assert back.offsets["hip_l"].r0_joint.tolist() == [0.6, 0.8, 0, 1 / 3]
    assert back.to_json(exact=True) == model.to_json(exact=True)
    filed = BodyModel.from_dict(json.loads(model.to_json()))  # a file's precision: 7 decimals (6 for the time)
    assert filed.joints["shoulder_l"].world.tolist() == [0.3333333, 0.6666667, -0.1428571]
    assert filed.bones["forearm_l"].length == 0.26 and filed.reference_time == 0.333333


# Every bad body.json gets one line naming the file and the field (FORMATS.md §3).

@pytest.mark.parametrize("mutate, field, words", [
    (lambda d: d["bones"]["forearm_l"].update(length=0), "bones.forearm_l.length", "positive length"),
    (lambda d: d["bones"]["forearm_l"].update(length=-0.26), "bones.forearm_l.length", "positive length"),
    (lambda d: d["bones"]["forearm_l"].update(length=True), "bones.forearm_l.length", "finite number"),
    (lambda d: d["bones"]["forearm_l"].update(length="0.26"), "bones.forearm_l.length", "finite number"),
    (lambda d: d["bones"]["forearm_l"].update(radius_tail=-0.03), "bones.forearm_l.radius_tail", "radius"),
    (lambda d: d["joints"]["shoulder_l"].update(world=[0, True, 1]), "joints.shoulder_l.world", "3 numbers"),
    (lambda d: d["joints"]["shoulder_l"].update(world=["0.18", "0.02", "1.42"]), "joints.shoulder_l.world",
     "3 numbers"),
    (lambda d: d["joints"]["shoulder_l"].update(world=[1e308, 0, 1]), "joints.shoulder_l.world", "below 10000"),
    (lambda d: d.update(tpose={"head": [0, 0, 1.6, 1, 0, 0, float("nan")]}), "tpose.head[6]", "not a finite"),
    (lambda d: d.update(eye_height=float("inf")), "eye_height", "not a finite"),
    (lambda d: d["calibration"]["quality"]["swing_shoulder_l"].update(rms_mm=float("nan")),
     "calibration.quality.swing_shoulder_l.rms_mm", "not a finite"),
])
def test_lax_values_refused_naming_file_and_field(mutate, field, words):
    data = json.loads(json.dumps(EXAMPLE))
    mutate(data)
    with pytest.raises(BodyCalError) as err:
        BodyModel.from_dict(data, source="x.body.json")
    text = str(err.value)
    assert text.startswith(f"x.body.json: {field}: ") and words in text and "\n" not in text, text


@pytest.mark.parametrize("blob, words", [
    (b"BLENDER-v405RENDH\x00\x00\x00" + bytes(range(256)), "is a .blend file"),
    (b"\x28\xb5\x2f\xfd" + bytes(range(256)), "is a .blend file"),  # zstd-compressed .blend
    ("{\"name\": \"caf\u00e9\"}".encode("latin-1"), "not UTF-8 text (byte 13)"),
    (b"[" * 100_000 + b"]" * 100_000, "nested too deeply"),
    (b'{"format": "bodycal-body", "version": 1, "kind": "user", "x": ' + b"[" * 500 + b"]" * 500 + b"}",
     "x" + "[0]" * 64 + ": nested more than 64 levels deep"),
    (b'{"format": "bodycal-body", "version": 1, "kind": "user", "reference_time": NaN}',
     "reference_time: nan is not a finite number"),
])
def test_unreadable_body_files_are_one_line(tmp_path, blob, words):
    path = tmp_path / "u.body.json"
    path.write_bytes(blob)
    with pytest.raises(BodyCalError) as err:
        BodyModel.load(path)
    text = str(err.value)
    assert text.startswith(str(path)) and words in text and "\n" not in text, text


def test_cli_retarget_with_a_random_bytes_body_is_one_line(tmp_path):
    # End to end: exit 2 and exactly one line on stderr, naming the body file.
    import subprocess
    import sys

    from recording_fixtures import tpose_recording
    from repo_paths import REPO

    from bodycal_addon.recording import io as rio

    rec = rio.save_recording(tpose_recording(seconds=0.5), tmp_path / "rec.bcrec.json")[0]
    body = tmp_path / "user.body.json"
    body.write_bytes(np.random.default_rng(13).integers(0, 256, 3000, dtype=np.uint8).tobytes())
    out = subprocess.run([sys.executable, "-m", "bodycal_addon", "retarget", str(rec), "--user", str(body),
                          "--avatar", str(tmp_path / "avatar.blend"), "-o", str(tmp_path / "out.blend")],
                         cwd=REPO, capture_output=True, text=True, timeout=300)
    assert out.returncode == 2, out.stderr
    lines = out.stderr.splitlines()
    assert len(lines) == 1 and str(body) in lines[0] and "not a body model" in lines[0], out.stderr
