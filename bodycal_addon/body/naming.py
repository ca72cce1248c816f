"""Bone maps from avatar naming schemes to the canonical skeleton (DESIGN.md §2): each scheme
(Unreal, Rigify, Mixamo, VRM, VRoid, MakeHuman, Daz, Character Creator, CMU) is a set of regular
expressions per body segment; `detect_bone_map` picks the scheme that maps an armature best.
"""

from __future__ import annotations

import functools
import re
from dataclasses import dataclass

from .skeleton import FINGERS, required_segments

# --- Bone maps -------------------------------------------------------------------------------
# A naming scheme turns avatar bone names into segments. Each segment has one or more regular
# expressions in priority order (matched against the whole name, letter case ignored); `{s}`
# stands for the side as the scheme writes it. Chains (spine, neck) take every bone that matches
# their expression, ordered bottom-up by the token the expression's group captures.
#
# Bones a scheme does not name stay unmapped and follow their parent rigidly: twist, IK,
# corrective, facial, hair, cloth and toe bones. Where a rig splits a limb bone (Daz's ShldrBend +
# ShldrTwist, MakeHuman's upperarm01 + upperarm02) the segment takes the bone whose head is the
# joint (armature.py's joint rules); the next joint is the head of the next segment's bone, so a
# twist bone in between changes nothing. Where the bone called "pelvis" is not the hips root
# (Daz, Character Creator: hip -> pelvis -> thighs, hip -> abdomen), the `pelvis` segment is the
# root ("hip", "CC_Base_Hip") and the pelvis bone follows it; `read_armature` refuses a map whose
# pelvis bone is not an ancestor of both thighs and the spine.

_SEP = r"[ _.]?"  # an optional word separator: "LeftUpperArm", "Left Upper Arm", "left_upper_arm"


@dataclass(frozen=True)
class NamingScheme:
    """`patterns`: (segment template, regexes in priority order). `chains`: (chain segment, regex
    whose one group is the order token, order), where order is None (the token is a number, ""
    = 0, ascending), "descending" (a number, highest at the bottom) or a dict token -> rank (the
    token lower-cased, separators removed)."""

    name: str
    title: str
    side_tokens: dict[str, str]  # canonical side -> how the scheme writes it
    patterns: tuple[tuple[str, tuple[str, ...]], ...]
    chains: tuple[tuple[str, str, object], ...] = ()
    # Fingers numbered from wherever the rig starts (Quaternius: Index1..3 on one character,
    # Index2..4 on the next): (regex with {finger}, {s} and one group, the number; finger -> word).
    # The three lowest-numbered bones of a finger are its phalanges 1..3; fewer than three map none.
    digits: tuple[str, dict[str, str]] | None = None


def _p(segment: str, *regexes: str) -> tuple[str, tuple[str, ...]]:
    return segment, regexes


def _fingers(regex: str, names: dict[str, str], numbers=("1", "2", "3"), skip=()) -> list:
    """Phalanges 1..3 of every finger: `regex` with {finger} and {n} filled in, {{s}} kept."""
    return [_p(f"{f}_{i}_{{s}}", regex.format(finger=names[f], n=num))
            for f in FINGERS if f not in skip for i, num in enumerate(numbers, start=1)]


_UE_FINGERS = {f: f for f in FINGERS}
UNREAL = NamingScheme(
    "unreal", "Unreal Engine (UE4/UE5 Mannequin, MetaHuman body, MPFB game engine)",
    {"l": "l", "r": "r"},
    (
        _p("root", r"root"),
        _p("pelvis", r"pelvis"),
        _p("head", r"head"),
        _p("clavicle_{s}", r"clavicle_{s}"),
        _p("upperarm_{s}", r"upperarm_{s}"),
        _p("forearm_{s}", r"lowerarm_{s}"),
        _p("hand_{s}", r"hand_{s}"),
        _p("thigh_{s}", r"thigh_{s}"),
        _p("shin_{s}", r"calf_{s}"),
        _p("foot_{s}", r"foot_{s}"),
        _p("toe_{s}", r"ball_{s}"),
        _p("breast_{s}", r"breast_{s}"),  # MPFB's game_engine_with_breast
        *[_p(f"metacarpal_{f}_{{s}}", rf"{f}_metacarpal_{{s}}") for f in FINGERS],  # UE5
        *_fingers(r"{finger}_{n}_{{s}}", _UE_FINGERS, ("01", "02", "03")),
    ),
    (("spine", r"spine_?(\d+)", None), ("neck", r"neck_?(\d+)", None)),
)

