"""Bone naming schemes (naming.SCHEMES): each convention's real bone names, extra bones
included (twist, IK, corrective, facial, hair, breast, toes), detected with no manual step; the
required segments land on the right bones and the extras stay unmapped. The name lists come from
the tools that make these rigs (sources in body/naming.py's comments):
the VRM add-on for Blender's human bone mappers and humanoid template, MPFB2's rig definitions,
the Diffeomorphic Daz importer's and DazToUnreal's rename tables, a Character Creator skeleton,
Unreal's MetaHuman / Manny bone lists, Unity's HumanTrait.BoneName."""

from __future__ import annotations

import random

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bodycal_addon.body import naming
from bodycal_addon.body import skeleton as sk

SIDES = {"l": ("L", "Left", "left", "l"), "r": ("R", "Right", "right", "r")}


# --- the name lists, per convention --------------------------------------------------------------

def ue5_manny() -> list[str]:
    names = ["root", "pelvis", *[f"spine_0{k}" for k in range(1, 6)], "neck_01", "neck_02", "head",
             "ik_foot_root", "ik_foot_l", "ik_foot_r", "ik_hand_root", "ik_hand_gun", "ik_hand_l", "ik_hand_r",
             "interaction", "center_of_mass", "spine_04_latissimus_l", "spine_04_latissimus_r"]
    for s in ("l", "r"):
        names += [f"{b}_{s}" for b in (
            "clavicle", "clavicle_out", "clavicle_scap", "clavicle_pec", "upperarm", "upperarm_twist_01",
            "upperarm_twist_02", "upperarm_twistCor_01", "upperarm_bicep", "upperarm_tricep",
            "upperarm_correctiveRoot", "upperarm_bck", "upperarm_fwd", "upperarm_in", "upperarm_out", "lowerarm",
            "lowerarm_twist_01", "lowerarm_twist_02", "lowerarm_correctiveRoot", "lowerarm_in", "lowerarm_out",
            "lowerarm_fwd", "lowerarm_bck", "wrist_inner", "wrist_outer", "hand", "weapon", "thigh",
            "thigh_twist_01", "thigh_twist_02", "thigh_twistCor_01", "thigh_correctiveRoot", "thigh_bck",
            "thigh_fwd", "thigh_out", "thigh_in", "thigh_bck_lwr", "thigh_fwd_lwr", "calf", "calf_twist_01",
            "calf_twist_02", "calf_twistCor_02", "calf_correctiveRoot", "calf_knee", "calf_kneeBack", "foot",
            "ankle_bck", "ankle_fwd", "ball", "bigtoe_01", "littletoe_01")]
        for f in ("index", "middle", "ring", "pinky"):
            names += [f"{f}_metacarpal_{s}"] + [f"{f}_0{i}_{s}" for i in (1, 2, 3)]
        names += [f"thumb_0{i}_{s}" for i in (1, 2, 3)]
    return names


def ue4_mannequin() -> list[str]:
    names = ["root", "pelvis", "spine_01", "spine_02", "spine_03", "neck_01", "head", "ik_foot_root", "ik_foot_l",
             "ik_foot_r", "ik_hand_root", "ik_hand_gun", "ik_hand_l", "ik_hand_r"]
    for s in ("l", "r"):
        names += [f"{b}_{s}" for b in ("clavicle", "upperarm", "upperarm_twist_01", "lowerarm", "lowerarm_twist_01",
                                       "hand", "thigh", "thigh_twist_01", "calf", "calf_twist_01", "foot", "ball")]
        names += [f"{f}_0{i}_{s}" for f in sk.FINGERS for i in (1, 2, 3)]
    return names


def mixamo(prefix: str = "mixamorig:") -> list[str]:
    names = [prefix + n for n in ("Hips", "Spine", "Spine1", "Spine2", "Neck", "Head", "HeadTop_End", "LeftEye",
                                  "RightEye")]
    for side in ("Left", "Right"):
        names += [f"{prefix}{side}{b}" for b in ("Shoulder", "Arm", "ForeArm", "Hand", "UpLeg", "Leg", "Foot",
                                                 "ToeBase", "Toe_End")]
        names += [f"{prefix}{side}Hand{f}{i}" for f in ("Thumb", "Index", "Middle", "Ring", "Pinky")
                  for i in (1, 2, 3, 4)]
    return names


def cmu_mb() -> list[str]:  # MPFB2 rig.cmu_mb, all 31 bones
    return ["Hips", "LowerBack", "Spine", "Spine1", "Neck", "Neck1", "Head", "LHipJoint", "RHipJoint", "LThumb",
            "RThumb", *[f"{side}{b}" for side in ("Left", "Right") for b in (
                "Shoulder", "Arm", "ForeArm", "Hand", "FingerBase", "HandFinger1", "UpLeg", "Leg", "Foot", "ToeBase")]]


