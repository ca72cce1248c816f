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


# --- The fingers of one frame (fingers.FingerSet, DESIGN.md "Prepared solver") -----------
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
    after the MCP (PIP, DIP, tip), [n][9], None when `joints` is False; the frames of phalanges 1,
    2, 3, rows, [n][27]): flat, so numpy reads them as (n, 9) and (n, 27) (nested sequences cost
    it several times more). Written out scalar by scalar: a comprehension or a loop over three
    items costs as much here as a numpy call."""
    points, frames = ([] if joints else None), []
    for i, k in enumerate(items):
        m, r, t = mcp[i], ref[i], tip[i]
        if k[13] is not None:  # the thumb's roll about +Y (appendix D): ref @ roll
            r = _mul33(r, k[13])
        if radius is not None and radius[i]:
            (_, y0, z0), (_, y1, z1), (_, y2, z2), _, _, c2, s2 = _finger_base(k, m, r, t)
            rad = radius[i]
            t = (t[0] + rad * (c2 * z0 - s2 * y0), t[1] + rad * (c2 * z1 - s2 * y1),
                 t[2] + rad * (c2 * z2 - s2 * y2))  # the distal phalanx's +Z
        (x0, y0, z0), (x1, y1, z1), (x2, y2, z2), c1, s1, c2, s2 = _finger_base(k, m, r, t)
        # phalanx k is the base turned by Rx(k α): its columns x, c y + s z, -s y + c z
        u0, u1, u2 = c1 * y0 + s1 * z0, c1 * y1 + s1 * z1, c1 * y2 + s1 * z2
        w0, w1, w2 = c2 * y0 + s2 * z0, c2 * y1 + s2 * z1, c2 * y2 + s2 * z2
        frames.append((x0, y0, z0, x1, y1, z1, x2, y2, z2,
                       x0, u0, c1 * z0 - s1 * y0, x1, u1, c1 * z1 - s1 * y1, x2, u2, c1 * z2 - s1 * y2,
                       x0, w0, c2 * z0 - s2 * y0, x1, w1, c2 * z1 - s2 * y1, x2, w2, c2 * z2 - s2 * y2))
        if joints:  # each phalanx's +Y times its length, summed from the MCP
            l1, l2, l3 = k[0], k[1], k[2]
            p0, p1, p2 = y0 * l1, y1 * l1, y2 * l1
            q0, q1, q2 = u0 * l2 + p0, u1 * l2 + p1, u2 * l2 + p2
            m0, m1, m2 = m
            points.append((m0 + p0, m1 + p1, m2 + p2, m0 + q0, m1 + q1, m2 + q2,
                           m0 + (w0 * l3 + q0), m1 + (w1 * l3 + q1), m2 + (w2 * l3 + q2)))
    return points, frames


def _mul33(a, b) -> tuple:
    """a @ b of 3x3 nested sequences (rows)."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = a
    (b00, b01, b02), (b10, b11, b12), (b20, b21, b22) = b
    return ((a00 * b00 + a01 * b10 + a02 * b20, a00 * b01 + a01 * b11 + a02 * b21, a00 * b02 + a01 * b12 + a02 * b22),
            (a10 * b00 + a11 * b10 + a12 * b20, a10 * b01 + a11 * b11 + a12 * b21, a10 * b02 + a11 * b12 + a12 * b22),
            (a20 * b00 + a21 * b10 + a22 * b20, a20 * b01 + a21 * b11 + a22 * b21, a20 * b02 + a21 * b12 + a22 * b22))