_RIGIFY_FINGERS = {"thumb": "thumb", "index": "f_index", "middle": "f_middle", "ring": "f_ring",
                   "pinky": "f_pinky"}
RIGIFY_METARIG = NamingScheme(
    "rigify_metarig", "Rigify human metarig",
    {"l": "L", "r": "R"},
    (
        _p("pelvis", r"spine"),
        _p("head", r"spine\.006"),
        _p("clavicle_{s}", r"shoulder\.{s}"),
        _p("upperarm_{s}", r"upper_arm\.{s}"),
        _p("forearm_{s}", r"forearm\.{s}"),
        _p("hand_{s}", r"hand\.{s}"),
        _p("thigh_{s}", r"thigh\.{s}"),
        _p("shin_{s}", r"shin\.{s}"),
        _p("foot_{s}", r"foot\.{s}"),
        _p("toe_{s}", r"toe\.{s}"),
        _p("breast_{s}", r"breast\.{s}"),
        _p("pelvis_side_{s}", r"pelvis\.{s}"),
        _p("heel_{s}", r"heel\.02\.{s}"),
        # Rigify's palm.01 carries the index and the thumb; palm.02..04 the other fingers.
        _p("metacarpal_index_{s}", r"palm\.01\.{s}"),
        _p("metacarpal_middle_{s}", r"palm\.02\.{s}"),
        _p("metacarpal_ring_{s}", r"palm\.03\.{s}"),
        _p("metacarpal_pinky_{s}", r"palm\.04\.{s}"),
        *_fingers(r"{finger}\.{n}\.{{s}}", _RIGIFY_FINGERS, ("01", "02", "03")),
    ),
    # spine.001..003 are the trunk, spine.004..005 the neck (metarig's human layout).
    (("spine", r"spine\.(00[1-3])", None), ("neck", r"spine\.(00[45])", None)),
)

# Rigify's generated rig: the deforming DEF- bones carry the body (ORG-, MCH- and the controls drive
# them through constraints; blender/avatar_rig.py reads the DEF- bones as their own skeleton).
# Upper arms, forearms, thighs and shins are split into twist segments (`.001`): the segment is the
# first one, whose head is the joint, and the second follows it.
RIGIFY = NamingScheme(
    "rigify", "Rigify generated rig (DEF- deform bones)",
    {"l": "L", "r": "R"},
    (
        _p("root", r"root"),
        _p("pelvis", r"DEF-spine"),
        _p("head", r"DEF-spine\.006"),
        _p("clavicle_{s}", r"DEF-shoulder\.{s}"),
        _p("upperarm_{s}", r"DEF-upper_arm\.{s}"),
        _p("forearm_{s}", r"DEF-forearm\.{s}"),
        _p("hand_{s}", r"DEF-hand\.{s}"),
        _p("thigh_{s}", r"DEF-thigh\.{s}"),
        _p("shin_{s}", r"DEF-shin\.{s}"),
        _p("foot_{s}", r"DEF-foot\.{s}"),
        _p("toe_{s}", r"DEF-toe\.{s}"),
        _p("breast_{s}", r"DEF-breast\.{s}"),
        _p("pelvis_side_{s}", r"DEF-pelvis\.{s}"),
        _p("metacarpal_index_{s}", r"DEF-palm\.01\.{s}"),
        _p("metacarpal_middle_{s}", r"DEF-palm\.02\.{s}"),
        _p("metacarpal_ring_{s}", r"DEF-palm\.03\.{s}"),
        _p("metacarpal_pinky_{s}", r"DEF-palm\.04\.{s}"),
        *_fingers(r"DEF-{finger}\.{n}\.{{s}}", _RIGIFY_FINGERS, ("01", "02", "03")),
    ),
    (("spine", r"DEF-spine\.(00[1-3])", None), ("neck", r"DEF-spine\.(00[45])", None)),
)

