"""Bone map presets (FORMATS.md §5): the file format, its checks (one line naming the file and the
field), resolving a preset on an armature's bones, the round trip of a whole map, and batch jobs'
`bone_map`."""

from __future__ import annotations

import json
import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_naming_schemes import CASES, character_creator, cmu_mb, daz_genesis8

from bodycal_addon.app import batch
from bodycal_addon.body import bone_presets as bp
from bodycal_addon.body import naming
from bodycal_addon.core.errors import BodyCalError

GOOD = {"format": "bodycal-bone-map", "version": 1, "name": "Ogre",
        "bones": {"pelvis": "Hips_jnt", "head": "Head_jnt", "toe_l": None},
        "chains": {"spine": ["Spine_jnt", "Chest_jnt"], "neck": []}}


def _chains(bm: naming.BoneMap) -> dict:
    return {k: v for k, v in bm.chains.items() if v}


@pytest.mark.parametrize("case", sorted(CASES))
def test_a_whole_map_round_trips_through_a_preset_file(tmp_path, case):
    """Export then import gives the same map, on the bones in any order, whatever detection says."""
    names = CASES[case][0]
    bm = naming.detect_bone_map(names)
    path = bp.preset_from_bone_map(bm, case).save(tmp_path / f"{case}.json")
    back = bp.load_preset(path)
    assert back.scheme is None and back.name == case
    shuffled = list(names)
    random.Random(7).shuffle(shuffled)
    again = back.resolve(shuffled)
    assert again.bones == bm.bones
    assert _chains(again) == _chains(bm)
    assert set(again.unmapped) == set(bm.unmapped)


def test_a_scheme_preset_forces_that_scheme():
    """The CMU rig is detected as cmu_mb (LowerBack in the spine); the Mixamo preset maps it the
    Mixamo way, LowerBack left out."""
    names = cmu_mb()
    assert naming.detect_bone_map(names).chains["spine"][0] == "LowerBack"
    (mixamo,) = [p for p in bp.builtin_presets() if p.scheme == "mixamo"]
    bm = mixamo.resolve(names)
    assert bm.scheme == "mixamo"
    assert bm.chains["spine"] == ["Spine", "Spine1"] and "LowerBack" in bm.unmapped
    assert {p.scheme for p in bp.builtin_presets()} == set(naming.SCHEME_BY_NAME)


def test_a_preset_over_a_scheme_replaces_its_choices():
    preset = bp.parse_preset({"format": "bodycal-bone-map", "version": 1, "scheme": "daz_genesis8",
                              "bones": {"toe_l": None, "head": "neckUpper", "upperarm_l": "lShldrTwist",
                                        "shin_r": "rThighBend"}})
    bm = preset.resolve(daz_genesis8())
    assert "toe_l" not in bm.bones and "lToe" in bm.unmapped
    assert bm.bones["head"] == "neckUpper" and bm.chains["neck"] == ["neckLower"]  # moved out of the chain
    assert bm.bones["upperarm_l"] == "lShldrTwist" and "lShldrBend" in bm.unmapped
    assert bm.bones["shin_r"] == "rThighBend" and "thigh_r" not in bm.bones  # taken from the scheme's thigh
    assert bm.bones["thigh_l"] == "lThighBend"  # the scheme's choice elsewhere
    assert bm.scheme == "daz_genesis8+preset"


def test_a_preset_without_scheme_maps_only_what_it_lists():
    bm = bp.parse_preset(GOOD, "ogre.json").resolve(["Hips_jnt", "Head_jnt", "Spine_jnt", "Chest_jnt", "Tail"])
    assert bm.bones == {"pelvis": "Hips_jnt", "head": "Head_jnt"}
    assert bm.chains == {"spine": ["Spine_jnt", "Chest_jnt"], "neck": []}
    assert bm.unmapped == ["Tail"]
    assert "thigh_l" in bm.missing()