def cmu_joints() -> list[str]:  # CMU BVH, 3ds Max friendly release (131_01_start_walk_stop.bvh), all 31 joints
    return ["Hips", "LHipJoint", "RHipJoint", "lowerback", "Chest", "Chest2", "lowerneck", "Neck", "Head", "lhand",
            "LFingers", "LThumb", "rhand", "RFingers", "RThumb", *[f"{side}{b}" for side in ("Left", "Right") for b in (
                "Hip", "Knee", "Ankle", "Toe", "Collar", "Shoulder", "Elbow", "Wrist")]]


def vrm(thumb: tuple[str, str, str], style: str = "vrm") -> list[str]:
    """VRM humanoid names ("vrm": leftUpperArm), or Unity's ("unity": LeftUpperArm, and the
    fingers as HumanTrait.BoneName writes them, "Left Thumb Proximal")."""
    unity = style == "unity"
    centre = ["Hips", "Spine", "Chest", "UpperChest", "Neck", "Head", "Jaw"] if unity else \
        ["hips", "spine", "chest", "upperChest", "neck", "head", "jaw"]
    names = list(centre)
    for side in (("Left", "Right") if unity else ("left", "right")):
        names += [side + b for b in ("Shoulder", "UpperArm", "LowerArm", "Hand", "UpperLeg", "LowerLeg", "Foot",
                                     "Toes", "Eye")]
        for f in ("Thumb", "Index", "Middle", "Ring", "Little"):
            for p in (thumb if f == "Thumb" else ("Proximal", "Intermediate", "Distal")):
                names.append(f"{side} {f} {p}" if unity else f"{side}{f}{p}")
    return names


def vroid(symmetrised: bool = False) -> list[str]:
    def side(s, part):
        return f"{part}_{s}" if symmetrised else f"J_Bip_{s}_{part}"

    def centre(part):
        return part if symmetrised else f"J_Bip_C_{part}"

    def sec(s, part):
        return f"{part}_{s}" if symmetrised else f"J_Sec_{s}_{part}"
    names = ["Root", *[centre(p) for p in ("Hips", "Spine", "Chest", "UpperChest", "Neck", "Head")]]
    names += [("" if symmetrised else "J_Sec_") + f"Hair{k}_{i:02d}" for i in range(1, 8) for k in (1, 2, 3)]
    for s in ("L", "R"):
        names += [side(s, p) for p in ("Shoulder", "UpperArm", "LowerArm", "Hand", "UpperLeg", "LowerLeg", "Foot",
                                       "ToeBase")]
        names += [side(s, f"{f}{i}") for f in ("Thumb", "Index", "Middle", "Ring", "Little") for i in (1, 2, 3)]
        names += [sec(s, "Bust1"), sec(s, "Bust2"), sec(s, "CoatSkirtBack_01"), sec(s, "CoatSkirtBack_end_01"),
                  f"FaceEye_{s}" if symmetrised else f"J_Adj_{s}_FaceEye"]
    return names


def vrm_addon(thumb=("proximal", "intermediate", "distal")) -> list[str]:
    names = ["root", "hips", "spine", "chest", "upper_chest", "neck", "head"]
    for s in ("L", "R"):
        names += [f"{b}.{s}" for b in ("eye", "shoulder", "upper_arm", "lower_arm", "hand", "upper_leg", "lower_leg",
                                       "foot", "toes")]
        names += [f"thumb_{p}.{s}" for p in thumb]
        names += [f"{f}_{p}.{s}" for f in ("index", "middle", "ring", "little")
                  for p in ("proximal", "intermediate", "distal")]
    return names