# Mixamo's rig uses MotionBuilder's (HumanIK) names behind a `mixamorig:` prefix; Blender's FBX
# import keeps it, numbered when several characters share a file (`mixamorig1:`, `mixamorig12:`),
# and glTF tools drop the colon (`mixamorigHips`). Ready Player Me and MPFB's "mixamo" rig use
# the names without a prefix.
_MIXAMO = r"(?:mixamorig\d*[:_]?)?"
_MIXAMO_FINGERS = {"thumb": "Thumb", "index": "Index", "middle": "Middle", "ring": "Ring", "pinky": "Pinky"}
_MIXAMO_BODY = (
    _p("pelvis", _MIXAMO + r"Hips"),
    _p("head", _MIXAMO + r"Head"),
    _p("clavicle_{s}", _MIXAMO + r"{s}Shoulder"),
    _p("upperarm_{s}", _MIXAMO + r"{s}Arm"),
    _p("forearm_{s}", _MIXAMO + r"{s}ForeArm"),
    _p("hand_{s}", _MIXAMO + r"{s}Hand"),
    _p("thigh_{s}", _MIXAMO + r"{s}UpLeg"),
    _p("shin_{s}", _MIXAMO + r"{s}Leg"),
    _p("foot_{s}", _MIXAMO + r"{s}Foot"),
    _p("toe_{s}", _MIXAMO + r"{s}ToeBase"),
)
MIXAMO = NamingScheme(
    "mixamo", "Mixamo / MotionBuilder (mixamorig: prefix or none)",
    {"l": "Left", "r": "Right"},
    (*_MIXAMO_BODY, *_fingers(_MIXAMO + r"{{s}}Hand{finger}{n}", _MIXAMO_FINGERS)),
    (("spine", _MIXAMO + r"Spine(\d*)", None), ("neck", _MIXAMO + r"Neck(\d*)", None)),
)

# MakeHuman / MPFB's "CMU MB" skeleton: the CMU motion capture BVH's MotionBuilder names, with a
# LowerBack below Spine, hip joints from the hips to the thighs, and one-bone thumbs and
# two-bone lumped fingers (LThumb, LeftFingerBase, LeftHandFinger1: no canonical phalanges).
CMU_MB = NamingScheme(
    "cmu_mb", "MakeHuman CMU MB (CMU motion capture names)",
    {"l": "Left", "r": "Right"},
    (*_MIXAMO_BODY, _p("pelvis_side_l", r"LHipJoint"), _p("pelvis_side_r", r"RHipJoint")),
    (("spine", r"(LowerBack)", {"lowerback": -1}), ("spine", r"Spine(\d*)", None), ("neck", r"Neck(\d*)", None)),
)

# The CMU motion capture BVH of the "3ds Max friendly" release (cgspeed), the one most BVH packs
# ship: bones named by the joint at their head, so "LeftShoulder" is the upper arm (it starts at
# the shoulder) and the clavicle is "LeftCollar"; lowerback, Chest, Chest2 up the spine and
# lowerneck, Neck up the neck; lhand / LFingers / LThumb are lumped hand bones (no phalanges).
CMU_JOINTS = NamingScheme(
    "cmu_joints", "CMU motion capture BVH, joint names (3ds Max friendly release)",
    {"l": "Left", "r": "Right"},
    (
        _p("pelvis", r"Hips"),
        _p("head", r"Head"),
        _p("clavicle_{s}", r"{s}Collar"),
        _p("upperarm_{s}", r"{s}Shoulder"),
        _p("forearm_{s}", r"{s}Elbow"),
        _p("hand_{s}", r"{s}Wrist"),
        _p("thigh_{s}", r"{s}Hip"),
        _p("shin_{s}", r"{s}Knee"),
        _p("foot_{s}", r"{s}Ankle"),
        _p("toe_{s}", r"{s}Toe"),
        _p("pelvis_side_l", r"LHipJoint"), _p("pelvis_side_r", r"RHipJoint"),
    ),
    (("spine", r"(lowerback|Chest|Chest2)", {"lowerback": 0, "chest": 1, "chest2": 2}),
     ("neck", r"(lowerneck|Neck)", {"lowerneck": 0, "neck": 1})),
)

