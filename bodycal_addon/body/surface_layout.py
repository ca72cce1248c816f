"""The canonical surface topology shared by the user and every avatar (Delahaye 2023, appendix C,
Figure 11): the same element ids, point names and triangles on both sides, so that each user
element has exactly one avatar counterpart for the egocentric mapping (DESIGN.md §5).

Elements:
- `capsule:<bone>` around the limb bones and every finger phalanx; radii are the bone's
  `radius_head` / `radius_tail` (BodyModel.bones).
- `sphere:skull`: the back of the skull, `center` local to the `head` bone.
- `mesh:torso`: front `sternum, chest_l, chest_r, belly_ul, belly_ur, belly_ll, belly_lr`,
  belly centre `belly_c1..c4`, back `back_ul, back_ur, back_low`; each point local to its
  nearest vertebra bone (`spine_01`..`spine_12`).
- `mesh:palm_<s>`: `palm_1..palm_N` (N >= 3) local to the `hand_<s>` bone, a triangle fan.
- `mesh:sole_<s>`: `sole_1..sole_N` (N >= 3) local to the `foot_<s>` bone, a triangle fan.
- `mesh:jaw`: `ear_l, ear_r, upper_lip, chin, jaw_l, jaw_r` local to the `head` bone.

Bone frames (`bone_frame`): origin at the bone's head joint, +Y along the bone (head -> tail),
+X the bone's `right` (for hinges, the flexion axis), +Z = X x Y. Surface points, sphere centres
and capsule angles are expressed in these frames, at the reference time (user) or in the rest
pose (avatar). Triangles are wound so that (b - a) x (c - a) points out of the body.

The performer's left is the avatar's left: `_l` is at +X in Blender's front view (facing -Y).
"""

from __future__ import annotations

import numpy as np

from ..core.transforms import EPS, frame_from_axes
from . import skeleton as sk

LIMB_CAPSULE_BONES = tuple(f"{b}_{s}" for s in sk.SIDES for b in ("upperarm", "forearm", "thigh", "shin"))
FINGER_CAPSULE_BONES = tuple(f"{f}_{i}_{s}" for s in sk.SIDES for f in sk.FINGERS for i in (1, 2, 3))
CAPSULE_BONES = LIMB_CAPSULE_BONES + FINGER_CAPSULE_BONES

TORSO_FRONT = ("sternum", "chest_l", "chest_r", "belly_ul", "belly_ur", "belly_ll", "belly_lr")
BELLY_CENTRE = ("belly_c1", "belly_c2", "belly_c3", "belly_c4")
TORSO_BACK = ("back_ul", "back_ur", "back_low")
TORSO_POINTS = TORSO_FRONT + BELLY_CENTRE + TORSO_BACK
JAW_POINTS = ("ear_l", "ear_r", "upper_lip", "chin", "jaw_l", "jaw_r")
SKULL_POINTS = ("skull_top", "skull_left", "skull_right", "skull_back")

# Bilinear coordinates (a, b) of the four belly centre points inside the belly quad (Delahaye 2023,
# appendix C, Figure 11a); see belly_centre_points.
BELLY_CENTRE_UV = {"belly_c1": (1 / 3, 1 / 3), "belly_c2": (2 / 3, 1 / 3),
                   "belly_c3": (1 / 3, 2 / 3), "belly_c4": (2 / 3, 2 / 3)}


def belly_centre_points(ul, ur, ll, lr) -> dict[str, np.ndarray]:
    """Default belly centre points: bilinear interpolation of the four belly corners
    (DESIGN.md §3). `a` runs from the upper-left corner's side to the upper-right's, `b` from top
    to bottom. Works on arrays with leading axes."""
    ul, ur, ll, lr = (np.asarray(p, float) for p in (ul, ur, ll, lr))
    out = {}
    for name, (a, b) in BELLY_CENTRE_UV.items():
        out[name] = (1 - a) * (1 - b) * ul + a * (1 - b) * ur + (1 - a) * b * ll + a * b * lr
    return out


# Front as seen by the performer: `_l` corners on their left. Winding makes the normal point
# forward (out of the belly) for a performer facing -Y with left at +X; see test_surface_layout.
TORSO_TRIANGLES = (
    ("sternum", "belly_ul", "chest_l"),
    ("sternum", "belly_ur", "belly_ul"),
    ("sternum", "chest_r", "belly_ur"),
    ("belly_ul", "belly_c2", "belly_c1"),
    ("belly_ul", "belly_ur", "belly_c2"),
    ("belly_ur", "belly_c4", "belly_c2"),
    ("belly_ur", "belly_lr", "belly_c4"),
    ("belly_lr", "belly_c3", "belly_c4"),
    ("belly_lr", "belly_ll", "belly_c3"),
    ("belly_ll", "belly_c1", "belly_c3"),
    ("belly_ll", "belly_ul", "belly_c1"),
    ("belly_c1", "belly_c4", "belly_c3"),
    ("belly_c1", "belly_c2", "belly_c4"),
    ("back_ul", "back_low", "back_ur"),
)

JAW_TRIANGLES = (
    ("ear_l", "upper_lip", "jaw_l"),
    ("jaw_l", "upper_lip", "chin"),
    ("upper_lip", "jaw_r", "chin"),
    ("upper_lip", "ear_r", "jaw_r"),
)


def fan_triangles(names: list[str]) -> list[tuple[str, str, str]]:
    """Triangle fan over an outline (palms, soles); the caller orders the outline so the normal
    points out of the body (palm: out of the palm; sole: down)."""
    return [(names[0], names[i], names[i + 1]) for i in range(1, len(names) - 1)]


def palm_points(count: int, side: str) -> list[str]:
    return [f"palm_{i}_{side}" for i in range(1, count + 1)]


def sole_points(count: int, side: str) -> list[str]:
    return [f"sole_{i}_{side}" for i in range(1, count + 1)]


def element_ids() -> list[str]:
    ids = [f"capsule:{b}" for b in CAPSULE_BONES]
    ids += ["sphere:skull", "mesh:torso", "mesh:jaw"]
    ids += [f"mesh:{part}_{s}" for part in ("palm", "sole") for s in sk.SIDES]
    return ids


def bone_frame(head: np.ndarray, tail: np.ndarray, right: np.ndarray) -> np.ndarray:
    """The bone's rotation (columns x, y, z) from its joints and local right; arrays broadcast
    over leading (frame) axes."""
    return frame_from_axes(np.asarray(tail, float) - np.asarray(head, float), np.asarray(right, float))


def nearest_vertebra(point: np.ndarray, spine_joints: np.ndarray) -> str:
    """Name of the vertebra bone (`spine_01`..`spine_12`) whose segment is closest to `point`;
    `spine_joints` is (13, 3): spine_root, spine_01..spine_12."""
    a, b = spine_joints[:-1], spine_joints[1:]
    ab = b - a
    t = np.clip(((point - a) * ab).sum(-1) / np.maximum((ab * ab).sum(-1), EPS), 0, 1)
    d = np.linalg.norm(point - (a + t[:, None] * ab), axis=-1)
    return f"spine_{int(np.argmin(d)) + 1:02d}"