def _bad(**changes) -> dict:
    data = json.loads(json.dumps(GOOD))
    for key, value in changes.items():
        if value is ...:
            del data[key]
        else:
            data[key] = value
    return data


BAD = [
    ("not an object", ["a", "list"], None, "JSON object"),
    ("wrong format", _bad(format="keemap"), "format", "bodycal-bone-map"),
    ("no format", _bad(format=...), "format", "bodycal-bone-map"),
    ("future version", _bad(version=2), "version", "not supported"),
    ("version true", _bad(version=True), "version", "not supported"),
    ("unknown key", _bad(bone={"pelvis": "Hips"}), "bone", "unknown key 'bone' (did you mean 'bones'?)"),
    ("unknown segment", _bad(bones={"upper_arm_l": "L_Arm"}), "bones.upper_arm_l",
     "unknown segment 'upper_arm_l' (did you mean 'upperarm_l'?)"),
    ("chain as a bone", _bad(bones={"spine": "Spine_jnt"}), "bones.spine", "under \"chains\""),
    ("unknown chain", _bad(chains={"tail": ["Tail"]}), "chains.tail", "unknown chain"),
    ("chain not a list", _bad(chains={"spine": "Spine_jnt"}), "chains.spine", "list of bone names"),
    ("bone not text", _bad(bones={"pelvis": 3}), "bones.pelvis", "bone name"),
    ("bone with a newline", _bad(bones={"pelvis": "Hips\nX"}), "bones.pelvis", "control character"),
    ("bones not an object", _bad(bones=["Hips"]), "bones", "object"),
    ("one bone twice", _bad(bones={"pelvis": "Hips_jnt", "head": "Hips_jnt"}), "bones.head", "given to bones.pelvis"),
    ("bone also in a chain", _bad(bones={"pelvis": "Spine_jnt"}), "chains.spine[0]", "given to bones.pelvis"),
    ("unknown scheme", _bad(scheme="mixamo2"), "scheme", "unknown naming scheme 'mixamo2' (did you mean 'mixamo'?)"),
    ("maps nothing", _bad(bones={}, chains={}), None, "maps no bone"),
]


@pytest.mark.parametrize("what,data,field,words", BAD, ids=[b[0] for b in BAD])
def test_each_bad_preset_is_one_line_naming_the_file_and_field(what, data, field, words):
    with pytest.raises(BodyCalError) as exc:
        bp.parse_preset(data, "ogre.json")
    line = str(exc.value)
    assert "\n" not in line and line.startswith("ogre.json: ")
    if field:
        assert f"ogre.json: {field}: " in line
    assert words in line


def test_a_bone_the_armature_lacks_is_one_line_with_the_nearest_name():
    preset = bp.parse_preset(GOOD, "ogre.json")
    with pytest.raises(BodyCalError) as exc:
        preset.resolve(["Hip_jnt", "Head_jnt", "Spine_jnt", "Chest_jnt"])
    assert str(exc.value) == ("ogre.json: bones.pelvis: the armature has no bone 'Hips_jnt' "
                              "(did you mean 'Hip_jnt'?)")


@pytest.mark.parametrize("content,words", [
    (b"{\"format\": ", "not valid JSON (Expecting value at line 1 column 12)"),
    (b"\xff\xfe\x00garbage", "not valid JSON (not UTF-8 text)"),
    (b"[" * 100000, "nested too deeply"),
    (b" " * (bp.MAX_BYTES + 1), "larger than"),
])
def test_a_file_that_is_not_a_preset_is_one_line(tmp_path, content, words):
    path = tmp_path / "broken.json"
    path.write_bytes(content)
    with pytest.raises(BodyCalError) as exc:
        bp.load_preset(path)
    assert words in str(exc.value) and str(path) in str(exc.value) and "\n" not in str(exc.value)