# VRM humanoid bone names (VRM 0.x and 1.0) are Unity's HumanBodyBones with a lower-case first
# letter; Unity's own rigs write them "LeftUpperArm" and, for fingers, HumanTrait.BoneName's
# "Left Thumb Proximal". VRM 1.0 renamed the thumb: its phalanges 1..3 are Metacarpal,
# Proximal, Distal; VRM 0.x and Unity call them Proximal, Intermediate, Distal. A rig carries
# one of the two sets; the priorities below read either.
_VRM_FINGERS = {"thumb": "Thumb", "index": "Index", "middle": "Middle", "ring": "Ring", "pinky": "Little"}
_VRM_PHALANGES = ("Proximal", "Intermediate", "Distal")
_VRM_CHAIN_ORDER = {"spine": 0, "chest": 1, "upperchest": 2, "neck": 0}
VRM_HUMANOID = NamingScheme(
    "vrm_humanoid", "VRM 0.x / 1.0 humanoid, Unity HumanBodyBones",
    {"l": "left", "r": "right"},
    (
        _p("pelvis", r"hips"),
        _p("head", r"head"),
        _p("clavicle_{s}", rf"{{s}}{_SEP}shoulder"),
        _p("upperarm_{s}", rf"{{s}}{_SEP}upper{_SEP}arm"),
        _p("forearm_{s}", rf"{{s}}{_SEP}lower{_SEP}arm"),
        _p("hand_{s}", rf"{{s}}{_SEP}hand"),
        _p("thigh_{s}", rf"{{s}}{_SEP}upper{_SEP}leg"),
        _p("shin_{s}", rf"{{s}}{_SEP}lower{_SEP}leg"),
        _p("foot_{s}", rf"{{s}}{_SEP}foot"),
        _p("toe_{s}", rf"{{s}}{_SEP}toes?"),
        _p("thumb_1_{s}", rf"{{s}}{_SEP}thumb{_SEP}metacarpal", rf"{{s}}{_SEP}thumb{_SEP}proximal"),
        _p("thumb_2_{s}", rf"{{s}}{_SEP}thumb{_SEP}proximal", rf"{{s}}{_SEP}thumb{_SEP}intermediate"),
        _p("thumb_3_{s}", rf"{{s}}{_SEP}thumb{_SEP}distal"),
        *_fingers(rf"{{{{s}}}}{_SEP}{{finger}}{_SEP}{{n}}", _VRM_FINGERS, _VRM_PHALANGES, skip=("thumb",)),
    ),
    (("spine", rf"(spine|chest|upper{_SEP}chest)", _VRM_CHAIN_ORDER), ("neck", r"(neck)", _VRM_CHAIN_ORDER)),
)


def _vroid(part: str) -> str:
    """A sided VRoid bone: "J_Bip_L_UpperArm", or "UpperArm_L" once the VRM add-on's Symmetrize
    VRoid Bone Names on X-Axis has run."""
    return rf"(?:J_Bip_{{s}}_{part}|{part}_{{s}})"


_VROID_FINGERS = {"thumb": "Thumb", "index": "Index", "middle": "Middle", "ring": "Ring", "pinky": "Little"}
VROID = NamingScheme(
    "vroid", "VRoid Studio (J_Bip_*, also symmetrised by the VRM add-on)",
    {"l": "L", "r": "R"},
    (
        _p("root", r"Root"),
        _p("pelvis", r"(?:J_Bip_C_)?Hips"),
        _p("head", r"(?:J_Bip_C_)?Head"),
        _p("clavicle_{s}", _vroid("Shoulder")),
        _p("upperarm_{s}", _vroid("UpperArm")),
        _p("forearm_{s}", _vroid("LowerArm")),
        _p("hand_{s}", _vroid("Hand")),
        _p("thigh_{s}", _vroid("UpperLeg")),
        _p("shin_{s}", _vroid("LowerLeg")),
        _p("foot_{s}", _vroid("Foot")),
        _p("toe_{s}", _vroid("ToeBase")),
        _p("breast_{s}", r"(?:J_Sec_{s}_Bust1|Bust1_{s})"),  # spring bones: follow the chest
        *[_p(f"{f}_{i}_{{s}}", _vroid(f"{_VROID_FINGERS[f]}{i}")) for f in FINGERS for i in (1, 2, 3)],
    ),
    (("spine", r"(?:J_Bip_C_)?(Spine|Chest|UpperChest)", _VRM_CHAIN_ORDER),
     ("neck", r"(?:J_Bip_C_)?(Neck)", _VRM_CHAIN_ORDER)),
)

# The armature the VRM add-on for Blender creates (Add > Armature > VRM Humanoid): snake_case
# VRM names with Blender's .L/.R; fingers "index_proximal.L" (also "index.proximal.L").
VRM_ADDON = NamingScheme(
    "vrm_addon", "VRM add-on for Blender's humanoid armature (hips, upper_arm.L)",
    {"l": "L", "r": "R"},
    (
        _p("root", r"root"),
        _p("pelvis", r"hips"),
        _p("head", r"head"),
        _p("clavicle_{s}", r"shoulder\.{s}"),
        _p("upperarm_{s}", r"upper_arm\.{s}"),
        _p("forearm_{s}", r"lower_arm\.{s}"),
        _p("hand_{s}", r"hand\.{s}"),
        _p("thigh_{s}", r"upper_leg\.{s}"),
        _p("shin_{s}", r"lower_leg\.{s}"),
        _p("foot_{s}", r"foot\.{s}"),
        _p("toe_{s}", r"toes\.{s}"),
        _p("thumb_1_{s}", r"thumb[._]metacarpal\.{s}", r"thumb[._]proximal\.{s}"),
        _p("thumb_2_{s}", r"thumb[._]proximal\.{s}", r"thumb[._]intermediate\.{s}"),
        _p("thumb_3_{s}", r"thumb[._]distal\.{s}"),
        *_fingers(r"{finger}[._]{n}\.{{s}}", {f: n.lower() for f, n in _VRM_FINGERS.items()},
                  tuple(p.lower() for p in _VRM_PHALANGES), skip=("thumb",)),
    ),
    (("spine", r"(spine|chest|upper_chest)", _VRM_CHAIN_ORDER), ("neck", r"(neck)", _VRM_CHAIN_ORDER)),
)

