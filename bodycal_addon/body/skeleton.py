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
# A rig without clavicles (CesiumMan's arms hang from the chest) is retargeted with the clavicle
# joint where the spine puts it (rest_frames.complete_joints: spine_05), riding on the chest.
OPTIONAL_SEGMENTS = AUXILIARY_SEGMENTS | {"neck"} | {f"{part}_{s}" for part in ("toe", "clavicle") for s in SIDES}


def required_segments(with_fingers: bool = False) -> tuple[str, ...]:
    """Segments a humanoid avatar must have mapped to be retargeted."""
    req = [s for s in SEGMENTS if s not in OPTIONAL_SEGMENTS]
    if not with_fingers:
        req = [s for s in req if not any(s.startswith(f + "_") for f in FINGERS)]
    return tuple(req)

# Index tables of the canonical skeleton, shared by every stage that works on (..., B) or (..., J) arrays.
BONE_INDEX: dict[str, int] = {b.name: i for i, b in enumerate(BONES)}
SPINE_JOINTS: tuple[str, ...] = tuple(spine_joint(k) for k in range(SPINE_COUNT + 1))  # spine_root, spine_01..12
SPINE_BONES: tuple[str, ...] = tuple(f"spine_{k:02d}" for k in range(1, SPINE_COUNT + 1))
HINGE_BONES: frozenset[str] = frozenset(b.name for b in BONES if b.hinge)
REQUIRED_JOINTS = ("pelvis", "spine_root", "skull_base", "head", "shoulder_l", "shoulder_r", "elbow_l", "elbow_r",
                   "wrist_l", "wrist_r", "hip_l", "hip_r", "knee_l", "knee_r", "ankle_l", "ankle_r")


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
