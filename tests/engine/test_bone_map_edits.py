"""Editing the bone map an armature keeps (detection plus the user's overrides, one segment at a
time, as the panel's bone map editor does): what an edit stores, what it refuses (one line,
nothing changed), and that no sequence of edits can leave a bone on two segments."""

from __future__ import annotations

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from test_naming_schemes import ue4_mannequin

from bodycal_addon.body import bone_presets as bp
from bodycal_addon.body import naming
from bodycal_addon.body import skeleton as sk
from bodycal_addon.core.errors import BodyCalError

NAMES = ue4_mannequin() + ["lowerarm_twist_01_l"]


def _line(call) -> str:
    with pytest.raises(BodyCalError) as exc:
        call()
    line = str(exc.value)
    assert "\n" not in line
    return line


def test_without_overrides_the_map_is_detection():
    assert bp.map_with_overrides(NAMES, {}) == naming.detect_bone_map(NAMES)


def test_an_edit_stores_one_segment_and_detection_keeps_the_rest():
    ov = bp.edit_overrides(NAMES, {}, "forearm_l", "lowerarm_twist_01_l")
    assert ov == {"forearm_l": "lowerarm_twist_01_l"}
    bm = bp.map_with_overrides(NAMES, ov)
    assert bm.bones["forearm_l"] == "lowerarm_twist_01_l" and bm.bones["forearm_r"] == "lowerarm_r"
    assert "lowerarm_l" in bm.unmapped and bm.scheme == "unreal+custom"
    assert bp.segment_value(bm, "forearm_l") == "lowerarm_twist_01_l"
    # "" unmaps, None gives the segment back to detection
    ov = bp.edit_overrides(NAMES, ov, "toe_l", "")
    assert "toe_l" not in bp.map_with_overrides(NAMES, ov).bones
    ov = bp.edit_overrides(NAMES, ov, "forearm_l", None)
    assert ov == {"toe_l": ""} and bp.map_with_overrides(NAMES, ov).bones["forearm_l"] == "lowerarm_l"


def test_a_chain_is_its_list_bottom_up():
    ov = bp.edit_overrides(NAMES, {}, "spine", " spine_01,spine_02 ")
    bm = bp.map_with_overrides(NAMES, ov)
    assert bm.chains["spine"] == ["spine_01", "spine_02"] and "spine_03" in bm.unmapped
    assert bp.segment_value(bm, "spine") == "spine_01, spine_02"
    assert bp.edit_overrides(NAMES, {}, "spine", "")["spine"] == "" and \
        bp.map_with_overrides(NAMES, {"spine": ""}).missing() == ["spine"]


def test_a_bone_the_armature_lacks_is_one_line_with_the_nearest_name():
    line = _line(lambda: bp.edit_overrides(NAMES, {}, "forearm_l", "lowerarmm_l", source="Ogre"))
    assert line == "Ogre: forearm_l: the armature has no bone 'lowerarmm_l' (did you mean 'lowerarm_l'?)"
    assert "no bone 'chest'" in _line(lambda: bp.edit_overrides(NAMES, {}, "spine", "spine_01, chest"))
    assert "unknown segment 'forarm_l' (did you mean 'forearm_l'?)" in \
        _line(lambda: bp.edit_overrides(NAMES, {}, "forarm_l", "lowerarm_l"))


def test_a_bone_on_two_segments_is_one_line_naming_both():
    line = _line(lambda: bp.edit_overrides(NAMES, {}, "hand_l", "lowerarm_l", source="Ogre"))
    assert line == ("Ogre: bone 'lowerarm_l' is given to forearm_l and hand_l (a bone can serve one segment "
                    "only: clear forearm_l first, or pick another bone)")
    assert "given to head and spine[2]" in _line(lambda: bp.edit_overrides(NAMES, {}, "spine",
                                                                           "spine_01, spine_02, head"))
    assert "given to spine[0] and spine[1]" in _line(lambda: bp.edit_overrides(NAMES, {}, "spine",
                                                                              "spine_01, spine_01"))
    # the way to move a bone: clear where it is, then give it
    ov = bp.edit_overrides(NAMES, bp.edit_overrides(NAMES, {}, "forearm_l", ""), "hand_l", "lowerarm_l")
    assert bp.map_with_overrides(NAMES, ov).bones["hand_l"] == "lowerarm_l"
    # giving a segment back to detection is checked too
    assert "given to hand_l and forearm_l" in _line(lambda: bp.edit_overrides(NAMES, ov, "forearm_l", None))


def test_a_clash_already_there_does_not_block_other_edits_but_is_the_maps_problem():
    clashing = {"hand_l": "lowerarm_l"}  # stored before edits were checked
    assert "given to forearm_l and hand_l" in _line(lambda: bp.check_overrides(NAMES, clashing, "Ogre"))
    ov = bp.edit_overrides(NAMES, clashing, "toe_r", "")
    assert ov == {"hand_l": "lowerarm_l", "toe_r": ""}
    fixed = bp.edit_overrides(NAMES, ov, "hand_l", "hand_l")
    bp.check_overrides(NAMES, fixed)
    renamed = [n for n in NAMES if n != "hand_l"] + ["hand_left"]
    line = _line(lambda: bp.check_overrides(renamed, fixed, "Ogre"))
    assert line.startswith("Ogre: hand_l: the armature has no bone 'hand_l' (did you mean ")


_SEGMENTS = st.sampled_from(sk.SEGMENTS)
_VALUES = st.none() | st.just("") | st.sampled_from(NAMES) | \
    st.lists(st.sampled_from(NAMES), min_size=1, max_size=3).map(", ".join)


@settings(max_examples=200, deadline=None)
@given(edits=st.lists(st.tuples(_SEGMENTS, _VALUES), min_size=1, max_size=12))
def test_no_sequence_of_edits_puts_a_bone_on_two_segments(edits):
    ov: dict[str, str] = {}
    for segment, value in edits:
        try:
            after = bp.edit_overrides(NAMES, ov, segment, value)
        except BodyCalError as exc:
            assert "\n" not in str(exc)
            continue
        ov = after
        bm = bp.map_with_overrides(NAMES, ov)
        bp.check_overrides(NAMES, ov)  # every bone there, each on one segment
        if value is not None and segment not in sk.CHAIN_SEGMENTS:
            assert bm.bones.get(segment, "") == value
        used = [*bm.bones.values(), *(b for c in bm.chains.values() for b in c)]
        assert len(used) == len(set(used)) and set(used) <= set(NAMES)