# MakeHuman's default skeleton (MPFB2 rig.default, 163 bones; rig.default_no_toes): the hips
# root is "root", the spine is numbered top-down (spine05 lowest), limbs are split in two
# (upperarm01 + upperarm02: the segment is the 01 bone, whose head is the joint); clavicle.L
# runs from the sternum and shoulder01.L on to the shoulder joint (it follows the clavicle).
# Toes: the middle toe's base bone (default) or the one toe bone (default_no_toes).
MAKEHUMAN = NamingScheme(
    "makehuman", "MakeHuman / MPFB default skeleton (root, spine05..01, upperarm01.L)",
    {"l": "L", "r": "R"},
    (
        _p("pelvis", r"root"),
        _p("head", r"head"),
        _p("clavicle_{s}", r"clavicle\.{s}"),
        _p("upperarm_{s}", r"upperarm01\.{s}"),
        _p("forearm_{s}", r"lowerarm01\.{s}"),
        _p("hand_{s}", r"wrist\.{s}"),
        _p("thigh_{s}", r"upperleg01\.{s}"),
        _p("shin_{s}", r"lowerleg01\.{s}"),
        _p("foot_{s}", r"foot\.{s}"),
        _p("toe_{s}", r"toe3-1\.{s}", r"toe1-1\.{s}"),
        _p("pelvis_side_{s}", r"pelvis\.{s}"),
        _p("breast_{s}", r"breast\.{s}"),
        *[_p(f"metacarpal_{f}_{{s}}", rf"metacarpal{k}\.{{s}}") for k, f in enumerate(FINGERS[1:], start=1)],
        *[_p(f"{f}_{i}_{{s}}", rf"finger{k}-{i}\.{{s}}") for k, f in enumerate(FINGERS, start=1) for i in (1, 2, 3)],
    ),
    (("spine", r"spine(0[1-5])", "descending"), ("neck", r"neck(0\d)", None)),
)

# Daz Genesis 3 and 8 (as the Diffeomorphic importer brings them into Blender): "hip" is the
# hips root (hip -> pelvis -> thighs, hip -> abdomenLower); limbs split into Bend + Twist bones,
# the segment being the Bend bone (its head is the joint); lCarpal1..4 are the metacarpals of
# the index..pinky. Genesis 1 and 2 names (lShldr, lForeArm, lThigh, abdomen, chest, neck) are
# the second choices.
_DAZ8_SPINE = {"abdomenlower": 0, "abdomen": 0, "abdomenupper": 1, "abdomen2": 1, "chestlower": 2, "chest": 2,
               "chestupper": 3}
DAZ_GENESIS8 = NamingScheme(
    "daz_genesis8", "Daz Genesis 3 / 8 (hip, abdomenLower, lShldrBend)",
    {"l": "l", "r": "r"},
    (
        _p("pelvis", r"hip"),
        _p("head", r"head"),
        _p("clavicle_{s}", r"{s}Collar"),
        _p("upperarm_{s}", r"{s}ShldrBend", r"{s}Shldr"),
        _p("forearm_{s}", r"{s}ForearmBend", r"{s}ForeArm"),
        _p("hand_{s}", r"{s}Hand"),
        _p("thigh_{s}", r"{s}ThighBend", r"{s}Thigh"),
        _p("shin_{s}", r"{s}Shin"),
        _p("foot_{s}", r"{s}Foot"),
        _p("toe_{s}", r"{s}Toe"),
        _p("breast_{s}", r"{s}Pectoral"),
        _p("heel_{s}", r"{s}Heel"),
        *[_p(f"metacarpal_{f}_{{s}}", rf"{{s}}Carpal{k}") for k, f in enumerate(FINGERS[1:], start=1)],
        *_fingers(r"{{s}}{finger}{n}", {"thumb": "Thumb", "index": "Index", "middle": "Mid", "ring": "Ring",
                                        "pinky": "Pinky"}),
    ),
    (("spine", r"(abdomenLower|abdomenUpper|chestLower|chestUpper|abdomen2?|chest)", _DAZ8_SPINE),
     ("neck", r"(neckLower|neckUpper|neck)", {"necklower": 0, "neck": 0, "neckupper": 1})),
)