MAKEHUMAN_DEFAULT = """breast.L breast.R clavicle.L clavicle.R eye.L eye.R finger1-1.L finger1-1.R finger1-2.L
finger1-2.R finger1-3.L finger1-3.R finger2-1.L finger2-1.R finger2-2.L finger2-2.R finger2-3.L finger2-3.R finger3-1.L
finger3-1.R finger3-2.L finger3-2.R finger3-3.L finger3-3.R finger4-1.L finger4-1.R finger4-2.L finger4-2.R finger4-3.L
finger4-3.R finger5-1.L finger5-1.R finger5-2.L finger5-2.R finger5-3.L finger5-3.R foot.L foot.R head jaw levator02.L
levator02.R levator03.L levator03.R levator04.L levator04.R levator05.L levator05.R levator06.L levator06.R
lowerarm01.L lowerarm01.R lowerarm02.L lowerarm02.R lowerleg01.L lowerleg01.R lowerleg02.L lowerleg02.R metacarpal1.L
metacarpal1.R metacarpal2.L metacarpal2.R metacarpal3.L metacarpal3.R metacarpal4.L metacarpal4.R neck01 neck02 neck03
oculi01.L oculi01.R oculi02.L oculi02.R orbicularis03.L orbicularis03.R orbicularis04.L orbicularis04.R oris01 oris02
oris03.L oris03.R oris04.L oris04.R oris05 oris06 oris06.L oris06.R oris07.L oris07.R pelvis.L pelvis.R risorius02.L
risorius02.R risorius03.L risorius03.R root shoulder01.L shoulder01.R special01 special03 special04 special05.L
special05.R special06.L special06.R spine01 spine02 spine03 spine04 spine05 temporalis01.L temporalis01.R
temporalis02.L temporalis02.R toe1-1.L toe1-1.R toe1-2.L toe1-2.R toe2-1.L toe2-1.R toe2-2.L toe2-2.R toe2-3.L toe2-3.R
toe3-1.L toe3-1.R toe3-2.L toe3-2.R toe3-3.L toe3-3.R toe4-1.L toe4-1.R toe4-2.L toe4-2.R toe4-3.L toe4-3.R toe5-1.L
toe5-1.R toe5-2.L toe5-2.R toe5-3.L toe5-3.R tongue00 tongue01 tongue02 tongue03 tongue04 tongue05.L tongue05.R
tongue06.L tongue06.R tongue07.L tongue07.R upperarm01.L upperarm01.R upperarm02.L upperarm02.R upperleg01.L
upperleg01.R upperleg02.L upperleg02.R wrist.L wrist.R""".split()  # MPFB2 rig.default: all 163 bones


def daz_genesis8() -> list[str]:
    names = ["hip", "pelvis", "abdomenLower", "abdomenUpper", "chestLower", "chestUpper", "neckLower", "neckUpper",
             "head", "upperTeeth", "lowerJaw", "lowerTeeth", "tongue01", "tongue02", "tongue03", "tongue04",
             "lowerFaceRig", "upperFaceRig", "lEye", "rEye", "lEar", "rEar", "CenterBrow", "lNasolabialLower"]
    for s in ("l", "r"):
        names += [s + b for b in (
            "Collar", "ShldrBend", "ShldrTwist", "ForearmBend", "ForearmTwist", "Hand", "Pectoral", "ThighBend",
            "ThighTwist", "Shin", "Foot", "Metatarsals", "Toe", "Heel", "BigToe", "BigToe_2",
            *[f"SmallToe{k}{x}" for k in (1, 2, 3, 4) for x in ("", "_2")])]
        names += [f"{s}Carpal{k}" for k in (1, 2, 3, 4)]
        names += [f"{s}{f}{i}" for f in ("Thumb", "Index", "Mid", "Ring", "Pinky") for i in (1, 2, 3)]
    return names


def daz_genesis9() -> list[str]:
    names = ["hip", "pelvis", "spine1", "spine2", "spine3", "spine4", "neck1", "neck2", "head", "l_eye", "r_eye",
             "l_ear", "r_ear", "l_eyelidupper", "l_browinner", "l_cheek", "r_lipupper"]
    for s in ("l", "r"):
        names += [f"{s}_{b}" for b in (
            "shoulder", "upperarm", "upperarmtwist1", "upperarmtwist2", "upperarmtwist1(drv)", "forearm",
            "forearmtwist1", "forearmtwist2", "hand", "hand_anchor", "pectoral", "thigh", "thightwist1",
            "thightwist2", "shin", "foot", "metatarsal", "toes", "bigtoe1", "bigtoe2", "indextoe1", "indextoe2",
            "midtoe1", "midtoe2", "ringtoe1", "ringtoe2", "pinkytoe1", "pinkytoe2")]
        names += [f"{s}_{f}metacarpal" for f in ("index", "mid", "ring", "pinky")]
        names += [f"{s}_{f}{i}" for f in ("thumb", "index", "mid", "ring", "pinky") for i in (1, 2, 3)]
    return names


def quaternius(first_finger: int) -> list[str]:
    """A Quaternius character (exported from Blender, .L/.R names): the men's fingers are numbered
    2..4 and their two-bone thumbs 2..3, the women's 1..3; the root carries a weapon socket."""
    names = ["Root", "Hips", "Abdomen", "Torso", "Chest", "Neck", "Head", "Weapon"]
    for s in ("L", "R"):
        names += [f"{b}.{s}" for b in ("Shoulder", "UpperArm", "LowerArm", "Hand", "UpperLeg", "LowerLeg", "Foot")]
        names += [f"{f}{n}.{s}" for f in ("Index", "Middle", "Ring", "Pinky")
                  for n in range(first_finger, first_finger + 3)]
        names += [f"Thumb{n}.{s}" for n in (range(2, 4) if first_finger == 2 else range(1, 4))]
    return names