def test_missing_file_and_folder_are_one_line(tmp_path):
    for path, words in ((tmp_path / "nope.json", "no such file"), (tmp_path, "is a folder")):
        with pytest.raises(BodyCalError, match=words):
            bp.load_preset(path)


def test_the_name_defaults_to_the_file_name(tmp_path):
    data = _bad(name=...)
    path = tmp_path / "ogre.bonemap.json"
    path.write_text(json.dumps(data))
    assert bp.load_preset(path).name == "ogre"


json_values = st.recursive(st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=8),
                           lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner,
                                                                                         max_size=4), max_leaves=12)


@settings(max_examples=150, deadline=None)
@given(key=st.sampled_from([*bp.KEYS, "extra"]), value=json_values,
       segment=st.sampled_from([*bp.SINGLE_SEGMENTS, "spine", "neck", "nope"]), bone=json_values)
def test_any_json_is_a_preset_or_one_line(key, value, segment, bone):
    data = _bad(**{key: value})
    if isinstance(data.get("bones"), dict):
        data["bones"][segment] = bone
    try:
        preset = bp.parse_preset(data, "fuzz.json")
    except BodyCalError as exc:
        assert "\n" not in str(exc) and str(exc).startswith("fuzz.json")
        return
    assert preset.to_dict()["format"] == bp.FORMAT
    assert bp.parse_preset(json.loads(preset.to_json()), "again.json").to_dict() == preset.to_dict()


# --- batch jobs' bone_map -------------------------------------------------------------------------

def _jobs(tmp_path, avatar_extra: str) -> object:
    (tmp_path / "jobs.toml").write_text(
        '[[recordings]]\npath = "take.bcrec.json"\nuser = "me.body.json"\n\n'
        f'[[avatars]]\nblend = "ogre.blend"\n{avatar_extra}\n')
    return tmp_path / "jobs.toml"


def test_a_jobs_bone_map_reaches_the_command_line(tmp_path):
    bp.preset_from_bone_map(naming.detect_bone_map(character_creator()), "cc").save(tmp_path / "cc.json")
    jobs, _settings = batch.load_jobs(_jobs(tmp_path, 'bone_map = "cc.json"'))
    (job,) = jobs
    argv = job.argv()
    assert argv[argv.index("--bone-map") + 1] == str(tmp_path / "cc.json")
    jobs, _settings = batch.load_jobs(_jobs(tmp_path, ""))
    assert "--bone-map" not in jobs[0].argv()


@pytest.mark.parametrize("content,words", [
    (None, "no such file"),
    ('{"format": "bodycal-bone-map", "version": 1, "bones": {"hips": "Hips"}}', "unknown segment 'hips'"),
    ("{", "not valid JSON"),
])
def test_a_bad_jobs_bone_map_is_one_line_before_any_job(tmp_path, content, words):
    if content is not None:
        (tmp_path / "map.json").write_text(content)
    with pytest.raises(BodyCalError) as exc:
        batch.load_jobs(_jobs(tmp_path, 'bone_map = "map.json"'))
    line = str(exc.value)
    assert "jobs.toml: avatars[0].bone_map: " in line and words in line and "\n" not in line


def test_the_formats_example_is_a_valid_preset():
    """FORMATS.md §5's example parses, and says what the table says."""
    import pathlib
    import re

    text = (pathlib.Path(__file__).resolve().parents[2] / "docs" / "FORMATS.md").read_text()
    section = text[text.index("## 5. Bone map presets"):]
    example = json.loads(re.search(r"```json\n(.*?)\n```", section, re.S).group(1))
    preset = bp.parse_preset(example, "FORMATS.md")
    assert preset.scheme == "mixamo" and preset.bones["toe_l"] is None
    assert preset.chains["spine"] == ["Ogre_Spine", "Ogre_Spine1", "Ogre_Chest"]
    for scheme in naming.SCHEME_BY_NAME:  # every scheme is listed in the section
        assert f"`{scheme}`" in section, scheme