# Daz Genesis 9: snake_case with the side first (l_upperarm, l_upperarmtwist1, l_indexmetacarpal),
# the spine spine1..4, the neck neck1..2; "hip" is the hips root as in Genesis 8.
DAZ_GENESIS9 = NamingScheme(
    "daz_genesis9", "Daz Genesis 9 (hip, spine1, l_upperarm)",
    {"l": "l", "r": "r"},
    (
        _p("pelvis", r"hip"),
        _p("head", r"head"),
        _p("clavicle_{s}", r"{s}_shoulder"),
        _p("upperarm_{s}", r"{s}_upperarm"),
        _p("forearm_{s}", r"{s}_forearm"),
        _p("hand_{s}", r"{s}_hand"),
        _p("thigh_{s}", r"{s}_thigh"),
        _p("shin_{s}", r"{s}_shin"),
        _p("foot_{s}", r"{s}_foot"),
        _p("toe_{s}", r"{s}_toes"),
        _p("breast_{s}", r"{s}_pectoral"),
        *[_p(f"metacarpal_{f}_{{s}}", rf"{{s}}_{n}metacarpal")
          for f, n in (("index", "index"), ("middle", "mid"), ("ring", "ring"), ("pinky", "pinky"))],
        *_fingers(r"{{s}}_{finger}{n}", {"thumb": "thumb", "index": "index", "middle": "mid", "ring": "ring",
                                         "pinky": "pinky"}),
    ),
    (("spine", r"spine(\d)", None), ("neck", r"neck(\d)", None)),
)

# Reallusion Character Creator 3/4, iClone, ActorCore and AccuRIG: CC_Base_Hip is the hips root
# (Hip -> Pelvis -> thighs, Hip -> Waist -> Spine01 -> Spine02 -> NeckTwist01 -> NeckTwist02 ->
# Head); twist and share bones (CC_Base_L_UpperarmTwist01, CC_Base_L_ElbowShareBone) hang off
# the limb bones and follow them. Fingers are Thumb1 / Index1 / Mid1 ... or, in older exports,
# Finger00..02 (thumb) to Finger40..42 (pinky).
_CC_FINGERS = {"thumb": ("Thumb", 0), "index": ("Index", 1), "middle": ("Mid", 2), "ring": ("Ring", 3),
               "pinky": ("Pinky", 4)}
CHARACTER_CREATOR = NamingScheme(
    "character_creator", "Character Creator / iClone / ActorCore (CC_Base_*)",
    {"l": "L", "r": "R"},
    (
        _p("root", r"CC_Base_BoneRoot"),
        _p("pelvis", r"CC_Base_Hip"),
        _p("head", r"CC_Base_Head"),
        _p("clavicle_{s}", r"CC_Base_{s}_Clavicle"),
        _p("upperarm_{s}", r"CC_Base_{s}_Upperarm"),
        _p("forearm_{s}", r"CC_Base_{s}_Forearm"),
        _p("hand_{s}", r"CC_Base_{s}_Hand"),
        _p("thigh_{s}", r"CC_Base_{s}_Thigh"),
        _p("shin_{s}", r"CC_Base_{s}_Calf"),
        _p("foot_{s}", r"CC_Base_{s}_Foot"),
        _p("toe_{s}", r"CC_Base_{s}_ToeBase"),
        _p("breast_{s}", r"CC_Base_{s}_Breast"),
        *[_p(f"{f}_{i}_{{s}}", rf"CC_Base_{{s}}_{word}{i}", rf"CC_Base_{{s}}_Finger{k}{i - 1}")
          for f, (word, k) in _CC_FINGERS.items() for i in (1, 2, 3)],
    ),
    (("spine", r"CC_Base_(Waist|Spine01|Spine02)", {"waist": 0, "spine01": 1, "spine02": 2}),
     ("neck", r"CC_Base_NeckTwist(\d+)", None)),
)