def _quaternius_expect(first_finger: int) -> dict:
    limbs = {"clavicle": "Shoulder.{s}", "upperarm": "UpperArm.{s}", "forearm": "LowerArm.{s}", "hand": "Hand.{s}",
             "thigh": "UpperLeg.{s}", "shin": "LowerLeg.{s}", "foot": "Foot.{s}"}
    fingers = ("Thumb", "Index", "Middle", "Ring", "Pinky")[1 if first_finger == 2 else 0:]
    for f, w in zip(sk.FINGERS[5 - len(fingers):], fingers):
        for i in (1, 2, 3):
            limbs[f"{f}_{i}"] = f"{w}{first_finger + i - 1}.{{s}}"
    return expect("Hips", "Head", ["Abdomen", "Torso", "Chest"], ["Neck"], limbs, 0, {"root": "Root"})


def character_creator(fingers: str = "named") -> list[str]:
    names = ["CC_Base_BoneRoot", "CC_Base_Hip", "CC_Base_Pelvis", "CC_Base_Waist", "CC_Base_Spine01",
             "CC_Base_Spine02", "CC_Base_NeckTwist01", "CC_Base_NeckTwist02", "CC_Base_Head", "CC_Base_FacialBone",
             "CC_Base_JawRoot", "CC_Base_Tongue01", "CC_Base_Tongue02", "CC_Base_Tongue03", "CC_Base_Teeth01",
             "CC_Base_Teeth02", "CC_Base_UpperJaw", "CC_Base_L_Eye", "CC_Base_R_Eye"]
    for s in ("L", "R"):
        names += [f"CC_Base_{s}_{b}" for b in (
            "Clavicle", "Upperarm", "UpperarmTwist01", "UpperarmTwist02", "Forearm", "ForearmTwist01",
            "ForearmTwist02", "ElbowShareBone", "Hand", "RibsTwist", "Breast", "Thigh", "ThighTwist01",
            "ThighTwist02", "Calf", "CalfTwist01", "CalfTwist02", "KneeShareBone", "Foot", "ToeBase",
            "ToeBaseShareBone", "BigToe1", "IndexToe1", "MidToe1", "RingToe1", "PinkyToe1")]
        if fingers == "named":
            names += [f"CC_Base_{s}_{f}{i}" for f in ("Thumb", "Index", "Mid", "Ring", "Pinky") for i in (1, 2, 3)]
        else:
            names += [f"CC_Base_{s}_Finger{k}{i}" for k in range(5) for i in range(3)]
    return names


# --- what each must map to ---------------------------------------------------------------------------

def expect(pelvis, head, spine, neck, limbs: dict[str, str], side_index: int, extra: dict | None = None) -> dict:
    """The expected map: single segments {segment: bone} and the chains. `limbs` holds templates
    with {s} (the side in the scheme's spelling, SIDES[...][side_index])."""
    bones = {"pelvis": pelvis, "head": head}
    for seg, template in limbs.items():
        for s in ("l", "r"):
            bones[f"{seg}_{s}"] = template.format(s=SIDES[s][side_index])
    bones.update(extra or {})
    return {"bones": bones, "chains": {"spine": spine, "neck": neck}}


def _fingers(template: str, words: tuple[str, ...], numbers=("1", "2", "3")) -> dict:
    """Phalanges 1..3 of the five fingers: `template` with {f} = the finger's word, {n} = the number."""
    out = {}
    for f, w in zip(sk.FINGERS, words):
        for i, n in enumerate(numbers, start=1):
            out[f"{f}_{i}"] = template.replace("{f}", w).replace("{n}", n)
    return out


UE_LIMBS = {"clavicle": "clavicle_{s}", "upperarm": "upperarm_{s}", "forearm": "lowerarm_{s}", "hand": "hand_{s}",
            "thigh": "thigh_{s}", "shin": "calf_{s}", "foot": "foot_{s}", "toe": "ball_{s}"}
MIXAMO_LIMBS = {"clavicle": "{p}{s}Shoulder", "upperarm": "{p}{s}Arm", "forearm": "{p}{s}ForeArm",
                "hand": "{p}{s}Hand", "thigh": "{p}{s}UpLeg", "shin": "{p}{s}Leg", "foot": "{p}{s}Foot",
                "toe": "{p}{s}ToeBase"}


