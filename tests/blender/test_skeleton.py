"""The canonical skeleton and the bone maps of the real avatars' naming schemes."""

import json

import addon_utils
import bpy
import numpy as np
import pytest

from bodycal_addon.body import naming
from bodycal_addon.body import skeleton as sk

FACE_PREFIXES = ("face", "lip", "brow", "ear", "nose", "lid", "cheek", "chin", "jaw", "tongue", "teeth",
                 "temple", "forehead", "eye")


def test_every_bone_links_known_joints_and_parents():
    for b in sk.BONES:
        assert b.head in sk.JOINT_INDEX and b.tail in sk.JOINT_INDEX, b
        assert b.parent is None or b.parent in sk.BONE_BY_NAME, b
    assert len(set(sk.JOINTS)) == len(sk.JOINTS)
    # 12 vertebrae from the spine root to the skull base's vertebra, clavicles on the 5th.
    assert sk.BONE_BY_NAME["spine_01"].head == "spine_root"
    assert sk.BONE_BY_NAME["spine_12"].tail == "spine_12"
    assert sk.BONE_BY_NAME["clavicle_l"].head == "spine_05"
    assert {b.name for b in sk.BONES if b.hinge} >= {"forearm_l", "shin_r", "index_2_l", "thumb_3_r"}


@pytest.mark.parametrize("variant", ["adult_male", "adult_female", "child_10y", "heavy_belly_male",
                                     "long_arms_male"])
def test_unreal_style_avatars_map_every_body_bone(data_dir, variant):
    bones = json.loads((data_dir / "avatars" / "mpfb2_variants" / f"{variant}.skeleton.json").read_text())["bones"]
    bm = naming.detect_bone_map(list(bones))
    assert bm.scheme == "unreal"
    assert bm.unmapped == []
    assert bm.missing(with_fingers=True) == []
    assert bm.chains["spine"] == ["spine_01", "spine_02", "spine_03"]
    assert bm.chains["neck"] == ["neck_01"]
    assert bm.bones["shin_l"] == "calf_l" and bm.bones["forearm_r"] == "lowerarm_r"
    assert bm.bones["index_3_r"] == "index_03_r"
    # Every bone maps to exactly one segment.
    mapped = list(bm.bones.values()) + [b for chain in bm.chains.values() for b in chain]
    assert sorted(mapped) == sorted(bones)


def test_rigify_human_metarig_maps_every_body_bone():
    addon_utils.enable("rigify", default_set=True)
    bpy.ops.object.armature_human_metarig_add()
    names = [b.name for b in bpy.context.active_object.data.bones]
    body = [n for n in names if not n.startswith(FACE_PREFIXES)]
    assert len(body) == 67
    bm = naming.detect_bone_map(body)
    assert bm.scheme == "rigify_metarig"
    assert bm.unmapped == []
    assert bm.missing(with_fingers=True) == []
    assert bm.bones["pelvis"] == "spine" and bm.bones["head"] == "spine.006"
    assert bm.chains["spine"] == ["spine.001", "spine.002", "spine.003"]
    assert bm.chains["neck"] == ["spine.004", "spine.005"]
    assert bm.bones["clavicle_l"] == "shoulder.L" and bm.bones["pinky_3_r"] == "f_pinky.03.R"


def test_mixamo_and_vrm_names_map():
    mixamo = ["mixamorig:Hips", "mixamorig:Spine", "mixamorig:Spine1", "mixamorig:Spine2", "mixamorig:Neck",
              "mixamorig:Head"]
    vrm = ["hips", "spine", "chest", "upperChest", "neck", "head"]
    for s in ("Left", "Right"):
        mixamo += [f"mixamorig:{s}{b}" for b in ("Shoulder", "Arm", "ForeArm", "Hand", "UpLeg", "Leg", "Foot")]
        low = s.lower()
        vrm += [f"{low}{b}" for b in ("Shoulder", "UpperArm", "LowerArm", "Hand", "UpperLeg", "LowerLeg", "Foot")]
        vrm += [f"{low}Thumb{p}" for p in ("Metacarpal", "Proximal", "Distal")]
    m = naming.detect_bone_map(mixamo)
    assert m.scheme == "mixamo" and m.unmapped == [] and m.missing() == []
    assert m.chains["spine"] == ["mixamorig:Spine", "mixamorig:Spine1", "mixamorig:Spine2"]
    v = naming.detect_bone_map(vrm)
    assert v.scheme == "vrm_humanoid" and v.unmapped == [] and v.missing() == []
    assert v.chains["spine"] == ["spine", "chest", "upperChest"]
    assert v.bones["thumb_1_l"] == "leftThumbMetacarpal" and v.bones["thumb_3_r"] == "rightThumbDistal"


def test_missing_bones_are_listed():
    bm = naming.detect_bone_map(["pelvis", "spine_01", "head", "upperarm_l", "lowerarm_l"])
    missing = bm.missing()
    assert "hand_l" in missing and "thigh_r" in missing and "upperarm_l" not in missing


def test_resample_polyline_equal_arc_length_vectorised():
    rng = np.random.default_rng(3)
    pts = np.cumsum(rng.uniform(0.05, 0.2, size=(7, 4, 3)), axis=1)  # 7 frames of a 3-bone chain
    out = sk.resample_polyline(pts, 12)
    assert out.shape == (7, 13, 3)
    np.testing.assert_allclose(out[:, 0], pts[:, 0])
    np.testing.assert_allclose(out[:, -1], pts[:, -1])
    for f in range(7):  # reference: the same resampling with np.interp on one polyline
        np.testing.assert_allclose(out[f], sk.resample_polyline(pts[f], 12), atol=1e-12)
    seg = np.linalg.norm(np.diff(pts[0], axis=0), axis=1)
    arc = np.concatenate([[0], np.cumsum(seg)])
    t = np.linspace(0, arc[-1], 13)
    np.testing.assert_allclose(out[0, :, 1], np.interp(t, arc, pts[0, :, 1]))