# Rigs made in Blender with its .L / .R side suffix and plain words (Quaternius' characters, game
# rigs: Hips, Abdomen / Torso / Chest or Spine, UpperArm.L, LowerArm.L, Hand.L or Palm.L, UpperLeg.L,
# LowerLeg.L, Foot.L); fingers numbered from 1 or 2 (`digits`). Listed after the VRM add-on's
# scheme, whose snake_case names it also reads: a tie keeps that one.
BLENDER_SIDED = NamingScheme(
    "blender_sided", "Blender .L/.R names (Quaternius, game rigs: Hips, UpperArm.L, LowerLeg.L)",
    {"l": "L", "r": "R"},
    (
        _p("root", r"root"),
        _p("pelvis", r"hips", r"pelvis"),
        _p("head", r"head"),
        _p("clavicle_{s}", r"shoulder\.{s}", r"clavicle\.{s}"),
        _p("upperarm_{s}", r"upper_?arm\.{s}", r"arm\.{s}"),
        _p("forearm_{s}", r"(?:lower_?|fore_?)arm\.{s}"),
        _p("hand_{s}", r"hand\.{s}", r"palm\.{s}", r"palm2\.{s}"),
        _p("thigh_{s}", r"upper_?leg\.{s}", r"thigh\.{s}"),
        _p("shin_{s}", r"lower_?leg\.{s}", r"shin\.{s}", r"calf\.{s}", r"leg\.{s}"),
        _p("foot_{s}", r"foot\.{s}"),
        _p("toe_{s}", r"toes?\.{s}", r"toe_?base\.{s}", r"ball\.{s}"),
    ),
    (("spine", r"(spine\d?|abdomen|torso|chest|upper_?chest)",
      {"spine": 0, "spine1": 1, "spine2": 2, "spine3": 3, "abdomen": 0, "torso": 1, "chest": 2, "upperchest": 3}),
     ("neck", r"neck(\d*)", None)),
    (r"{finger}(\d*)\.{s}", {"thumb": "thumb", "index": "index", "middle": "middle", "ring": "ring",
                              "pinky": "(?:pinky|little)"}),
)

SCHEMES: tuple[NamingScheme, ...] = (UNREAL, RIGIFY_METARIG, RIGIFY, MIXAMO, CMU_MB, CMU_JOINTS, VRM_HUMANOID, VROID,
                                     VRM_ADDON, BLENDER_SIDED, MAKEHUMAN, DAZ_GENESIS8, DAZ_GENESIS9,
                                     CHARACTER_CREATOR)
SCHEME_BY_NAME: dict[str, NamingScheme] = {s.name: s for s in SCHEMES}


@dataclass
class BoneMap:
    """Avatar bone names for each segment; chains are ordered bottom-up."""

    scheme: str
    bones: dict[str, str]
    chains: dict[str, list[str]]
    unmapped: list[str]

    def missing(self, with_fingers: bool = False) -> list[str]:
        have = set(self.bones) | {k for k, v in self.chains.items() if v}
        return [s for s in required_segments(with_fingers) if s not in have]

    def to_dict(self) -> dict:
        return {"scheme": self.scheme, "bones": dict(self.bones),
                "chains": {k: list(v) for k, v in self.chains.items()}, "unmapped": list(self.unmapped)}

    @classmethod
    def from_dict(cls, d: dict) -> BoneMap:
        return cls(d.get("scheme", "custom"), dict(d.get("bones", {})),
                   {k: list(v) for k, v in d.get("chains", {}).items()}, list(d.get("unmapped", [])))

    def same_mapping(self, other: BoneMap) -> bool:
        """The same bone for every segment and the same chains (the scheme's label aside)."""
        def chains(bm):
            return {k: list(v) for k, v in bm.chains.items() if v}
        return self.bones == other.bones and chains(self) == chains(other)


@dataclass(frozen=True, eq=False)  # hashed by identity: a cache key
class _CompiledScheme:
    segments: tuple[str, ...]
    regexes: tuple[tuple[int, int, re.Pattern], ...]  # (segment index, priority, regex)
    chains: tuple[tuple[str, re.Pattern, object], ...]


_COMPILED: dict[int, tuple[NamingScheme, _CompiledScheme]] = {}


def _compiled(scheme: NamingScheme) -> _CompiledScheme:
    got = _COMPILED.get(id(scheme))
    if got is None or got[0] is not scheme:
        segments, regexes = [], []
        for seg_t, templates in scheme.patterns:
            sides = scheme.side_tokens.items() if "{s}" in seg_t else [(None, None)]
            for side, token in sides:
                seg = seg_t if side is None else seg_t.replace("{s}", side)
                if seg not in segments:
                    segments.append(seg)
                k = segments.index(seg)
                base = sum(1 for r in regexes if r[0] == k)  # a segment listed again: its first entry wins
                for prio, rx in enumerate(templates):
                    regexes.append((k, base + prio, re.compile(rx if token is None else rx.replace("{s}", token),
                                                               re.I)))
        chains = tuple((c, re.compile(rx, re.I), order) for c, rx, order in scheme.chains)
        got = (scheme, _CompiledScheme(tuple(segments), tuple(regexes), chains))
        _COMPILED[id(scheme)] = got
    return got[1]