def _mixamo_expect(p: str) -> dict:
    limbs = {k: v.replace("{p}", p) for k, v in MIXAMO_LIMBS.items()}
    limbs |= _fingers(p + "{s}Hand{f}{n}", ("Thumb", "Index", "Middle", "Ring", "Pinky"))
    return expect(p + "Hips", p + "Head", [p + "Spine", p + "Spine1", p + "Spine2"], [p + "Neck"], limbs, 1)


VRM_LIMBS = {"clavicle": "{s}Shoulder", "upperarm": "{s}UpperArm", "forearm": "{s}LowerArm", "hand": "{s}Hand",
             "thigh": "{s}UpperLeg", "shin": "{s}LowerLeg", "foot": "{s}Foot", "toe": "{s}Toes"}
VROID_LIMBS = {"clavicle": "Shoulder", "upperarm": "UpperArm", "forearm": "LowerArm", "hand": "Hand",
               "thigh": "UpperLeg", "shin": "LowerLeg", "foot": "Foot", "toe": "ToeBase"}


def _vroid_expect(sym: bool) -> dict:
    def side(part):
        return f"{part}_{{s}}" if sym else f"J_Bip_{{s}}_{part}"
    c = "" if sym else "J_Bip_C_"
    limbs = {k: side(v) for k, v in VROID_LIMBS.items()}
    limbs |= {f"{f}_{i}": side(f"{w}{i}") for f, w in zip(sk.FINGERS, ("Thumb", "Index", "Middle", "Ring", "Little"))
              for i in (1, 2, 3)}
    limbs["breast"] = "Bust1_{s}" if sym else "J_Sec_{s}_Bust1"
    return expect(c + "Hips", c + "Head", [c + "Spine", c + "Chest", c + "UpperChest"], [c + "Neck"], limbs, 0,
                  {"root": "Root"})


def _vrm_expect(style: str, thumb) -> dict:
    unity = style == "unity"
    limbs = dict(VRM_LIMBS)
    for f, w in zip(sk.FINGERS, ("Thumb", "Index", "Middle", "Ring", "Little")):
        phalanges = thumb if f == "thumb" else ("Proximal", "Intermediate", "Distal")
        for i, p in enumerate(phalanges, start=1):
            limbs[f"{f}_{i}"] = f"{{s}} {w} {p}" if unity else f"{{s}}{w}{p}"
    centre = ["Hips", "Head", "Spine", "Chest", "UpperChest", "Neck"] if unity else \
        ["hips", "head", "spine", "chest", "upperChest", "neck"]
    return expect(centre[0], centre[1], centre[2:5], [centre[5]], limbs, 1 if unity else 2)


def _vrm_addon_expect(thumb) -> dict:
    limbs = {"clavicle": "shoulder.{s}", "upperarm": "upper_arm.{s}", "forearm": "lower_arm.{s}", "hand": "hand.{s}",
             "thigh": "upper_leg.{s}", "shin": "lower_leg.{s}", "foot": "foot.{s}", "toe": "toes.{s}"}
    for f, w in zip(sk.FINGERS, ("thumb", "index", "middle", "ring", "little")):
        phalanges = thumb if f == "thumb" else ("proximal", "intermediate", "distal")
        for i, p in enumerate(phalanges, start=1):
            limbs[f"{f}_{i}"] = f"{w}_{p}.{{s}}"
    return expect("hips", "head", ["spine", "chest", "upper_chest"], ["neck"], limbs, 0, {"root": "root"})


MAKEHUMAN_EXPECT = expect(
    "root", "head", ["spine05", "spine04", "spine03", "spine02", "spine01"], ["neck01", "neck02", "neck03"],
    {"clavicle": "clavicle.{s}", "upperarm": "upperarm01.{s}", "forearm": "lowerarm01.{s}", "hand": "wrist.{s}",
     "thigh": "upperleg01.{s}", "shin": "lowerleg01.{s}", "foot": "foot.{s}", "toe": "toe3-1.{s}",
     "pelvis_side": "pelvis.{s}", "breast": "breast.{s}",
     **{f"metacarpal_{f}": f"metacarpal{k}.{{s}}" for k, f in enumerate(sk.FINGERS[1:], start=1)},
     **{f"{f}_{i}": f"finger{k}-{i}.{{s}}" for k, f in enumerate(sk.FINGERS, start=1) for i in (1, 2, 3)}}, 0)