def _finger_base(k: tuple, m, r, t) -> tuple:
    """`FingerSet._realigned` of one finger: the realigned first phalanx's rows and the cosines and
    sines of α and 2α."""
    l1, l2, l3, c0, bb, a4, minus_b, den, ylo, yhi, plo, phi, half = k[:13]
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = r
    rel0, rel1, rel2 = t[0] - m[0], t[1] - m[1], t[2] - m[2]
    lx = r00 * rel0 + r10 * rel1 + r20 * rel2  # ref^T rel: the target in the reference frame
    ly = r01 * rel0 + r11 * rel1 + r21 * rel2
    lz = r02 * rel0 + r12 * rel1 + r22 * rel2
    # eq. 3-4 (fingers.flexion_from_distance, its constant parts kept); a math call costs ten
    # float operations, so the angles' cosines and sines come from the sides they are made of
    # where no clamp changes the angle (numpy's values to float64's rounding)
    disc = bb - a4 * (c0 - (rel0 * rel0 + rel1 * rel1 + rel2 * rel2))
    x = (minus_b - math.sqrt(disc if disc > 0.0 else 0.0)) / den
    x = -FINGER_X_CLAMP if x < -FINGER_X_CLAMP else FINGER_X_CLAMP if x > FINGER_X_CLAMP else x
    if x > 0.0:  # α = π - acos(x) beyond its 90° cap
        c1, s1 = _COS_CAP, 1.0
    else:
        c1, s1 = -x, math.sqrt(1.0 - x * x)
    c2, s2 = c1 * c1 - s1 * s1, 2.0 * s1 * c1  # of 2α
    # realign (fingers.realign): the target's yaw and pitch clamped, the flexed tip's pitch
    h = math.hypot(ly, lz)
    pitch = math.atan2(-lz, ly)
    if plo <= pitch <= phi:  # Rx(-pitch): its cosine and sine
        ca, sa = (ly / h, lz / h) if h > 0.0 else (1.0, 0.0)
    else:  # to the nearer limit around the circle (fingers._clamp_angle)
        pitch = phi if (pitch - phi) % (2.0 * math.pi) < half else plo
        ca, sa = math.cos(-pitch), math.sin(-pitch)
    yaw = math.atan2(lx, h)
    if ylo <= yaw <= yhi:  # Rz(-yaw)
        length = math.hypot(lx, h)
        cb, sb = (h / length, -lx / length) if length > 0.0 else (1.0, 0.0)
    else:
        yaw = ylo if yaw < ylo else yhi
        cb, sb = math.cos(-yaw), math.sin(-yaw)
    fx, fy = l1 + l2 * c1 + l3 * c2, -(l2 * s1 + l3 * s2)  # Rx(the flexed tip's pitch)
    nf = math.hypot(fx, fy)
    cc, sc = (fx / nf, fy / nf) if nf > 0.0 else (1.0, 0.0)
    # base = ref @ Rx(-pitch) Rz(-yaw) Rx(flexed) (fingers._rx_rz_rx_of's entries)
    e01, e02 = -sb * cc, sb * sc
    bcc, bsc = cb * cc, -cb * sc
    e10, e11, e12 = ca * sb, ca * bcc - sa * sc, ca * bsc - sa * cc
    e20, e21, e22 = sa * sb, sa * bcc + ca * sc, sa * bsc + ca * cc
    return ((r00 * cb + r01 * e10 + r02 * e20, r00 * e01 + r01 * e11 + r02 * e21, r00 * e02 + r01 * e12 + r02 * e22),
            (r10 * cb + r11 * e10 + r12 * e20, r10 * e01 + r11 * e11 + r12 * e21, r10 * e02 + r11 * e12 + r12 * e22),
            (r20 * cb + r21 * e10 + r22 * e20, r20 * e01 + r21 * e11 + r22 * e21, r20 * e02 + r21 * e12 + r22 * e22),
            c1, s1, c2, s2)


FINGER_X_CLAMP = 0.9999  # fingers.X_CLAMP (eq. 4); the finger tests check they agree
FINGER_FLEXION_CAP = math.pi / 2  # fingers.FLEXION_CAP
_COS_CAP = math.cos(FINGER_FLEXION_CAP)  # numpy's cosine of the capped α (6e-17, not 0)
