"""One frame in Blender's own `mathutils` (DESIGN.md "Prepared solver", BLENDER_NOTES.md).

A live frame or a preview's is a few dozen 3x3 products, cross products and normalisations on
single items, where numpy's per-call cost (several thousand instructions) is the whole cost: a
3x3 product takes 0.2 us in mathutils against 2.6 us in numpy. So each kernel has two
implementations, chosen by one dispatcher: numpy over a leading frame axis (the bake), and
mathutils for one frame. mathutils ships inside every Blender (a built-in module: importable in
Blender, and after `import bpy` in the bpy module); the engine lane and a plain interpreter use
PyPI's build of the same code (`mathutils`, requirements-dev.txt). Where it cannot be imported (a
worker process started from Blender's own Python, which has no mathutils of its own), one frame
takes the numpy path: the same values to float32's rounding (below).

Decision (precision): mathutils stores float32 (Blender's and PyPI's alike, BLENDER_NOTES.md), so
a one-frame solve agrees with the bake's float64 values to float32's rounding, not to the bit:
measured on the pinned takes, within the tolerances the pin tests state (DESIGN.md "Prepared
solver"). Python floats read out of mathutils are float32 values; scalar arithmetic between them
(lengths, angles) runs in Python's float64.

This is the only engine module that imports mathutils (tests/engine/test_module_layout.py)."""

from __future__ import annotations

import math

import numpy as np

try:
    import mathutils
    from mathutils import Matrix, Quaternion, Vector
except ImportError:  # Blender's own Python outside Blender (a worker process), or no PyPI build
    mathutils = None
    Matrix = Quaternion = Vector = None

# Whether one frame takes the mathutils path (tests switch it off to compare with the numpy path).
ENABLED = mathutils is not None


def matrices(a: np.ndarray) -> list:
    """mathutils Matrices of a stack of 3x3 matrices (K, 3, 3) (rows, as numpy's)."""
    return [Matrix(m) for m in a.tolist()]


def vectors(a: np.ndarray) -> list:
    """mathutils Vectors of (K, 3) rows."""
    return [Vector(v) for v in a.tolist()]


def matrix_rows(ms: list) -> list:
    """The entries of mathutils 3x3 matrices as row-major lists of nine floats (np.array's input)."""
    return [m[0][:] + m[1][:] + m[2][:] for m in ms]


def matrix_array(ms: list) -> np.ndarray:
    """(K, 3, 3) float64 of mathutils 3x3 matrices."""
    return np.array(matrix_rows(ms), float).reshape(len(ms), 3, 3)


def vector_array(vs: list) -> np.ndarray:
    """(K, 3) float64 of mathutils Vectors (or 3-sequences)."""
    return np.array([v[:] for v in vs], float).reshape(len(vs), 3)


# --- The fingers of one frame (issue 41; fingers.FingerSet, DESIGN.md "Prepared solver") -----------
# A finger of one frame is a dozen scalars (eq. 3-4's flexion, the target's yaw and pitch) and a
# few 3x3 products: in Python floats (float64: numpy's values to its rounding, ~1e-15) one finger
# costs less than one numpy call on the stacked items. Each finger's constants come as one tuple
# (`fingers.FingerSet.one_frame_items`).

def finger_frames(items: list, mcp: list, ref: list, tip: list, radius: list | None = None,
                  joints: bool = True) -> tuple[list, list]:
    """`fingers.FingerSet.pose` of one frame: `items` the fingers' constant tuples, `mcp`, `tip`
    [n][3] and `ref` [n][3][3] (rows) as nested lists of floats. `radius` [n] (or None): the LED's
    offset off the tip joint on the back of the distal phalanx (`user_animation.pose_user_fingers`):
    aimed at the joint instead, once the first pose gives the phalanx's -Z. Returns (the joints
    [n][3][3] after the MCP (PIP, DIP, tip), None when `joints` is False; the frames [n][3][3][3]
    of phalanges 1, 2, 3, rows)."""
    points, frames = ([] if joints else None), []
    for i, k in enumerate(items):
        m, r, t = mcp[i], ref[i], tip[i]
        if k[13] is not None:  # the thumb's roll about +Y (appendix D): ref @ roll
            r = _mul33(r, k[13])
        if radius is not None and radius[i]:
            bx, by, bz, c1, s1, c2, s2 = _finger_base(k, m, r, t)
            rad = radius[i]
            t = [t[j] + rad * (c2 * bz[j] - s2 * by[j]) for j in range(3)]  # the distal phalanx's +Z
        bx, by, bz, c1, s1, c2, s2 = _finger_base(k, m, r, t)
        y2 = [c1 * by[j] + s1 * bz[j] for j in range(3)]
        z2 = [c1 * bz[j] - s1 * by[j] for j in range(3)]
        y3 = [c2 * by[j] + s2 * bz[j] for j in range(3)]
        z3 = [c2 * bz[j] - s2 * by[j] for j in range(3)]
        frames.append([[[bx[j], by[j], bz[j]] for j in range(3)], [[bx[j], y2[j], z2[j]] for j in range(3)],
                       [[bx[j], y3[j], z3[j]] for j in range(3)]])
        if joints:
            l1, l2, l3 = k[0], k[1], k[2]
            p1 = [by[j] * l1 for j in range(3)]
            p2 = [y2[j] * l2 + p1[j] for j in range(3)]
            p3 = [y3[j] * l3 + p2[j] for j in range(3)]
            points.append([[m[j] + p1[j] for j in range(3)], [m[j] + p2[j] for j in range(3)],
                           [m[j] + p3[j] for j in range(3)]])
    return points, frames