DAZ8_EXPECT = expect(
    "hip", "head", ["abdomenLower", "abdomenUpper", "chestLower", "chestUpper"], ["neckLower", "neckUpper"],
    {"clavicle": "{s}Collar", "upperarm": "{s}ShldrBend", "forearm": "{s}ForearmBend", "hand": "{s}Hand",
     "thigh": "{s}ThighBend", "shin": "{s}Shin", "foot": "{s}Foot", "toe": "{s}Toe", "breast": "{s}Pectoral",
     "heel": "{s}Heel",
     **{f"metacarpal_{f}": f"{{s}}Carpal{k}" for k, f in enumerate(sk.FINGERS[1:], start=1)},
     **_fingers("{s}{f}{n}", ("Thumb", "Index", "Mid", "Ring", "Pinky"))}, 3)

DAZ9_EXPECT = expect(
    "hip", "head", ["spine1", "spine2", "spine3", "spine4"], ["neck1", "neck2"],
    {"clavicle": "{s}_shoulder", "upperarm": "{s}_upperarm", "forearm": "{s}_forearm", "hand": "{s}_hand",
     "thigh": "{s}_thigh", "shin": "{s}_shin", "foot": "{s}_foot", "toe": "{s}_toes", "breast": "{s}_pectoral",
     **{f"metacarpal_{f}": f"{{s}}_{w}metacarpal" for f, w in zip(sk.FINGERS[1:], ("index", "mid", "ring", "pinky"))},
     **_fingers("{s}_{f}{n}", ("thumb", "index", "mid", "ring", "pinky"))}, 3)


def _cc_expect(fingers: str) -> dict:
    limbs = {"clavicle": "CC_Base_{s}_Clavicle", "upperarm": "CC_Base_{s}_Upperarm", "forearm": "CC_Base_{s}_Forearm",
             "hand": "CC_Base_{s}_Hand", "thigh": "CC_Base_{s}_Thigh", "shin": "CC_Base_{s}_Calf",
             "foot": "CC_Base_{s}_Foot", "toe": "CC_Base_{s}_ToeBase", "breast": "CC_Base_{s}_Breast"}
    for k, (f, w) in enumerate(zip(sk.FINGERS, ("Thumb", "Index", "Mid", "Ring", "Pinky"))):
        for i in (1, 2, 3):
            limbs[f"{f}_{i}"] = f"CC_Base_{{s}}_{w}{i}" if fingers == "named" else f"CC_Base_{{s}}_Finger{k}{i - 1}"
    return expect("CC_Base_Hip", "CC_Base_Head", ["CC_Base_Waist", "CC_Base_Spine01", "CC_Base_Spine02"],
                  ["CC_Base_NeckTwist01", "CC_Base_NeckTwist02"], limbs, 0, {"root": "CC_Base_BoneRoot"})


# UE5's metacarpals are canonical (auxiliary) segments: they move rigidly with the hand like the
# canonical metacarpals, and mapping them keeps the palm's skin on the hand for contact checks.
UE_FINGERS = {f"metacarpal_{f}": f"{f}_metacarpal_{{s}}" for f in ("index", "middle", "ring", "pinky")}
UE_FINGERS |= {f"{f}_{i}": f"{f}_0{i}_{{s}}" for f in sk.FINGERS for i in (1, 2, 3)}
UE4_FINGERS = {k: v for k, v in UE_FINGERS.items() if not k.startswith("metacarpal")}

