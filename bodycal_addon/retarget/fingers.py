"""Finger animation (Delahaye 2023, appendix D "Finger motion capture", eq. 3-4; DESIGN.md §6), numpy
only, vectorised over frames.

A finger is three phalanges l1, l2, l3 from the base (MCP) joint. Its flexion comes from the
MCP -> fingertip distance assuming equal flexion at the PIP and DIP joints; then the whole finger
turns about the MCP (yaw, pitch, within anatomical limits) so the tip points at the target.

Reference frame (per finger, world columns x, y, z): +Y along the finger at rest (the "artificial
bone linking the wrist to the base joint"), +X the flexion axis; a positive rotation about +X
flexes, so the finger curls toward +Z (the palm side). Angles follow the paper's Figure 16:
pitch > 0 extends the finger (toward -Z, the back of the hand), pitch < 0 flexes it; yaw > 0 turns
it toward +X.

**Decision**: pitch is measured in the flexion plane and yaw out of it, the floating-axis order of
a joint coordinate system (Wu 2005: flexion about the hand's axis first, then abduction), so a
direction is Rx(-pitch) Rz(-yaw) +Y. Figure 16 draws yaw as a longitude about the hand's up axis,
whose pole is where a curled fingertip points (pitch near -90°): there the yaw of the tip's
direction is undefined, and 0.15 mm of marker noise flipped a gripping finger between its ±15°
yaw limits from frame to frame. In this order the pole is at yaw ±90°, far outside every limit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from types import SimpleNamespace

import numpy as np

from ..core.one_frame import float_array
from ..core.transforms import all_true, matmul_stack, stack_mul

FLEXION_CAP = np.pi / 2  # appendix D: α never exceeds 90°
X_CLAMP = 0.9999  # eq. 4
# Appendix D, from [Ari18]: (yaw min, yaw max), (pitch min, pitch max), degrees.
LIMITS = {"finger": ((-15.0, 15.0), (-85.0, 10.0)), "thumb": ((-30.0, 40.0), (-15.0, 15.0))}
THUMB_ROLL = np.deg2rad(45.0)
# `FingerSet.pose_floats`' math, bound once (a module global's lookup costs less than an attribute's)
_sqrt, _acos, _cos, _sin, _atan2, _hypot = math.sqrt, math.acos, math.cos, math.sin, math.atan2, math.hypot
_PI, _TWO_PI = math.pi, 2 * math.pi
FEW_ITEMS = 64  # FingerSet.constants: items (fingers x frames) up to which its scalars are arrays


def tip_distance(l1, l2, l3, alpha) -> np.ndarray:
    """MCP -> fingertip distance of a straight-based finger with flexion α at both PIP and DIP:
    the tip is l1 Y + l2 R(α) Y + l3 R(2α) Y, so
    d² = l1² + l2² + l3² + 2 l2 (l1 + l3) cos α + 2 l1 l3 cos 2α."""
    l1, l2, l3, a = (np.asarray(x, float) for x in (l1, l2, l3, alpha))
    return np.sqrt(l1 * l1 + l2 * l2 + l3 * l3 + 2 * l2 * (l1 + l3) * np.cos(a) + 2 * l1 * l3 * np.cos(2 * a))


def flexion_from_distance(l1, l2, l3, d) -> np.ndarray:
    """Flexion α (radians, PIP = DIP) from the MCP -> fingertip distance d (Delahaye 2023, eq. 3-4).

    With cos 2α = 2 cos² α - 1 and x = cos(π - α) = -cos α, tip_distance gives
    4 l1 l3 x² - 2 l2 (l1 + l3) x + (l1² + l2² + l3² - 2 l1 l3 - d²) = 0, i.e. the paper's
    a = 4 l1 l3, b = -2 l2 (l1 + l3), c = l1² + l2² + l3² - 2 l1 l3 - d²; the root
    x = (-b - sqrt(b² - 4ac)) / 2a is the one that gives x = -1 (α = 0) for the straight finger,
    so the paper's equation checks out as printed. x is clamped to ±0.9999 (eq. 4),
    α = π - acos(x), then capped at 90° (appendix D). A distance out of range gives the nearest
    valid flexion (the discriminant is clamped at 0); never NaN."""
    l1, l2, l3, d = (np.asarray(x, float) for x in (l1, l2, l3, d))
    a = 4.0 * l1 * l3
    b = -2.0 * l2 * (l1 + l3)
    c = l1 * l1 + l2 * l2 + l3 * l3 - 2.0 * l1 * l3 - d * d
    disc = np.maximum(b * b - 4.0 * a * c, 0.0)
    x = (-b - np.sqrt(disc)) / np.maximum(2.0 * a, 1e-18)
    x = np.clip(x, -X_CLAMP, X_CLAMP)
    return np.minimum(np.pi - np.arccos(x), FLEXION_CAP)


def _ry(angle):
    if isinstance(angle, float):  # one roll for every finger (pose_finger's): built once
        return _ry_once(float(angle))
    return _ry_built(angle)


def _ry_built(angle):
    c, s = np.cos(angle), np.sin(angle)
    z, o = np.zeros_like(c), np.ones_like(c)
    return np.stack([np.stack([c, z, s], -1), np.stack([z, o, z], -1), np.stack([-s, z, c], -1)], -2)


@lru_cache(maxsize=8)
def _ry_once(angle: float) -> np.ndarray:
    m = _ry_built(angle)
    m.setflags(write=False)  # shared by every call
    return m


def yaw_pitch(direction) -> tuple[np.ndarray, np.ndarray]:
    """(yaw, pitch) of directions (..., 3) expressed in the finger's reference frame:
    direction = Rx(-pitch) Rz(-yaw) +Y = (sin yaw, cos yaw cos pitch, -cos yaw sin pitch).
    Yaw is within ±90°, pitch within ±180° (a tip behind the base joint has |pitch| > 90°)."""
    d = np.asarray(direction, float)
    pitch = np.arctan2(-d[..., 2], d[..., 1])
    yaw = np.arctan2(d[..., 0], np.hypot(d[..., 1], d[..., 2]))
    return yaw, pitch


def _clamp_angle(angle, lo, hi):
    """Clamp angles (radians, within ±π) to [lo, hi] on the circle: an angle outside goes to the
    nearer limit around the circle, so a tip curled far behind the base joint (pitch near -180°)
    clamps to the flexion limit, not to the extension limit across the ±180° seam."""
    beyond_hi = np.mod(angle - hi, 2 * np.pi)  # how far past hi, going round the excluded arc
    excluded = 2 * np.pi - (hi - lo)
    return np.where((angle >= lo) & (angle <= hi), angle, np.where(beyond_hi < excluded / 2, hi, lo))


def realign(target_local, flexed_local, thumb: bool = False):
    """Realignment of a flexed finger toward its fingertip target (appendix D, Figure 16).

    target_local, flexed_local: (F, 3) the target tip and the flexed finger's tip (zero yaw by
    construction), both in the reference frame centred on the MCP. The target's yaw and pitch are
    clamped to the limits (fingers: yaw [-15°, 15°], pitch [-85°, 10°]; thumb: yaw [-30°, 40°],
    pitch [-15°, 15°]); the correction unpitches the flexed finger (about +X), turns it out of its
    flexion plane by the yaw (about +Z), then pitches it to the target's pitch (about +X).
    Returns (rotation (F, 3, 3) in the reference frame, yaw, pitch) with the clamped target
    angles."""
    ylo, yhi, plo, phi = _limits(thumb)
    yaw, pitch = yaw_pitch(target_local)
    yaw = np.clip(yaw, ylo, yhi)
    pitch = _clamp_angle(pitch, plo, phi)
    _, flexed_pitch = yaw_pitch(flexed_local)
    return _rx_rz_rx(-pitch, -yaw, flexed_pitch), yaw, pitch


def _limits(thumb):
    """(yaw min, yaw max, pitch min, pitch max) in radians, for one finger or per item (`thumb`
    a bool array)."""
    lims = _LIMITS_RAD
    if np.ndim(thumb) == 0:
        return tuple(lims["thumb" if thumb else "finger"])
    return tuple(np.where(thumb, t, f) for t, f in zip(lims["thumb"], lims["finger"]))


_LIMITS_RAD = {k: [np.deg2rad(x) for pair in v for x in pair] for k, v in LIMITS.items()}  # _limits', once


def _rx_rz_rx(a, b, c):
    """Rx(a) Rz(b) Rx(c), written out (a stacked 3x3 matmul costs numpy one BLAS call per frame)."""
    angles = np.empty((3,) + np.shape(a))
    angles[0], angles[1], angles[2] = a, b, c
    return _rx_rz_rx_of(angles)


_SIGNS = np.array([-1.0, 1.0])  # (-x, y) of a pair (x, y): a negation is exact, so -u v = u (-v)


def _rx_rz_rx_of(angles: np.ndarray) -> np.ndarray:
    """Rx(a) Rz(b) Rx(c) of `angles` (3, ...) = (a, b, c). Built components first, each entry one
    contiguous row of the items (numpy's loops over a trailing axis of 3 cost several times more on
    a bake's thousands), a few rows at a time (a live frame's cost is the count of numpy calls),
    then laid out (..., 3, 3). The same products and sums as entry by entry: a negation is exact,
    so -u v = u (-v) and u - v w = u + (-v) w to the bit. Fewer than `FEW_ITEMS` items (a live
    frame's fingers) take `_rx_rz_rx_few`."""
    shape = angles.shape[1:]
    if angles[0].size < FEW_ITEMS:
        return _rx_rz_rx_few(angles)
    signs = _SIGNS.reshape((2,) + (1,) * len(shape))
    trig = np.empty((2,) + angles.shape)  # the cosines and sines of a, b, c: the six in two calls
    np.cos(angles, out=trig[0])
    np.sin(angles, out=trig[1])
    sb, cb = trig[1, 1], trig[0, 1]
    out = np.empty((3, 3) + shape)  # (row, column, ...)
    # Rz(b) Rx(c) has rows (cb, -sb cc, sb sc), (sb, cb cc, -cb sc), (0, sc, cc); Rx(a) mixes the
    # last two, column by column as ca r1 - sa r2 and sa r1 + ca r2.
    out[0, 0] = cb
    minus_cc_sc = trig[:, 2] * signs  # (-cc, sc)
    np.multiply(sb, minus_cc_sc, out=out[0, 1:])
    r1, r2 = np.empty((3,) + shape), np.empty((3,) + shape)
    r1[0] = sb
    np.multiply(cb, -minus_cc_sc, out=r1[1:])  # cb cc, cb (-sc)
    r2[0] = 0.0
    r2[1:] = trig[::-1, 2]  # sc, cc
    # rows 1 and 2 at once: (ca, sa) r1 + (-sa, ca) r2
    np.add(trig[:, 0, None] * r1, (trig[::-1, 0] * signs)[:, None] * r2, out=out[1:])
    return np.ascontiguousarray(out.reshape(9, -1).T).reshape(shape + (3, 3))


# `_rx_rz_rx_few`'s plan: rows of (ca cb cc sa sb sc, their negatives, 1, 0) that each product
# multiplies, as `_rx_rz_rx_of` pairs them
_CA, _CB, _CC, _SA, _SB, _SC = range(6)
_NEG, _ONE, _ZERO = 6, 12, 13
# the first products: (u, v) = cb (cc, -sc), sb (-cc), sb sc, ca sb, -sa sc, -sa cc, sa sb, ca sc,
# ca cc, and the zero terms of the (1, 0) and (2, 0) entries, -sa 0 and ca 0
_FIRST = (np.array([_CB, _CB, _SB, _SB, _CA, _NEG + _SA, _NEG + _SA, _SA, _CA, _CA, _NEG + _SA, _CA]),
          np.array([_CC, _NEG + _SC, _NEG + _CC, _SC, _SB, _SC, _CC, _SB, _SC, _CC, _ZERO, _ZERO]))
# the entries (1, 0..2), (2, 0..2): (1 ca ca, 1 sa sa) (ca sb, u, v, sa sb, u, v) plus their other
# terms (-sa 0, -sa sc, -sa cc, ca 0, ca sc, ca cc); 1 x is x, to the bit
_SECOND = (np.array([_ONE, _CA, _CA, _ONE, _SA, _SA]), np.array([4, 0, 1, 7, 0, 1]), np.array([10, 5, 6, 11, 8, 9]))


def _rx_rz_rx_few(angles: np.ndarray) -> np.ndarray:
    """`_rx_rz_rx_of` of a few items in a dozen numpy calls: every product of one level in one
    gathered product, the same factors and sums (so the same bits, signed zeros too), where the
    components-first layout's broadcast calls cost a live frame's ten fingers about 130,000
    instructions a rotation (callgrind; 90,000 this way)."""
    n = angles[0].size
    trig = np.empty((14, n))
    np.cos(angles, out=trig[_CA:_SA])
    np.sin(angles, out=trig[_SA:_NEG])
    np.negative(trig[:_NEG], out=trig[_NEG:_ONE])
    trig[_ONE], trig[_ZERO] = 1.0, 0.0
    first = trig.take(_FIRST[0], axis=0) * trig.take(_FIRST[1], axis=0)
    second = trig.take(_SECOND[0], axis=0) * first.take(_SECOND[1], axis=0)
    second += first.take(_SECOND[2], axis=0)
    entries = np.concatenate((trig[_CB:_CB + 1], first[2:4], second))
    return np.ascontiguousarray(entries.T).reshape(angles.shape[1:] + (3, 3))


@dataclass
class FingerPose:
    joints: np.ndarray | None  # (F, 4, 3): mcp, pip, dip, tip (None: not asked for)
    rotations: np.ndarray  # (F, 3, 3, 3): world frames of phalanges 1, 2, 3 (+Y along, +X flexion axis)
    flexion: np.ndarray  # (F,) α at PIP and DIP
    yaw: np.ndarray  # (F,) clamped realignment yaw
    pitch: np.ndarray  # (F,) clamped realignment pitch


def _per_item(v, n: int) -> np.ndarray:
    """(n,) floats of a length given per item or once."""
    v = np.asarray(v, float)
    return v if v.shape == (n,) else np.broadcast_to(v, (n,))


class FingerSet:
    """`pose_finger`'s constants for one set of items (fingers x frames) posed together, computed
    once: the phalanx lengths, the parts of eq. 3-4's quadratic that do not depend on the distance,
    each item's limits and which items are thumbs rolled by how much. A live solve poses the same
    fingers every frame, so the solver keeps one per finger set; `pose` gives the same values,
    operation for operation, as pose_finger always did."""

    def __init__(self, l1, l2, l3, thumb=False, roll: float | None = None):
        """l1, l2, l3: (n,) the items' phalanx lengths; thumb, roll: as pose_finger takes them."""
        l1, l2, l3 = (np.asarray(v, float) for v in (l1, l2, l3))  # (n,) each
        self.n = len(l1)
        self.l1, self.l2, self.l3 = l1, l2, l3
        # flexion_from_distance's a, b and c without d² (each evaluated as it writes them)
        a = 4.0 * l1 * l3
        b = -2.0 * l2 * (l1 + l3)
        self.c0 = l1 * l1 + l2 * l2 + l3 * l3 - 2.0 * l1 * l3
        self.bb, self.a4, self.minus_b = b * b, 4.0 * a, -b
        self.den = np.maximum(2.0 * a, 1e-18)
        ylo, yhi, plo, phi = _limits(np.asarray(thumb, bool) if np.ndim(thumb) else bool(thumb))
        self.yaw_lo, self.yaw_hi, self.pitch_lo, self.pitch_hi = ylo, yhi, plo, phi
        self.half_excluded = (2 * np.pi - (phi - plo)) / 2  # _clamp_angle's excluded arc, halved
        self.lens_rows = np.stack([l1, l2, l3])  # (3, n)
        # the thumbs' roll (appendix D): every item, the thumbs (rows), or none; a roll of zero
        # (a user's thumb, whose frame carries its own) turns nothing
        turn = THUMB_ROLL if roll is None else roll
        turns = bool(np.any(np.asarray(turn) != 0))
        if np.ndim(thumb):
            self.roll_rows = np.flatnonzero(np.asarray(thumb, bool))
            self.roll = _ry(turn) if len(self.roll_rows) and turns else None
        else:
            self.roll_rows = None
            self.roll = _ry(turn) if (thumb or roll is not None) and turns else None

    def _realigned(self, mcp, ref_rot, tip_target) -> tuple:
        """What `pose` and `distal_z` share: mcp as an array, the first phalanx's frame (n, 3, 3)
        (the reference, rolled, realigned), the cosines and sines of α and 2α ((2, n) each), α and
        the clamped yaw and pitch."""
        mcp = np.asarray(mcp, float)
        ref = np.asarray(ref_rot, float)
        if self.roll is not None:
            if self.roll_rows is None:
                ref = stack_mul(ref, self.roll)
            else:
                rows = self.roll_rows
                ref = ref.copy()
                ref[rows] = stack_mul(ref.take(rows, axis=0), self.roll)
        k = self.constants
        rel = np.asarray(tip_target, float) - mcp
        local = np.einsum("fji,fj->fi", ref, rel)
        d = np.sqrt(np.add.reduce(rel * rel, -1))  # np.linalg.norm's sum (ndarray.sum's reduction)
        # eq. 3-4 (flexion_from_distance, its constant parts kept)
        disc = np.maximum(self.bb - self.a4 * (self.c0 - d * d), k.zero)
        x = np.minimum(np.maximum((self.minus_b - np.sqrt(disc)) / self.den, k.minus_clamp), k.clamp)
        twice = np.empty((2, self.n))  # α and 2α: their cosines and sines in two calls
        alpha = np.minimum(k.pi - np.arccos(x), k.cap, out=twice[0])
        np.multiply(k.two, alpha, out=twice[1])
        cos, sin = np.cos(twice), np.sin(twice)
        # realign: the target's yaw and pitch clamped, the flexed tip's pitch (its yaw is zero)
        ly, lz = local[..., 1], local[..., 2]
        pitch = np.arctan2(-lz, ly)
        yaw = np.minimum(np.maximum(np.arctan2(local[..., 0], np.hypot(ly, lz)), self.yaw_lo), self.yaw_hi)
        inside = (pitch >= self.pitch_lo) & (pitch <= self.pitch_hi)
        if not all_true(inside):  # (every pitch within its limits: nothing to clamp)
            beyond_hi = np.mod(pitch - self.pitch_hi, k.two_pi)
            pitch = np.where(inside, pitch, np.where(beyond_hi < self.half_excluded, self.pitch_hi, self.pitch_lo))
        angles = np.empty((3, self.n))  # Rx(-pitch) Rz(-yaw) Rx(flexed pitch)
        np.negative(pitch, out=angles[0])
        np.negative(yaw, out=angles[1])
        # the flexed tip's pitch: arctan2(-(l2 s1 + l3 s2), (l1 + l2 c1) + l3 c2)
        lc, ls = self.lens_rows[1:] * cos, self.lens_rows[1:] * sin  # (l2 c1, l3 c2), (l2 s1, l3 s2)
        np.arctan2(-(ls[0] + ls[1]), self.l1 + lc[0] + lc[1], out=angles[2])
        base = matmul_stack(ref, _rx_rz_rx_of(angles))
        return mcp, base, cos, sin, alpha, yaw, pitch

    @property
    def constants(self) -> SimpleNamespace:
        """The scalars `pose` combines with the items' arrays: as arrays of the items' length for a
        few items (numpy converts a Python scalar on every call: a live frame's ufunc with one
        costs up to twice one of two arrays; the same values either way), as they are for many."""
        k = self.__dict__.get("_constants")
        if k is None:
            def items(v):
                return np.full(self.n, v) if self.n < FEW_ITEMS else v
            k = self._constants = SimpleNamespace(
                zero=items(0.0), clamp=items(X_CLAMP), minus_clamp=items(-X_CLAMP), pi=items(np.pi),
                cap=items(FLEXION_CAP), two=items(2.0), two_pi=items(2 * np.pi))
        return k

    def pose(self, mcp, ref_rot, tip_target, joints: bool = True) -> FingerPose:
        """pose_finger of these items: mcp (n, 3), ref_rot (n, 3, 3), tip_target (n, 3). `joints`
        False: the frames only (`FingerPose.joints` None; an avatar's IK reads no joints)."""
        mcp, base, cos, sin, alpha, yaw, pitch = self._realigned(mcp, ref_rot, tip_target)
        # Phalanges 2 and 3 and the joints components first (see _rx_rz_rx), the same operations
        # in the same order: a phalanx's +Y scaled by its length is its segment, summed from the MCP
        # one after the other (np.cumsum's order). Phalanx k is the base frame turned by Rx(k α)
        # (k = 0, 1, 2): its columns are x, c y + s z, -s y + c z of the base's.
        bx, by, bz = np.ascontiguousarray(base.transpose(2, 1, 0))  # columns, (row, item) each
        c, s = cos[:, None], sin[:, None]  # (2, 1, n): phalanges 2 and 3
        ys, zs = c * by + s * bz, c * bz - s * by  # (2, 3, n)
        n = self.n
        rots = np.empty((n, 3, 3, 3))
        rots[:, 0] = base
        rots[:, 1:, :, 0] = bx.T[:, None]
        rots[:, 1:, :, 1] = ys.transpose(2, 0, 1)
        rots[:, 1:, :, 2] = zs.transpose(2, 0, 1)
        if not joints:
            return FingerPose(None, rots, alpha, yaw, pitch)
        lens = self.lens_rows
        reach = np.empty((3, 3, n))  # (phalanx, row, item): the segments, then their running sums
        np.multiply(by, lens[0], out=reach[0])
        np.multiply(ys, lens[1:, None], out=reach[1:])
        reach[1] += reach[0]
        reach[2] += reach[1]
        points = np.empty((n, 4, 3))
        points[:, 0] = mcp
        points[:, 1:] = (mcp.T + reach).transpose(2, 0, 1)
        return FingerPose(points, rots, alpha, yaw, pitch)

    def pose_floats(self, mcp, ref_rot, tip_target, joints: bool = True, radius=None) -> tuple:
        """`pose` of a few items (a live frame's fingers, the user's and the avatar's) in Python
        floats where numpy's per-call cost on ten items was the cost: the same steps in float64
        (numpy's cosines and BLAS's sums may differ in the last bits: the same values to float64's
        rounding, not to the bit). Each item's target is taken into its reference frame in one
        numpy call, each item's three phalanx frames are found in that frame item by item
        (`_local_phalanges`: Rx Rz Rx and the flexions, no 3x3 product), and turned back to the
        world in one stacked product. `radius` (n,): each tip target is a fingertip LED one radius
        off the tip joint on the back of the distal phalanx, aimed as `distal_z` and `pose` do it
        in two numpy passes (pose_user_fingers; in the reference frame the LED's offset is the
        distal phalanx's local -Z, no product). Returns (joints (n, 4, 3) or None, rotations
        (n, 3, 3, 3), a view of an (n, 3, 9) array)."""
        mcp = np.asarray(mcp, float)
        ref = np.asarray(ref_rot, float)
        if self.roll is not None:
            if self.roll_rows is None:
                ref = stack_mul(ref, self.roll)
            else:
                ref = ref.copy()
                ref[self.roll_rows] = stack_mul(ref.take(self.roll_rows, axis=0), self.roll)
        consts = self._float_constants()
        local = np.einsum("fji,fj->fi", ref, np.asarray(tip_target, float) - mcp)  # ref^T (tip - mcp)
        n = len(local)
        if radius is None and not joints:
            return None, self.frames_floats(ref, local).reshape(n, 3, 3, 3).transpose(0, 2, 1, 3)
        radii = None if radius is None else np.asarray(radius, float).ravel().tolist()
        q_rows, j_rows = _local_phalanges(consts, local.tolist(), radii, joints)
        rots = _to_world(ref, q_rows, n).reshape(n, 3, 3, 3).transpose(0, 2, 1, 3)  # (item, phalanx, row, column)
        if not joints:
            return None, rots
        points = np.empty((n, 4, 3))
        points[:, 0] = mcp
        reach = float_array(j_rows).reshape(n, 3, 3)  # (item, joint, local xyz)
        np.add(mcp[:, None], np.matmul(reach, ref.swapaxes(-1, -2)), out=points[:, 1:])
        return points, rots

    def _float_constants(self) -> list:
        """`_local_phalanges`' constants, item by item, once per set."""
        consts = self.__dict__.get("_floats")
        if consts is None:
            n = self.n
            cols = [np.broadcast_to(np.asarray(v, float), (n,)).tolist() for v in (
                self.c0, self.bb, self.a4, self.minus_b, self.den, self.l1, self.l2, self.l3,
                self.yaw_lo, self.yaw_hi, self.pitch_lo, self.pitch_hi, self.half_excluded)]
            consts = self._floats = list(zip(*cols))
        return consts

    def frames_floats(self, ref, local) -> np.ndarray:
        """`pose_floats(...)[1]` (no joints, no LED) of a caller that has each item's target in its
        reference frame already: `ref` (n, 3, 3) the reference frames, rolled (a set whose roll is
        None takes them as given), `local` (n, 3) ref^T (tip - mcp). The avatar's one-frame finger
        IK finds `local` from the wrist without forming the MCPs (their offsets in the reference
        frame are constants). Returns an item's three phalanx frames side by side, (n, 3, 9)
        contiguous: [item, row, 3 phalanx + column] (a caller scatters it flat: a transposed
        view's scatter cost twice a flat one's)."""
        local = local.tolist() if isinstance(local, np.ndarray) else local
        return _to_world(ref, _local_phalanges(self._float_constants(), local, None, False)[0], len(local))

    def distal_z(self, mcp, ref_rot, tip_target) -> np.ndarray:
        """(n, 3) the distal phalanx's +Z (the third column of `pose(...).rotations[:, 2]`, the same
        values) without the rest of the pose: the fingertip LED's offset is all a first pose reads."""
        _, base, cos, sin = self._realigned(mcp, ref_rot, tip_target)[:4]
        b = base.transpose(2, 1, 0)  # columns, (row, item) each
        return (cos[1] * b[2] - sin[1] * b[1]).T


def _to_world(ref, q_rows: list, n: int) -> np.ndarray:
    """`_local_phalanges`' frames back to the world: each phalanx's frame is ref @ (its frame in
    ref), an item's three in one (3, 3) x (3, 9) product (three 3x3 products cost twice as much).
    Returns (n, 3, 9): [item, row, 3 phalanx + column]."""
    return np.matmul(ref, float_array(q_rows).reshape(n, 3, 9))


def _local_phalanges(consts: list, local: list, radii: list | None, joints: bool) -> tuple:
    """`FingerSet.pose_floats`' items in Python floats: per item its constants (`consts`), its
    target in its reference frame (`local`, a triple) and its LED's radius (`radii`, or None) ->
    the three phalanx frames in the reference frame side by side (27 floats: a (3, 9) matrix's
    rows, each the three frames' rows) and, with `joints`, the PIP, DIP and tip from the MCP in
    it (9 floats). `pose`'s steps on one item: eq. 3-4's flexion, the clamped yaw and pitch,
    Q = Rx(-pitch) Rz(-yaw) Rx(flexed pitch) the first phalanx's frame, phalanx k Q Rx(k α)
    (columns x, c y + s z, c z - s y)."""
    q_rows, j_rows = [], []
    for k, (lx, ly, lz), rad in zip(consts, local, radii or [None] * len(local)):
        c0, bb, a4, minus_b, den, l1, l2, l3, ylo, yhi, plo, phi, half = k
        while True:  # twice with an LED: the aim moved to the tip joint once the distal frame is known
            dd = (lx * lx + ly * ly) + lz * lz  # eq. 3-4 (flexion_from_distance)
            disc = bb - a4 * (c0 - dd)
            x = (minus_b - _sqrt(0.0 if disc < 0.0 else disc)) / den
            x = -X_CLAMP if x < -X_CLAMP else X_CLAMP if x > X_CLAMP else x
            alpha = _PI - _acos(x)
            alpha = FLEXION_CAP if alpha > FLEXION_CAP else alpha
            c1, s1, c2, s2 = _cos(alpha), _sin(alpha), _cos(2.0 * alpha), _sin(2.0 * alpha)
            pitch = _atan2(-lz, ly)  # realign: the target's yaw and pitch clamped
            yaw = _atan2(lx, _hypot(ly, lz))
            yaw = ylo if yaw < ylo else yhi if yaw > yhi else yaw
            if not plo <= pitch <= phi:
                pitch = phi if (pitch - phi) % _TWO_PI < half else plo
            flexed = _atan2(-(l2 * s1 + l3 * s2), (l1 + l2 * c1) + l3 * c2)
            ca, sa, cb, sb = _cos(-pitch), _sin(-pitch), _cos(-yaw), _sin(-yaw)
            cc, sc = _cos(flexed), _sin(flexed)
            # Rx(-pitch) Rz(-yaw) Rx(flexed): rows (cb, -sb cc, sb sc), ca r1 - sa r2, sa r1 + ca r2
            # of r1 = (sb, cb cc, -cb sc), r2 = (0, sc, cc)
            q01, q02 = -sb * cc, sb * sc
            u1, u2 = cb * cc, -cb * sc
            q10, q11, q12 = ca * sb, ca * u1 - sa * sc, ca * u2 - sa * cc
            q20, q21, q22 = sa * sb, sa * u1 + ca * sc, sa * u2 + ca * cc
            if rad is None:
                break
            # the LED one radius off the distal phalanx's -Z: aim at the joint (its +Z, c2 z - s2 y)
            lx, ly = lx + rad * (c2 * q02 - s2 * q01), ly + rad * (c2 * q12 - s2 * q11)
            lz = lz + rad * (c2 * q22 - s2 * q21)
            rad = None
        # phalanges 2 and 3: the first turned by Rx(α), Rx(2α)
        y10, y11, y12 = c1 * q01 + s1 * q02, c1 * q11 + s1 * q12, c1 * q21 + s1 * q22
        y20, y21, y22 = c2 * q01 + s2 * q02, c2 * q11 + s2 * q12, c2 * q21 + s2 * q22
        q_rows += (cb, q01, q02, cb, y10, c1 * q02 - s1 * q01, cb, y20, c2 * q02 - s2 * q01,
                   q10, q11, q12, q10, y11, c1 * q12 - s1 * q11, q10, y21, c2 * q12 - s2 * q11,
                   q20, q21, q22, q20, y12, c1 * q22 - s1 * q21, q20, y22, c2 * q22 - s2 * q21)
        if joints:  # the segments summed from the MCP one after the other
            e0, e1, e2 = q01 * l1, q11 * l1, q21 * l1
            f0, f1, f2 = y10 * l2 + e0, y11 * l2 + e1, y12 * l2 + e2
            j_rows += (e0, e1, e2, f0, f1, f2, y20 * l3 + f0, y21 * l3 + f1, y22 * l3 + f2)
    return q_rows, j_rows


def pose_finger(mcp, ref_rot, l1, l2, l3, tip_target, thumb: bool = False, roll: float | None = None) -> FingerPose:
    """Pose one finger for F frames (appendix D).

    mcp: (F, 3) base joint; ref_rot: (F, 3, 3) the finger's reference frame (module docstring);
    l1, l2, l3: phalanx lengths; tip_target: (F, 3) where the fingertip should be.
    thumb: use the thumb's limits and roll its reference frame about +Y by `roll` (default 45°,
    appendix D; pass -45° for a hand whose frames are mirrored); a bool array (F,) poses fingers
    and thumbs at once (`roll` then rolls the thumbs only).
    Flexion from the MCP -> target distance (eq. 3-4, capped at 90°), then the yaw/pitch
    realignment; the tip reaches the target whenever the distance and angles are within limits.
    (`FingerSet(l1, l2, l3, thumb, roll).pose(...)`: a caller posing the same fingers again keeps
    the FingerSet.)"""
    mcp = np.asarray(mcp, float)
    return FingerSet(_per_item(l1, len(mcp)), _per_item(l2, len(mcp)), _per_item(l3, len(mcp)), thumb,
                     roll).pose(mcp, ref_rot, tip_target)