def _mul33(a: list, b: list) -> list:
    """a @ b of 3x3 nested lists (rows)."""
    return [[a[i][0] * b[0][j] + a[i][1] * b[1][j] + a[i][2] * b[2][j] for j in range(3)] for i in range(3)]


def _finger_base(k: tuple, m: list, r: list, t: list) -> tuple:
    """`FingerSet._realigned` of one finger: the realigned first phalanx's columns (bx, by, bz)
    and the cosines and sines of α and 2α."""
    l1, l2, l3, c0, bb, a4, minus_b, den, ylo, yhi, plo, phi, half = k[:13]
    rel0, rel1, rel2 = t[0] - m[0], t[1] - m[1], t[2] - m[2]
    lx = r[0][0] * rel0 + r[1][0] * rel1 + r[2][0] * rel2  # ref^T rel: the target in the reference
    ly = r[0][1] * rel0 + r[1][1] * rel1 + r[2][1] * rel2
    lz = r[0][2] * rel0 + r[1][2] * rel1 + r[2][2] * rel2
    d = math.sqrt(rel0 * rel0 + rel1 * rel1 + rel2 * rel2)
    # eq. 3-4 (fingers.flexion_from_distance, its constant parts kept)
    disc = max(bb - a4 * (c0 - d * d), 0.0)
    x = min(max((minus_b - math.sqrt(disc)) / den, -FINGER_X_CLAMP), FINGER_X_CLAMP)
    alpha = min(math.pi - math.acos(x), FINGER_FLEXION_CAP)
    c1, s1, c2, s2 = math.cos(alpha), math.sin(alpha), math.cos(2.0 * alpha), math.sin(2.0 * alpha)
    # realign (fingers.realign): the target's yaw and pitch clamped, the flexed tip's pitch
    pitch = math.atan2(-lz, ly)
    yaw = min(max(math.atan2(lx, math.hypot(ly, lz)), ylo), yhi)
    if not plo <= pitch <= phi:  # nearer limit around the circle (fingers._clamp_angle)
        pitch = phi if (pitch - phi) % (2.0 * math.pi) < half else plo
    flexed = math.atan2(-(l2 * s1 + l3 * s2), l1 + l2 * c1 + l3 * c2)
    # Rx(-pitch) Rz(-yaw) Rx(flexed) (fingers._rx_rz_rx_of's entries)
    ca, sa, cb, sb = math.cos(-pitch), math.sin(-pitch), math.cos(-yaw), math.sin(-yaw)
    cc, sc = math.cos(flexed), math.sin(flexed)
    rot = ((cb, -sb * cc, sb * sc),
           (ca * sb, ca * (cb * cc) - sa * sc, ca * (-cb * sc) - sa * cc),
           (sa * sb, sa * (cb * cc) + ca * sc, sa * (-cb * sc) + ca * cc))
    base = _mul33(r, rot)
    return ([base[j][0] for j in range(3)], [base[j][1] for j in range(3)], [base[j][2] for j in range(3)],
            c1, s1, c2, s2)


FINGER_X_CLAMP = 0.9999  # fingers.X_CLAMP (eq. 4); the finger tests check they agree
FINGER_FLEXION_CAP = math.pi / 2  # fingers.FLEXION_CAP