CASES = {
    # name: (bone names, scheme, expected map)
    "ue5_manny": (ue5_manny(), "unreal",
                  expect("pelvis", "head", [f"spine_0{k}" for k in range(1, 6)], ["neck_01", "neck_02"],
                         UE_LIMBS | UE_FINGERS, 3, {"root": "root"})),
    "ue4_mannequin": (ue4_mannequin(), "unreal",
                      expect("pelvis", "head", ["spine_01", "spine_02", "spine_03"], ["neck_01"],
                             UE_LIMBS | UE4_FINGERS, 3, {"root": "root"})),
    "mixamo": (mixamo("mixamorig:"), "mixamo", _mixamo_expect("mixamorig:")),
    "mixamo_numbered": (mixamo("mixamorig12:"), "mixamo", _mixamo_expect("mixamorig12:")),
    "mixamo_no_prefix": (mixamo(""), "mixamo", _mixamo_expect("")),
    "mixamo_gltf": (mixamo("mixamorig"), "mixamo", _mixamo_expect("mixamorig")),
    "cmu_mb": (cmu_mb(), "cmu_mb",
               expect("Hips", "Head", ["LowerBack", "Spine", "Spine1"], ["Neck", "Neck1"],
                      {k: v.replace("{p}", "") for k, v in MIXAMO_LIMBS.items()}, 1,
                      {"pelvis_side_l": "LHipJoint", "pelvis_side_r": "RHipJoint"})),
    # Bones named by their head joint: "LeftShoulder" is the upper arm, "LeftCollar" the clavicle.
    "cmu_joints": (cmu_joints(), "cmu_joints",
                   expect("Hips", "Head", ["lowerback", "Chest", "Chest2"], ["lowerneck", "Neck"],
                          {"clavicle": "{s}Collar", "upperarm": "{s}Shoulder", "forearm": "{s}Elbow",
                           "hand": "{s}Wrist", "thigh": "{s}Hip", "shin": "{s}Knee", "foot": "{s}Ankle",
                           "toe": "{s}Toe"}, 1,
                          {"pelvis_side_l": "LHipJoint", "pelvis_side_r": "RHipJoint"})),
    "vrm1": (vrm(("Metacarpal", "Proximal", "Distal")), "vrm_humanoid",
             _vrm_expect("vrm", ("Metacarpal", "Proximal", "Distal"))),
    "vrm0": (vrm(("Proximal", "Intermediate", "Distal")), "vrm_humanoid",
             _vrm_expect("vrm", ("Proximal", "Intermediate", "Distal"))),
    "unity": (vrm(("Proximal", "Intermediate", "Distal"), "unity"), "vrm_humanoid",
              _vrm_expect("unity", ("Proximal", "Intermediate", "Distal"))),
    "vroid": (vroid(), "vroid", _vroid_expect(False)),
    "vroid_symmetrised": (vroid(True), "vroid", _vroid_expect(True)),
    "vrm_addon_vrm0": (vrm_addon(), "vrm_addon", _vrm_addon_expect(("proximal", "intermediate", "distal"))),
    "vrm_addon_vrm1": (vrm_addon(("metacarpal", "proximal", "distal")), "vrm_addon",
                       _vrm_addon_expect(("metacarpal", "proximal", "distal"))),
    "makehuman_default": (MAKEHUMAN_DEFAULT, "makehuman", MAKEHUMAN_EXPECT),
    "daz_genesis8": (daz_genesis8(), "daz_genesis8", DAZ8_EXPECT),
    "daz_genesis9": (daz_genesis9(), "daz_genesis9", DAZ9_EXPECT),
    "character_creator": (character_creator(), "character_creator", _cc_expect("named")),
    "character_creator_numbered": (character_creator("numbered"), "character_creator", _cc_expect("numbered")),
    # Blender's .L/.R side suffix with plain words; fingers numbered from wherever the rig starts
    "quaternius_men": (quaternius(2), "blender_sided", _quaternius_expect(2)),
    "quaternius_women": (quaternius(1), "blender_sided", _quaternius_expect(1)),
}


def _expected(case: str) -> tuple[list[str], str, dict[str, str], dict[str, list[str]]]:
    names, scheme, e = CASES[case]
    return names, scheme, e["bones"], e["chains"]


@pytest.mark.parametrize("case", sorted(CASES))
def test_each_convention_is_detected_and_maps_the_right_bones(case):
    names, scheme, bones, chains = _expected(case)
    assert len(set(names)) == len(names), "the fixture lists a bone twice"
    bm = naming.detect_bone_map(names)
    assert bm.scheme == scheme
    assert bm.missing() == []
    assert bm.bones == bones
    assert {k: v for k, v in bm.chains.items() if v} == chains
    # every other bone (twist, IK, corrective, facial, hair, cloth, toes) stays unmapped
    used = set(bones.values()) | {b for c in chains.values() for b in c}
    assert set(bm.unmapped) == set(names) - used
    assert len(bm.unmapped) + len(used) == len(names)


@pytest.mark.parametrize("case", ["ue5_manny", "daz_genesis8", "daz_genesis9", "character_creator",
                                  "makehuman_default"])
def test_split_and_helper_bones_stay_unmapped(case):
    """The twist half of a split limb and the corrective or IK helpers never take a segment: the
    segment's bone is the one whose head is the joint (armature.py)."""
    names, _scheme, _bones, _chains = _expected(case)
    bm = naming.detect_bone_map(names)
    helpers = [n for n in names if any(w in n.lower() for w in (
        "twist", "corrective", "ik_", "share", "upperarm02", "upperleg02", "lowerarm02", "lowerleg02",
        "shoulder01", "metatarsal")) and "necktwist" not in n.lower()]  # CC's neck bones are the neck
    assert helpers, case
    assert set(helpers) <= set(bm.unmapped)


def test_daz_and_cc_pelvis_bone_is_not_the_hips_root():
    """Daz and Character Creator hang the thighs from a 'pelvis' bone under the hips root: the
    root ('hip', 'CC_Base_Hip') is the pelvis segment, the pelvis bone follows it."""
    for names, root, pelvis_bone in ((daz_genesis8(), "hip", "pelvis"), (daz_genesis9(), "hip", "pelvis"),
                                     (character_creator(), "CC_Base_Hip", "CC_Base_Pelvis")):
        bm = naming.detect_bone_map(names)
        assert bm.bones["pelvis"] == root
        assert pelvis_bone in bm.unmapped