@functools.lru_cache(maxsize=1 << 16)
def _name_matches(comp: _CompiledScheme, name: str) -> tuple[tuple[tuple[int, int], ...], tuple | None]:
    """What one bone name matches in a scheme: (segment index, priority) pairs, and its chain
    (segment, rank) or None. Cached: detection runs every scheme over every bone, and the panel
    and the tests detect the same names again and again."""
    singles = tuple((k, prio) for k, prio, rx in comp.regexes if rx.fullmatch(name))
    for chain, rx, order in comp.chains:
        m = rx.fullmatch(name)
        if m:
            return singles, (chain, _chain_rank(m.group(1), order))
    return singles, None


def _chain_rank(token: str, order) -> float:
    if isinstance(order, dict):
        return float(order.get(re.sub(r"[ _.]", "", token.lower()), 99))
    value = float(token) if token.isdigit() else 0.0
    return -value if order == "descending" else value


def map_with_scheme(bone_names: list[str], scheme: NamingScheme) -> BoneMap:
    """Map bone names with one scheme: whole-name matches, letter case ignored. Each segment, in
    the scheme's order, takes the bone its highest-priority expression matches (ties: the first
    name in sorted order) and each bone serves one segment, so the map does not depend on the
    order of `bone_names`. Bones left over go to a chain whose expression they match, else to
    `unmapped` (in the order given)."""
    comp = _compiled(scheme)
    names = list(dict.fromkeys(bone_names))
    matches = {n: _name_matches(comp, n) for n in names}
    candidates: dict[int, list[tuple[int, str]]] = {}
    for n, (singles, _chain) in matches.items():
        for k, prio in singles:
            candidates.setdefault(k, []).append((prio, n))
    bones: dict[str, str] = {}
    taken: set[str] = set()
    for k, seg in enumerate(comp.segments):
        free = sorted(c for c in candidates.get(k, ()) if c[1] not in taken)
        if free:
            bones[seg] = free[0][1]
            taken.add(free[0][1])
    if scheme.digits:
        _map_digits(names, scheme, bones, taken)
    chain_hits: dict[str, list[tuple[float, str]]] = {c: [] for c, _rx, _o in comp.chains}
    unmapped = []
    for n in names:
        if n in taken:
            continue
        chain = matches[n][1]
        if chain is None:
            unmapped.append(n)
        else:
            chain_hits[chain[0]].append((chain[1], n))
    chains = {c: [n for _, n in sorted(hits)] for c, hits in chain_hits.items()}
    return BoneMap(scheme.name, bones, chains, unmapped)


def _map_digits(names: list[str], scheme: NamingScheme, bones: dict[str, str], taken: set[str]) -> None:
    """Phalanges 1..3 of each finger from `scheme.digits`: its three lowest-numbered free bones
    (no number counts as 0), for a finger none of whose phalanges is mapped yet."""
    template, words = scheme.digits
    for finger in FINGERS:
        for side, token in scheme.side_tokens.items():
            segments = [f"{finger}_{i}_{side}" for i in (1, 2, 3)]
            if any(seg in bones for seg in segments):
                continue
            rx = re.compile(template.replace("{finger}", words[finger]).replace("{s}", token), re.I)
            hits = sorted((int(m.group(1) or 0), n) for n in names if n not in taken and (m := rx.fullmatch(n)))
            if len(hits) >= 3:
                for seg, (_num, n) in zip(segments, hits):
                    bones[seg] = n
                    taken.add(n)


def head_from_neck(bm: BoneMap) -> bool:
    """A map without a head bone takes the top of its neck chain as the head (a base mesh's
    metarig with its head bone removed: spine.004-005 and no spine.006; the head's skin then
    rides on that bone). Changes `bm` in place; True when it did."""
    neck = bm.chains.get("neck") or []
    if "head" in bm.bones or len(neck) < 2:
        return False
    bm.bones["head"] = neck[-1]
    bm.chains["neck"] = neck[:-1]
    return True


def detect_bone_map(bone_names: list[str]) -> BoneMap:
    """The scheme that maps the most bones (ties: the fewest missing required segments, then the
    first in SCHEMES); without a head bone, the top of the neck is the head (`head_from_neck`)."""
    best = None
    names = list(dict.fromkeys(bone_names))
    for scheme in SCHEMES:
        bm = map_with_scheme(names, scheme)
        score = (len(names) - len(bm.unmapped), -len(bm.missing()))
        if best is None or score > best[0]:
            best = (score, bm)
    head_from_neck(best[1])
    return best[1]
