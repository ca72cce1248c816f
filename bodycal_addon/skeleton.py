"""The canonical skeleton (DESIGN.md §2) and bone maps from avatar naming schemes to it.

Joints are points; bones link a head joint to a tail joint. Every user body model and every
avatar body model names its joints and bones this way, so the egocentric mapping can pair the
user's surface elements with the avatar's one to one.

Spine (Delahaye 2023, appendix B "Trunk calibration"): the user model has 12 vertebrae of equal
length from `spine_root` up to `skull_base`. Vertebra bone `spine_k` runs from joint
`spine_{k-1}` (`spine_root` for k = 1) to joint `spine_k`; joint `spine_12` is the top of the
spine and coincides with `skull_base`. Clavicles start at joint `spine_05`, the top of the fifth
vertebra. Avatars may have fewer spine bones: their spine joints are resampled along the
avatar's spine curve (see `resample_polyline`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

SIDES = ("l", "r")
FINGERS = ("thumb", "index", "middle", "ring", "pinky")
SPINE_COUNT = 12
CLAVICLE_VERTEBRA = 5
FINGER_JOINTS = ("mcp", "pip", "dip", "tip")


def spine_joint(k: int) -> str:
    """Name of the joint at the top of vertebra k (1..12); k = 0 is the spine root."""
    return "spine_root" if k == 0 else f"spine_{k:02d}"


def _joint_names() -> tuple[str, ...]:
    names = ["pelvis", "spine_root"]
    names += [spine_joint(k) for k in range(1, SPINE_COUNT + 1)]
    names += ["skull_base", "head"]
    for s in SIDES:
        names += [f"clavicle_{s}", f"shoulder_{s}", f"elbow_{s}", f"wrist_{s}"]
        for f in FINGERS:
            names += [f"{j}_{f}_{s}" for j in FINGER_JOINTS]
        names += [f"hip_{s}", f"knee_{s}", f"ankle_{s}", f"toe_{s}"]
    return tuple(names)


JOINTS: tuple[str, ...] = _joint_names()


@dataclass(frozen=True)
class Bone:
    name: str
    head: str
    tail: str
    parent: str | None
    hinge: bool = False  # flexes about its local +X only (FORMATS.md §1)
    shortcut: bool = False  # used only for kinematic-path normalisation (DESIGN.md §5)


def _bones() -> tuple[Bone, ...]:
    bones = [Bone("sacrum", "pelvis", "spine_root", None)]
    for k in range(1, SPINE_COUNT + 1):
        parent = "sacrum" if k == 1 else f"spine_{k - 1:02d}"
        bones.append(Bone(f"spine_{k:02d}", spine_joint(k - 1), spine_joint(k), parent))
    bones.append(Bone("head", "skull_base", "head", f"spine_{SPINE_COUNT:02d}"))
    for s in SIDES:
        bones += [
            Bone(f"clavicle_{s}", spine_joint(CLAVICLE_VERTEBRA), f"shoulder_{s}", f"spine_{CLAVICLE_VERTEBRA:02d}"),
            Bone(f"upperarm_{s}", f"shoulder_{s}", f"elbow_{s}", f"clavicle_{s}"),
            Bone(f"forearm_{s}", f"elbow_{s}", f"wrist_{s}", f"upperarm_{s}", hinge=True),
        ]
        # The hand as one rigid body (the hand tracker's / glove's frame), wrist to middle base.
        bones.append(Bone(f"hand_{s}", f"wrist_{s}", f"mcp_middle_{s}", f"forearm_{s}"))
        for f in FINGERS:
            bones += [
                Bone(f"metacarpal_{f}_{s}", f"wrist_{s}", f"mcp_{f}_{s}", f"hand_{s}"),
                Bone(f"{f}_1_{s}", f"mcp_{f}_{s}", f"pip_{f}_{s}", f"metacarpal_{f}_{s}"),
                Bone(f"{f}_2_{s}", f"pip_{f}_{s}", f"dip_{f}_{s}", f"{f}_1_{s}", hinge=True),
                Bone(f"{f}_3_{s}", f"dip_{f}_{s}", f"tip_{f}_{s}", f"{f}_2_{s}", hinge=True),
            ]
        bones += [
            Bone(f"hip_{s}", "pelvis", f"hip_{s}", "sacrum", shortcut=True),
            Bone(f"thigh_{s}", f"hip_{s}", f"knee_{s}", "sacrum"),
            Bone(f"shin_{s}", f"knee_{s}", f"ankle_{s}", f"thigh_{s}", hinge=True),
            Bone(f"foot_{s}", f"ankle_{s}", f"toe_{s}", f"shin_{s}"),
        ]
    # Shortcut bones of Delahaye 2023, appendix D "Trunk animation": sacrum to the clavicle root,
    # clavicle root to the head. They carry no twist: only their axis is used (τ, DESIGN.md §5).
    bones += [
        Bone("shortcut_sacrum_clavicles", "pelvis", spine_joint(CLAVICLE_VERTEBRA), "sacrum", shortcut=True),
        Bone("shortcut_clavicles_head", spine_joint(CLAVICLE_VERTEBRA), "skull_base",
             "shortcut_sacrum_clavicles", shortcut=True),
    ]
    return tuple(bones)


BONES: tuple[Bone, ...] = _bones()
BONE_BY_NAME: dict[str, Bone] = {b.name: b for b in BONES}
JOINT_INDEX: dict[str, int] = {name: i for i, name in enumerate(JOINTS)}

# Body segments an avatar's bones map onto. `spine` and `neck` are chains (ordered bottom-up);
# the rest are single bones. Auxiliary segments (breast, pelvis side, heel) follow their parent
# and are never driven: they are mapped so that every body bone of a rig has a known role.
CHAIN_SEGMENTS = ("spine", "neck")


def _segments() -> tuple[str, ...]:
    seg = ["root", "pelvis", "spine", "neck", "head"]
    for s in SIDES:
        seg += [f"clavicle_{s}", f"upperarm_{s}", f"forearm_{s}", f"hand_{s}"]
        for f in FINGERS:
            seg += [f"metacarpal_{f}_{s}", f"{f}_1_{s}", f"{f}_2_{s}", f"{f}_3_{s}"]
        seg += [f"thigh_{s}", f"shin_{s}", f"foot_{s}", f"toe_{s}"]
        seg += [f"breast_{s}", f"pelvis_side_{s}", f"heel_{s}"]
    return tuple(seg)


SEGMENTS: tuple[str, ...] = _segments()
AUXILIARY_SEGMENTS = frozenset(
    s for s in SEGMENTS if s == "root" or s.startswith(("breast_", "pelvis_side_", "heel_", "metacarpal_"))
)
OPTIONAL_SEGMENTS = AUXILIARY_SEGMENTS | {"neck"} | {f"toe_{s}" for s in SIDES}


def required_segments(with_fingers: bool = False) -> tuple[str, ...]:
    """Segments a humanoid avatar must have mapped to be retargeted."""
    req = [s for s in SEGMENTS if s not in OPTIONAL_SEGMENTS]
    if not with_fingers:
        req = [s for s in req if not any(s.startswith(f + "_") for f in FINGERS)]
    return tuple(req)


# --- Bone maps -------------------------------------------------------------------------------
# A scheme turns an avatar bone name into (segment, chain position). Each scheme is a list of
# regular expressions over the bone name; `{s}` stands for the side as the scheme writes it.

@dataclass(frozen=True)
class NamingScheme:
    name: str
    side_tokens: dict[str, str]  # canonical side -> how the scheme writes it
    patterns: tuple[tuple[str, str], ...]  # (segment template, regex template)
    chains: tuple[tuple[str, str], ...] = ()  # (chain segment, regex with one numbered group)


def _finger_patterns(fmt: str, names: dict[str, str], phalanx_numbers: tuple[str, str, str]):
    out = []
    for f in FINGERS:
        for i, num in enumerate(phalanx_numbers, start=1):
            out.append((f"{f}_{i}_{{s}}", fmt.format(finger=names[f], n=num)))
    return out


_UNREAL_FINGERS = {f: f for f in FINGERS}
UNREAL = NamingScheme(
    "unreal",
    {"l": "l", "r": "r"},
    (
        ("root", r"root"),
        ("pelvis", r"pelvis"),
        ("head", r"head"),
        ("clavicle_{s}", r"clavicle_{s}"),
        ("upperarm_{s}", r"upperarm_{s}"),
        ("forearm_{s}", r"lowerarm_{s}"),
        ("hand_{s}", r"hand_{s}"),
        ("thigh_{s}", r"thigh_{s}"),
        ("shin_{s}", r"calf_{s}"),
        ("foot_{s}", r"foot_{s}"),
        ("toe_{s}", r"ball_{s}"),
        *[(f"metacarpal_{f}_{{s}}", rf"{f}_metacarpal_{{s}}") for f in FINGERS],
        *_finger_patterns(r"{finger}_{n}_{{s}}", _UNREAL_FINGERS, ("01", "02", "03")),
    ),
    (("spine", r"spine_?(\d+)"), ("neck", r"neck_?(\d+)")),
)

_RIGIFY_FINGERS = {"thumb": "thumb", "index": "f_index", "middle": "f_middle", "ring": "f_ring",
                   "pinky": "f_pinky"}
RIGIFY_METARIG = NamingScheme(
    "rigify_metarig",
    {"l": "L", "r": "R"},
    (
        ("pelvis", r"spine"),
        ("head", r"spine\.006"),
        ("clavicle_{s}", r"shoulder\.{s}"),
        ("upperarm_{s}", r"upper_arm\.{s}"),
        ("forearm_{s}", r"forearm\.{s}"),
        ("hand_{s}", r"hand\.{s}"),
        ("thigh_{s}", r"thigh\.{s}"),
        ("shin_{s}", r"shin\.{s}"),
        ("foot_{s}", r"foot\.{s}"),
        ("toe_{s}", r"toe\.{s}"),
        ("breast_{s}", r"breast\.{s}"),
        ("pelvis_side_{s}", r"pelvis\.{s}"),
        ("heel_{s}", r"heel\.02\.{s}"),
        # Rigify's palm.01 carries the index and the thumb; palm.02..04 the other fingers.
        ("metacarpal_index_{s}", r"palm\.01\.{s}"),
        ("metacarpal_middle_{s}", r"palm\.02\.{s}"),
        ("metacarpal_ring_{s}", r"palm\.03\.{s}"),
        ("metacarpal_pinky_{s}", r"palm\.04\.{s}"),
        *_finger_patterns(r"{finger}\.{n}\.{{s}}", _RIGIFY_FINGERS, ("01", "02", "03")),
    ),
    # spine.001..003 are the trunk, spine.004..005 the neck (metarig's human layout).
    (("spine", r"spine\.(00[1-3])"), ("neck", r"spine\.(00[45])")),
)

_MIXAMO_FINGERS = {"thumb": "Thumb", "index": "Index", "middle": "Middle", "ring": "Ring", "pinky": "Pinky"}
MIXAMO = NamingScheme(
    "mixamo",
    {"l": "Left", "r": "Right"},
    (
        ("pelvis", r"(?:mixamorig\d*:)?Hips"),
        ("head", r"(?:mixamorig\d*:)?Head"),
        ("clavicle_{s}", r"(?:mixamorig\d*:)?{s}Shoulder"),
        ("upperarm_{s}", r"(?:mixamorig\d*:)?{s}Arm"),
        ("forearm_{s}", r"(?:mixamorig\d*:)?{s}ForeArm"),
        ("hand_{s}", r"(?:mixamorig\d*:)?{s}Hand"),
        ("thigh_{s}", r"(?:mixamorig\d*:)?{s}UpLeg"),
        ("shin_{s}", r"(?:mixamorig\d*:)?{s}Leg"),
        ("foot_{s}", r"(?:mixamorig\d*:)?{s}Foot"),
        ("toe_{s}", r"(?:mixamorig\d*:)?{s}ToeBase"),
        *_finger_patterns(r"(?:mixamorig\d*:)?{{s}}Hand{finger}{n}", _MIXAMO_FINGERS, ("1", "2", "3")),
    ),
    (("spine", r"(?:mixamorig\d*:)?Spine(\d*)"), ("neck", r"(?:mixamorig\d*:)?Neck(\d*)")),
)

_VRM_FINGERS = {"thumb": "Thumb", "index": "Index", "middle": "Middle", "ring": "Ring", "pinky": "Little"}
_VRM_BODY = (
    ("pelvis", r"(?:J_Bip_C_)?hips"),
    ("head", r"(?:J_Bip_C_)?head"),
    ("clavicle_{s}", r"{s}Shoulder"),
    ("upperarm_{s}", r"{s}UpperArm"),
    ("forearm_{s}", r"{s}LowerArm"),
    ("hand_{s}", r"{s}Hand"),
    ("thigh_{s}", r"{s}UpperLeg"),
    ("shin_{s}", r"{s}LowerLeg"),
    ("foot_{s}", r"{s}Foot"),
    ("toe_{s}", r"{s}Toes"),
)
_VRM_NON_THUMB = tuple(p for p in _finger_patterns(r"{{s}}{finger}{n}", _VRM_FINGERS,
                                                   ("Proximal", "Intermediate", "Distal"))
                       if not p[0].startswith("thumb"))
# VRM humanoid bones: spine, chest, upperChest (bottom-up), neck.
_VRM_CHAINS = (("spine", r"(spine|chest|upperChest)"), ("neck", r"(neck)"))
VRM0 = NamingScheme(
    "vrm0", {"l": "left", "r": "right"},
    _VRM_BODY + _VRM_NON_THUMB + tuple(_finger_patterns(r"{{s}}{finger}{n}", _VRM_FINGERS,
                                                        ("Proximal", "Intermediate", "Distal"))[:3]),
    _VRM_CHAINS,
)
# VRM 1.0 renamed the thumb: Metacarpal, Proximal, Distal are its phalanges 1..3.
VRM1 = NamingScheme(
    "vrm1", {"l": "left", "r": "right"},
    _VRM_BODY + _VRM_NON_THUMB + tuple(_finger_patterns(r"{{s}}{finger}{n}", _VRM_FINGERS,
                                                        ("Metacarpal", "Proximal", "Distal"))[:3]),
    _VRM_CHAINS,
)

SCHEMES: tuple[NamingScheme, ...] = (UNREAL, RIGIFY_METARIG, MIXAMO, VRM0, VRM1)
_VRM_CHAIN_ORDER = {"spine": 0, "chest": 1, "upperchest": 2, "neck": 0}


def _chain_key(token: str) -> float:
    if token == "":
        return 0.0
    if token.isdigit():
        return float(token)
    return float(_VRM_CHAIN_ORDER.get(token.lower(), 99))


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


def map_with_scheme(bone_names: list[str], scheme: NamingScheme) -> BoneMap:
    """Map bone names with one scheme; case-insensitive, whole-name matches only."""
    compiled: list[tuple[str, re.Pattern]] = []
    for seg_t, rx_t in scheme.patterns:
        if "{s}" in seg_t or "{s}" in rx_t:
            for side, token in scheme.side_tokens.items():
                compiled.append((seg_t.replace("{s}", side), re.compile(rx_t.replace("{s}", token), re.I)))
        else:
            compiled.append((seg_t, re.compile(rx_t, re.I)))
    bones: dict[str, str] = {}
    chain_hits: dict[str, list[tuple[float, str]]] = {c: [] for c, _ in scheme.chains}
    unmapped = []
    chain_rx = [(c, re.compile(rx, re.I)) for c, rx in scheme.chains]
    for name in bone_names:
        seg = next((s for s, rx in compiled if rx.fullmatch(name)), None)
        if seg is not None and seg not in bones:
            bones[seg] = name
            continue
        for chain, rx in chain_rx:
            m = rx.fullmatch(name)
            if m:
                chain_hits[chain].append((_chain_key(m.group(1)), name))
                break
        else:
            unmapped.append(name)
    chains = {c: [n for _, n in sorted(hits)] for c, hits in chain_hits.items()}
    return BoneMap(scheme.name, bones, chains, unmapped)


def detect_bone_map(bone_names: list[str]) -> BoneMap:
    """The scheme that maps the most bones (ties: the fewest missing required segments)."""
    best = None
    for scheme in SCHEMES:
        bm = map_with_scheme(bone_names, scheme)
        score = (len(bone_names) - len(bm.unmapped), -len(bm.missing()))
        if best is None or score > best[0]:
            best = (score, bm)
    return best[1]


def resample_polyline(points: np.ndarray, count: int) -> np.ndarray:
    """`count + 1` points at equal arc length along a polyline (…, n, 3): spine joints for an
    avatar whose spine has a different number of bones than the canonical 12."""
    pts = np.asarray(points, dtype=float)
    seg = np.linalg.norm(np.diff(pts, axis=-2), axis=-1)
    cum = np.concatenate([np.zeros(seg.shape[:-1] + (1,)), np.cumsum(seg, axis=-1)], axis=-1)
    targets = np.linspace(0.0, 1.0, count + 1) * cum[..., -1:]
    out = np.empty(pts.shape[:-2] + (count + 1, 3))
    for axis in range(3):
        out[..., axis] = _interp_rows(np.broadcast_to(targets, cum.shape[:-1] + (count + 1,)), cum,
                                      pts[..., axis])
    return out


def _interp_rows(x: np.ndarray, xp: np.ndarray, fp: np.ndarray) -> np.ndarray:
    """np.interp row by row without a Python loop: polylines are short (a few bones), so the
    segment index is a comparison count."""
    idx = np.clip((x[..., :, None] >= xp[..., None, :]).sum(-1) - 1, 0, xp.shape[-1] - 2)
    x0 = np.take_along_axis(xp, idx, -1)
    x1 = np.take_along_axis(xp, idx + 1, -1)
    f0 = np.take_along_axis(fp, idx, -1)
    f1 = np.take_along_axis(fp, idx + 1, -1)
    span = x1 - x0
    t = np.divide(x - x0, span, out=np.zeros_like(span), where=span > 0)
    return f0 + t * (f1 - f0)