def test_today_vroid_maps_every_body_bone():
    """The VRoid rig that left 51 of 53 bones unmapped before: every J_Bip bone has a segment."""
    bm = naming.detect_bone_map(vroid())
    assert [n for n in bm.unmapped if n.startswith("J_Bip_")] == []
    assert bm.missing(with_fingers=True) == []


def test_letter_case_and_vrm_thumb_conventions():
    bm = naming.detect_bone_map([n.upper() for n in mixamo()])
    assert bm.scheme == "mixamo" and bm.bones["upperarm_l"] == "MIXAMORIG:LEFTARM"
    v1 = naming.detect_bone_map(vrm(("Metacarpal", "Proximal", "Distal")))
    v0 = naming.detect_bone_map(vrm(("Proximal", "Intermediate", "Distal")))
    assert [v1.bones[f"thumb_{i}_l"] for i in (1, 2, 3)] == ["leftThumbMetacarpal", "leftThumbProximal",
                                                             "leftThumbDistal"]
    assert [v0.bones[f"thumb_{i}_r"] for i in (1, 2, 3)] == ["rightThumbProximal", "rightThumbIntermediate",
                                                             "rightThumbDistal"]


# --- properties ------------------------------------------------------------------------------------

def _claimed_by_no_scheme(name: str) -> bool:
    return all(naming.map_with_scheme([name], s).unmapped == [name] for s in naming.SCHEMES)


EXTRA_WORDS = ["twist", "Twist01", "ik", "IK_", "corrective", "jiggle", "hair", "Hair_", "breast_jiggle", "cloth",
               "skirt", "tail", "wing", "eyelid", "brow", "lip", "cheek", "prop", "weapon", "socket", "helper", "end",
               "_end", "_01", ".001", ":", "DEF-", "MCH-", "L", "R", "_l", "_r", "Left", "Right", "0", "9"]


@st.composite
def extra_bones(draw):
    """Bones of any name no scheme knows: made of words rigs use for extras, or any text."""
    words = st.lists(st.sampled_from(EXTRA_WORDS), min_size=1, max_size=4).map("".join)
    text = st.text(alphabet=st.characters(min_codepoint=32, max_codepoint=0x24F), min_size=1, max_size=20)
    names = draw(st.lists(st.one_of(words, text), max_size=25, unique=True))
    return [n for n in names if _claimed_by_no_scheme(n)]


@settings(max_examples=60, deadline=None)
@given(case=st.sampled_from(sorted(CASES)), seed=st.integers(0, 2**32 - 1), extras=extra_bones())
def test_order_and_unknown_extra_bones_never_change_the_map(case, seed, extras):
    names, scheme, bones, chains = _expected(case)
    extras = [e for e in extras if e not in names]
    shuffled = names + extras
    random.Random(seed).shuffle(shuffled)
    bm = naming.detect_bone_map(shuffled)
    assert bm.scheme == scheme
    assert bm.bones == bones
    assert {k: v for k, v in bm.chains.items() if v} == chains
    assert set(extras) <= set(bm.unmapped)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_every_scheme_maps_any_order_of_its_own_names_the_same(seed):
    for case in CASES:
        names, scheme, bones, chains = _expected(case)
        shuffled = list(names)
        random.Random(seed).shuffle(shuffled)
        bm = naming.map_with_scheme(shuffled, naming.SCHEME_BY_NAME[scheme])
        assert bm.bones == bones, case
        assert {k: v for k, v in bm.chains.items() if v} == chains, case


def test_scheme_names_are_unique_and_titled():
    assert len(naming.SCHEME_BY_NAME) == len(naming.SCHEMES)
    assert all(s.title for s in naming.SCHEMES)


def test_a_metarig_without_its_head_bone_takes_the_top_of_its_neck():
    """A base mesh's metarig with spine.006 removed was refused for a missing head: the neck's top
    bone carries the head's skin."""
    names = ["spine", *[f"spine.00{k}" for k in range(1, 6)]]
    names += [f"{b}.{s}" for s in "LR" for b in ("shoulder", "upper_arm", "forearm", "hand", "thigh", "shin", "foot",
                                                 "toe", "pelvis", "heel.02")]
    bm = naming.detect_bone_map(names)
    assert bm.scheme == "rigify_metarig" and bm.missing() == []
    assert bm.bones["head"] == "spine.005" and bm.chains["neck"] == ["spine.004"]
    assert naming.detect_bone_map([*names, "spine.006"]).bones["head"] == "spine.006"  # a full metarig is unchanged
