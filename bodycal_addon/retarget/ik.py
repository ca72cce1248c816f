"""Analytical IK of the avatar (Delahaye 2023, appendix E; DESIGN.md §6), numpy only, vectorised over
a leading frame axis.

- `two_bone`: limbs (upperarm/forearm, thigh/shin). Flexion from the root-target distance
  (eq. 5-6), aligned to the target, swivel about the root-effector axis blended between the
  swivel through the retargeted intermediate-joint target and the user's swivel (eq. 7-8).
- `spine`: the trunk. Equal-angle arc whose chord matches the root -> skull-base distance, aimed
  at the skull base, a second pass that rotates the sacrum about its hip axis to line it up with
  the first vertebra, and a uniform twist (appendix D, "Trunk animation").

Rotations are world bone frames (columns x, y, z): +Y along the bone, +X its right, which for
the hinge is the flexion axis; a positive rotation about +X flexes (FORMATS.md §1).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ..core import one_frame
from ..core.one_frame import Matrix, Quaternion, Vector
from ..core.transforms import EPS, all_true, broadcast_shape, cross

BLEND_START = 0.05  # m: eq. 7, below this the user's swivel alone
BLEND_WIDTH = 0.10  # m: eq. 7, t = (r - 0.05) * 10 reaches 1 at 0.15 m
# m: the hinge axis weighs as much as this offset of the user's joint from the root-effector line.
# Decision: a measured hinge axis (a rotation, good to a degree) fixes the bending plane far better
# than the joint's offset while the limb is nearly straight, where a standing knee's 1-2 cm offset
# is mostly tracker noise: at 1 cm the swivel of straight limbs turned by tens of degrees from one
# frame to the next (a standing knee jumped 7-11 mm, the egocentric wrists' acceleration tripled on
# real clips). At 5 cm the upper arm's roll still jittered at twice the rotation copy's on a CMU
# walk at SteamVR noise (p95 0.53 vs 0.23 degrees per frame squared); at 10 cm 0.39, and the
# avatar's bend plane stays within 6 degrees (median) of the user's. (20 cm gave 0.32, but moved
# a nearly straight arm's elbow by 17-24 um on a rig whose rest Blender recomputed in float32,
# where 10 cm keeps it under 10 um: tests/blender/test_rig_variants.py.)
SWIVEL_HINT_WEIGHT = 0.1


def _dot(a, b):
    return np.einsum("...i,...i->...", a, b)


def _columns(x, y, z):
    """The matrices (..., 3, 3) with columns x, y, z (..., 3): np.stack(axis=-1)'s values, in a
    few assignments instead of its bookkeeping (which dominates on a few frames)."""
    out = np.empty(x.shape + (3,), np.result_type(x, y, z))
    out[..., 0], out[..., 1], out[..., 2] = x, y, z
    return out


def _unit(v, fallback):
    """Unit vectors (vectors last) and their norms, `fallback` where they vanish: the contract of
    `transforms.unit_and_norm`, kept apart because its norm is the einsum `_dot` of every other
    product here, which rounds differently in the last bit (unit_and_norm here moved 62 of the
    demo's 4108 baked curves). `fallback` may be a function giving it, called only when a vector
    vanishes (the usual case has none: its fallback would be computed for nothing)."""
    n = np.sqrt(_dot(v, v))
    ok = n > EPS
    if all_true(ok) and (callable(fallback) or np.shape(fallback) == v.shape
                         or broadcast_shape(np.shape(fallback), v.shape) == v.shape):
        return v / n[..., None], n  # np.where's values when every vector is kept
    fallback = fallback() if callable(fallback) else fallback
    return np.where(ok[..., None], v / np.where(ok, n, 1.0)[..., None], fallback), n


def _perp_unit(v, axis, fallback):
    """Unit component of v perpendicular to the unit `axis`; `fallback` where it vanishes."""
    w = v - _dot(v, axis)[..., None] * axis
    return _unit(w, fallback)


def _any_perpendicular(axis):
    """A unit vector perpendicular to each unit axis (deterministic, no NaN)."""
    ref = np.where((np.abs(axis[..., 0]) < 0.9)[..., None], np.array([1.0, 0.0, 0.0]), np.array([0.0, 1.0, 0.0]))
    return _perp_unit(ref, axis, np.array([0.0, 0.0, 1.0]))[0]


def swivel_blend(r) -> np.ndarray:
    """Eq. 7: t = 0 if r <= 0.05 m, (r - 0.05) * 10 in between, 1 from 0.15 m."""
    return np.clip((np.asarray(r, float) - BLEND_START) / BLEND_WIDTH, 0.0, 1.0)


def flexion_angle(l1, l2, d) -> np.ndarray:
    """Eq. 5-6: flexion α = π - acos((l1² + l2² - d²) / (2 l1 l2)), clamped to [0, π]
    (0 = straight: unreachable targets; π = folded)."""
    l1, l2, d = (np.asarray(x, float) for x in (l1, l2, d))
    c = (l1 * l1 + l2 * l2 - d * d) / np.maximum(2.0 * l1 * l2, EPS)
    return np.pi - np.arccos(np.clip(c, -1.0, 1.0))


@dataclass
class TwoBoneResult:
    mid: np.ndarray  # (F, 3) intermediate joint (elbow / knee)
    end: np.ndarray  # (F, 3) effector joint (wrist / ankle)
    rot1: np.ndarray  # (F, 3, 3) world frame of the first bone (+Y root -> mid, +X flexion axis)
    rot2: np.ndarray  # (F, 3, 3) world frame of the second bone (+Y mid -> end, same +X)
    blend: np.ndarray  # (F,) t of eq. 7
    swivel_dir: np.ndarray  # (F, 3) unit direction from the root-effector axis to the mid joint
    # (l1, l2, the root-target distance clamped to the limb's reach, unclamped) (F,) each: the
    # flexion and whether the target was reached are computed from these when asked for (the
    # solver reads neither)
    lengths: tuple

    @property
    def flexion(self) -> np.ndarray:
        """(F,) α, radians (eq. 5-6)."""
        l1, l2, d, _ = self.lengths
        return flexion_angle(l1, l2, d)

    @property
    def reached(self) -> np.ndarray:
        """(F,) bool: the target was within reach."""
        l1, l2, _, dist = self.lengths
        return (dist >= np.abs(l1 - l2) - 1e-9) & (dist <= l1 + l2 + 1e-9)

    def __iter__(self):
        """`mid, end, rot1, rot2 = two_bone(...)` unpacks the joints and the bone frames."""
        return iter((self.mid, self.end, self.rot1, self.rot2))


FEW_LIMBS = 4  # two_bone of this many items (limbs x frames) or fewer runs in Python floats


def two_bone(root, l1, l2, target, pole_target=None, user_swivel_dir=None, flex_axis_hint=None,
             size_ratio: float = 1.0) -> TwoBoneResult:
    """Two-bone analytical IK (Delahaye 2023, appendix E).

    root, target: (F, 3); l1, l2: bone lengths (scalars or (F,)).
    pole_target: (F, 3) the retargeted intermediate joint (elbow/knee) or None; its distance r from
      the root-target axis sets the blend t of eq. 7 and its direction gives the swivel β.
    user_swivel_dir: (F, 3) the user's swivel γ as a direction from the user's root-effector axis
      toward the user's intermediate joint (only its part perpendicular to the avatar's axis is
      used). `flex_axis_hint`: the user's hinge axis (forearm/shin +X, world), whose swivel is
      axis x hint; with both, the hint is added with the weight of a SWIVEL_HINT_WEIGHT offset, so
      it takes over smoothly as the user's limb straightens; with the hint alone it is the swivel.
    size_ratio: the avatar's size over the performer's (the root scale); r is divided by it, so
      eq. 7's metres are the performer's and an avatar scaled by s poses as its unscaled self,
      scaled (Decision: measured on the avatar, a child's elbow blended unlike its performer's).
    Returns TwoBoneResult. Unreachable targets: the limb fully extended toward the target; too
    close (d < |l1 - l2|): folded as far as possible toward it; target on the root: the axis is
    taken toward the pole target (else straight down). Never NaN.

    The mid joint lies in the half-plane through the axis and `swivel_dir`; the hinge axis is
    `swivel_dir x axis`, so the flexion is positive about +X of both bones (rot2 = rot1 Rx(α)).

    Decision (speed): a few items (FEW_LIMBS: a live frame's two arms or legs) are solved in
    Python floats (`_two_bone_one`, float64: numpy's values to their sums' rounding), where
    numpy's per-call overhead was the whole cost (mathutils' float32 Vectors, which it replaced,
    cost a third more: DESIGN.md "Prepared solver")."""
    root = np.asarray(root, float)
    target = np.asarray(target, float)
    F = root.shape[0]
    l1, l2 = np.asarray(l1, float), np.asarray(l2, float)
    if l1.shape != (F,):  # (a limb set's lengths come as (F,) already)
        l1 = np.broadcast_to(l1, (F,))
    if l2.shape != (F,):
        l2 = np.broadcast_to(l2, (F,))
    if F <= FEW_LIMBS and one_frame.ENABLED:
        return _two_bone_one(root, l1, l2, target, pole_target, user_swivel_dir, flex_axis_hint, size_ratio)
    down = np.broadcast_to(np.array([0.0, 0.0, -1.0]), (F, 3))
    fallback_axis = down
    if pole_target is not None:
        fallback_axis = _unit(np.asarray(pole_target, float) - root, down)[0]
    axis, dist = _unit(target - root, fallback_axis)
    d = np.clip(dist, np.abs(l1 - l2), l1 + l2)

    # γ: the user's swivel direction, perpendicular to this axis.
    if flex_axis_hint is not None:
        hint_dir = _unit(cross(axis, np.asarray(flex_axis_hint, float)), lambda: _any_perpendicular(axis))[0]
    else:
        hint_dir = _any_perpendicular(axis)
    gamma_dir = hint_dir
    if user_swivel_dir is not None:
        w = np.asarray(user_swivel_dir, float)
        w = w - _dot(w, axis)[..., None] * axis
        if flex_axis_hint is not None:
            # The hinge axis takes over smoothly as the user's limb straightens (its mid joint then
            # says nothing about the swivel): a SWIVEL_HINT_WEIGHT offset weighs as much as the hint.
            w = w + SWIVEL_HINT_WEIGHT * hint_dir
        gamma_dir = _unit(w, hint_dir)[0]
    # β: the swivel through the pole target; t from its distance to the axis (eq. 7-8).
    if pole_target is not None:
        rel = np.asarray(pole_target, float) - root
        beta_dir, r = _perp_unit(rel, axis, gamma_dir)
        t = swivel_blend(r / size_ratio)
    else:
        beta_dir, t = gamma_dir, np.zeros(F)
    # δ = t β + (1 - t) γ as angles about the axis, measured from γ (shortest way round).
    delta = t * np.arctan2(_dot(cross(gamma_dir, beta_dir), axis), _dot(gamma_dir, beta_dir))
    ortho = cross(axis, gamma_dir)
    swivel = np.cos(delta)[..., None] * gamma_dir + np.sin(delta)[..., None] * ortho

    a = (l1 * l1 - l2 * l2 + d * d) / np.maximum(2.0 * d, EPS)
    a = np.where(d > EPS, a, 0.0)
    h = np.sqrt(np.maximum(l1 * l1 - a * a, 0.0))
    mid = root + a[..., None] * axis + h[..., None] * swivel
    end = root + d[..., None] * axis
    x = cross(swivel, axis)
    y1 = _unit(mid - root, axis)[0]
    y2 = _unit(end - mid, axis)[0]
    rot1 = _columns(x, y1, cross(x, y1))
    rot2 = _columns(x, y2, cross(x, y2))
    return TwoBoneResult(mid, end, rot1, rot2, t, swivel, (l1, l2, d, dist))


# --- one frame: mathutils helpers (the spine's), two_bone of a few items in Python floats ---------

def _m_unit(v, fallback):
    """`_unit` of one mathutils Vector: (unit, norm), `fallback` (a Vector, or a function giving
    it) where the norm is EPS or less (NaN included)."""
    n = v.length
    if n > EPS:
        return v / n, n
    return (fallback() if callable(fallback) else fallback), n


def _m_any_perpendicular(axis):
    """`_any_perpendicular` of one unit Vector."""
    ref = _X if abs(axis[0]) < 0.9 else _Y
    return _m_unit(ref - axis * ref.dot(axis), _Z)[0]


def _f_unit(x, y, z, fallback):
    """`_unit` of one vector's components: (ux, uy, uz, norm), `fallback` (a triple, or a
    function giving it) where the norm is EPS or less (NaN included)."""
    n = math.sqrt((x * x + z * z) + y * y)
    if n > EPS:
        return x / n, y / n, z / n, n
    return (*(fallback() if callable(fallback) else fallback), n)


def _f_any_perpendicular(a0, a1, a2):
    """`_any_perpendicular` of one unit vector's components."""
    if abs(a0) < 0.9:  # +X made perpendicular
        return _f_unit(1.0 - a0 * a0, -a1 * a0, -a2 * a0, (0.0, 0.0, 1.0))[:3]
    return _f_unit(-a0 * a1, 1.0 - a1 * a1, -a2 * a1, (0.0, 0.0, 1.0))[:3]  # +Y


def _two_bone_one(root, l1, l2, target, pole_target, user_swivel_dir, flex_axis_hint, size_ratio):
    """`two_bone` of a few items (a live frame's two arms or two legs) in Python floats
    (`two_bone_floats`), its arrays in and out."""
    R = np.asarray(root, float).tolist()
    U, K, T, P = (np.asarray(a, float).reshape(-1, 3).tolist() if a is not None else None
                  for a in (user_swivel_dir, flex_axis_hint, target, pole_target))
    out = np.array(two_bone_floats(R, l1.tolist(), l2.tolist(), T, P, U, K, size_ratio))
    return TwoBoneResult(out[:, 0:3], out[:, 3:6], out[:, 6:15].reshape(-1, 3, 3),
                         out[:, 15:24].reshape(-1, 3, 3), out[:, 27], out[:, 24:27],
                         (l1, l2, out[:, 28], out[:, 29]))


def two_bone_floats(R, L1, L2, T, P, U, K, size_ratio) -> list:
    """`two_bone` of a few items in Python floats: each argument a list of Python floats per item
    (R roots, T targets, P pole targets, U the user's swivels, K hinge hints: triples, each list or
    None as `two_bone`'s; L1, L2 the lengths). Per item, the numpy path's steps on each vector's
    three components (float64, as numpy's; a float operation costs about a hundred instructions, a
    mathutils Vector operation 1,500-2,500). The limb is held relative to its root (the target and
    pole minus the root) and the joints come back added to the root: numpy's values to their sums'
    rounding. Returns per item a tuple of 30 floats: mid (3), end (3), rot1's and rot2's entries
    (9 each, row-major), the swivel direction (3), t, the clamped distance d and the unclamped one
    (a live frame's solver writes the frames straight from these: `PreparedSolver._limbs_one`)."""
    # `_f_unit`'s norms written in line (a call and its tuples cost more than the sums), each
    # falling back where its norm is EPS or less, NaN included (`not n > EPS`)
    sqrt, atan2, cos, sin = math.sqrt, math.atan2, math.cos, math.sin
    rows = []
    for i, (r0, r1, r2) in enumerate(R):
        t0, t1, t2 = T[i]
        t0, t1, t2 = t0 - r0, t1 - r1, t2 - r2
        dist = sqrt((t0 * t0 + t2 * t2) + t1 * t1)
        if dist > EPS:  # the axis
            a0, a1, a2 = t0 / dist, t1 / dist, t2 / dist
        elif P is None:
            a0, a1, a2 = 0.0, 0.0, -1.0
        else:
            p0, p1, p2 = P[i]
            a0, a1, a2 = _f_unit(p0 - r0, p1 - r1, p2 - r2, (0.0, 0.0, -1.0))[:3]
        b1, b2 = L1[i], L2[i]
        lo, hi = abs(b1 - b2), b1 + b2
        d = lo if dist < lo else hi if dist > hi else dist
        if K is not None:
            k0, k1, k2 = K[i]
            h0, h1, h2 = a1 * k2 - a2 * k1, a2 * k0 - a0 * k2, a0 * k1 - a1 * k0
            n = sqrt((h0 * h0 + h2 * h2) + h1 * h1)
            if n > EPS:
                h0, h1, h2 = h0 / n, h1 / n, h2 / n
            else:
                h0, h1, h2 = _f_any_perpendicular(a0, a1, a2)
        else:
            h0, h1, h2 = _f_any_perpendicular(a0, a1, a2)
        if U is not None:  # γ
            u0, u1, u2 = U[i]
            s = (u0 * a0 + u2 * a2) + u1 * a1
            w0, w1, w2 = u0 - s * a0, u1 - s * a1, u2 - s * a2
            if K is not None:
                w0, w1, w2 = w0 + SWIVEL_HINT_WEIGHT * h0, w1 + SWIVEL_HINT_WEIGHT * h1, w2 + SWIVEL_HINT_WEIGHT * h2
            n = sqrt((w0 * w0 + w2 * w2) + w1 * w1)
            g0, g1, g2 = (w0 / n, w1 / n, w2 / n) if n > EPS else (h0, h1, h2)
        else:
            g0, g1, g2 = h0, h1, h2
        if P is not None:  # β and t (eq. 7-8)
            p0, p1, p2 = P[i]
            p0, p1, p2 = p0 - r0, p1 - r1, p2 - r2
            s = (p0 * a0 + p2 * a2) + p1 * a1
            e0, e1, e2 = p0 - s * a0, p1 - s * a1, p2 - s * a2
            r = sqrt((e0 * e0 + e2 * e2) + e1 * e1)
            e0, e1, e2 = (e0 / r, e1 / r, e2 / r) if r > EPS else (g0, g1, g2)
            t = min(max((r / size_ratio - BLEND_START) / BLEND_WIDTH, 0.0), 1.0)
            # δ = t β + (1 - t) γ as angles about the axis, from γ
            c0, c1, c2 = g1 * e2 - g2 * e1, g2 * e0 - g0 * e2, g0 * e1 - g1 * e0
            delta = t * atan2((c0 * a0 + c2 * a2) + c1 * a1, (g0 * e0 + g2 * e2) + g1 * e1)
        else:
            t = delta = 0.0
        cs, sn = cos(delta), sin(delta)
        o0, o1, o2 = a1 * g2 - a2 * g1, a2 * g0 - a0 * g2, a0 * g1 - a1 * g0  # axis x γ
        s0, s1, s2 = cs * g0 + sn * o0, cs * g1 + sn * o1, cs * g2 + sn * o2  # the swivel
        a = (b1 * b1 - b2 * b2 + d * d) / max(2.0 * d, EPS) if d > EPS else 0.0
        h = sqrt(max(b1 * b1 - a * a, 0.0))
        m0, m1, m2 = a * a0 + h * s0, a * a1 + h * s1, a * a2 + h * s2  # mid, from the root
        n0, n1, n2 = d * a0, d * a1, d * a2  # end
        x0, x1, x2 = s1 * a2 - s2 * a1, s2 * a0 - s0 * a2, s0 * a1 - s1 * a0
        n = sqrt((m0 * m0 + m2 * m2) + m1 * m1)
        y0, y1, y2 = (m0 / n, m1 / n, m2 / n) if n > EPS else (a0, a1, a2)
        z0, z1, z2 = n0 - m0, n1 - m1, n2 - m2
        n = sqrt((z0 * z0 + z2 * z2) + z1 * z1)
        z0, z1, z2 = (z0 / n, z1 / n, z2 / n) if n > EPS else (a0, a1, a2)
        rows.append((r0 + m0, r1 + m1, r2 + m2, r0 + n0, r1 + n1, r2 + n2,
                     x0, y0, x1 * y2 - x2 * y1, x1, y1, x2 * y0 - x0 * y2, x2, y2, x0 * y1 - x1 * y0,
                     x0, z0, x1 * z2 - x2 * z1, x1, z1, x2 * z0 - x0 * z2, x2, z2, x0 * z1 - x1 * z0,
                     s0, s1, s2, t, d, dist))
    return rows


if Vector is not None:  # the constant Vectors (never changed in place)
    _X, _Y, _Z = (Vector(v) for v in ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)))


# --- spine ----------------------------------------------------------------------------------------

@dataclass
class SpineResult:
    joints: np.ndarray  # (F, n + 1, 3): the spine root, then the top of every vertebra
    rotations: np.ndarray  # (F, n, 3, 3) vertebra frames (+Y along, +X the twisted hip axis)
    sacrum_rot: np.ndarray  # (F, 3, 3) the sacrum's frame after the second pass
    bend: np.ndarray  # (F,) the angle between consecutive vertebrae, radians


def _arc_chord(lengths, theta):
    """Chord (along, across) of a planar chain whose k-th segment turns by k θ from the first.
    lengths (n,), theta (F,) -> (F, 2) in the frame of the first segment."""
    k = np.arange(len(lengths))
    ang = theta[:, None] * k
    return np.stack([(lengths * np.cos(ang)).sum(-1), (lengths * np.sin(ang)).sum(-1)], axis=-1)


def _solve_arc(lengths, chord, iterations=48):
    """θ >= 0 with |chord(θ)| = chord (bisection; the chord shrinks monotonically while the arc
    turns less than a full circle). Out of range: straight (θ = 0) or the tightest arc."""
    n = len(lengths)
    lo = np.zeros_like(chord)
    hi = np.full_like(chord, 2.0 * np.pi / max(n, 1) * 0.999)
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        c = np.linalg.norm(_arc_chord(lengths, mid), axis=-1)
        longer = c > chord
        lo = np.where(longer, mid, lo)
        hi = np.where(longer, hi, mid)
    return 0.5 * (lo + hi)


def _place_arc(start, lengths, target, bend_dir, fallback_side):
    """Equal-angle arc from `start` whose chord points at `target` (clamped to the chain's length),
    its first segment leaning toward `bend_dir`. Returns joints (F, n+1, 3) and θ (F,)."""
    lengths = np.asarray(lengths, float)
    chord_vec = target - start
    chord_dir, chord_len = _unit(chord_vec, np.array([0.0, 0.0, 1.0]))
    theta = _solve_arc(lengths, np.minimum(chord_len, lengths.sum()))
    fallback = _perp_unit(fallback_side, chord_dir, lambda: _any_perpendicular(chord_dir))[0]
    side = _perp_unit(bend_dir, chord_dir, fallback)[0]
    local = _arc_chord(lengths, theta)  # the chord seen from the first segment
    phi = np.arctan2(local[:, 1], local[:, 0])
    k = np.arange(len(lengths))
    # In the (chord_dir, side) plane segment k is at φ - kθ: the first leans φ toward `side`, the
    # chain curls back and its chord lies along chord_dir.
    ang = phi[:, None] - theta[:, None] * k
    seg = (np.cos(ang)[..., None] * chord_dir[:, None] + np.sin(ang)[..., None] * side[:, None]) * lengths[:, None]
    joints = np.concatenate([start[:, None], start[:, None] + np.cumsum(seg, axis=1)], axis=1)
    return joints, theta


MAX_SPINE_STRETCH = 1.05  # the spine reaches a skull base at most this much farther than its rest chord
MIN_SPINE_STRETCH = 0.85


@lru_cache(maxsize=16)
def _rest_spine(data: bytes, shape: tuple) -> tuple:
    """What `bend_rest_spine` reads of a rest spine (n, 3), once per spine: the vertebrae's lengths
    and unit directions, the rest chord's direction, the segment numbers 1..n and the
    (numerator, denominator) of the bend's share per segment."""
    rest_segments = np.frombuffer(data, float).reshape(shape)
    lengths = np.linalg.norm(rest_segments, axis=-1)
    seg0 = rest_segments / np.maximum(lengths, EPS)[:, None]
    u0 = _unit(rest_segments.sum(0), np.array([0.0, 1.0, 0.0]))[0]
    k = np.arange(1, len(lengths) + 1)
    for a in (lengths, seg0, u0, k):
        a.setflags(write=False)  # shared by every call
    return lengths, seg0, u0, k, (lengths.sum(), max(float((lengths * k).sum()), EPS))


def bend_rest_spine(start, sacrum_rot, rest_segments, target):
    """The rest spine bent by one equal angle per vertebra so that its chord points at `target`
    (Decision, replacing the equal-angle arc's chord-LENGTH match of appendix D when the rest
    shape is known): a spine near straight barely shortens as it bends (a 20° bend shortens a
    0.54 m chord by 2.7 mm, the size of the trackers' noise), so the length says little about the
    bend, while the chord's direction in the sacrum says it to a fraction of a degree. Segment k
    turns by (k + 1) δ about the axis that carries the rest chord to the current one, δ chosen so
    a straight chain's chord turns by that angle; a last rigid turn and a uniform stretch (within
    MIN/MAX_SPINE_STRETCH) put the top on the target. At the rest chord the rest shape comes back
    exactly. start (F, 3), sacrum_rot (F, 3, 3), rest_segments (n, 3) in the sacrum's frame,
    target (F, 3) -> joints (F, n + 1, 3), δ (F,)."""
    rest_segments = np.ascontiguousarray(rest_segments, float)
    lengths, seg0, u0, k, ratio = _rest_spine(rest_segments.tobytes(), rest_segments.shape)
    local = np.einsum("fji,fj->fi", sacrum_rot, target - start)
    ut, reach = _unit(local, u0)
    axis, sin_phi = _unit(cross(u0, ut), lambda: _any_perpendicular(np.broadcast_to(u0, ut.shape)))
    phi = np.arctan2(sin_phi, _dot(u0, ut))
    delta = phi * ratio[0] / ratio[1]
    return _bend_vertebrae(start, sacrum_rot, lengths, seg0, k, ut, reach, axis, delta), delta


def _turn_components(v, a, cos, sin):
    """Rodrigues' formula on components: v (3 arrays) turned about the unit axis a (3 arrays), each by
    the angle whose cosine and sine are given, broadcast: v c + (a x v) s + a (a . v) (1 - c),
    numpy's operations in their order (`_dot` adds (0 + 2) + 1, `cross` a1 v2 - a2 v1, ...)."""
    v0, v1, v2 = v
    a0, a1, a2 = a
    d = (a0 * v0 + a2 * v2) + a1 * v1
    e = 1 - cos
    return ((v0 * cos + (a1 * v2 - a2 * v1) * sin) + a0 * d * e,
            (v1 * cos + (a2 * v0 - a0 * v2) * sin) + a1 * d * e,
            (v2 * cos + (a0 * v1 - a1 * v0) * sin) + a2 * d * e)


def _bend_vertebrae(start, sacrum_rot, lengths, seg0, k, ut, reach, axis, delta):
    """`bend_rest_spine`'s vertebrae, components first: each component an (F, n) array (products
    over rows of three with broadcast operands cost several times more): each vertebra turned by
    its share of the bend (`_turn_components`: Rodrigues' formula), the chord summed over the
    vertebrae in order, the last rigid turn, the stretch, the sacrum's frame and the joints'
    running sum."""
    ang = delta[:, None] * k
    seg = _turn_components(seg0.T[:, None, :], axis.T[:, :, None], np.cos(ang), np.sin(ang))
    chord = np.empty((len(delta), 3))
    for i in range(3):  # (seg * lengths).sum over the vertebrae, in order (a running sum's last)
        chord[:, i] = np.cumsum(seg[i] * lengths, axis=1)[:, -1]
    cdir, clen = _unit(chord, ut)
    turn_axis, sin_t = _unit(cross(cdir, ut), axis)
    turn = np.arctan2(sin_t, _dot(cdir, ut))[:, None]
    seg = _turn_components(seg, turn_axis.T[:, :, None], np.cos(turn), np.sin(turn))
    stretch = np.clip(reach / np.maximum(clen, EPS), MIN_SPINE_STRETCH, MAX_SPINE_STRETCH)
    scale = lengths[None, :] * stretch[:, None]
    joints = np.empty((len(delta), len(lengths) + 1, 3))
    joints[:, 0] = start
    rot = sacrum_rot.transpose(1, 2, 0)  # rot[i, j]: (F,) entries
    for i in range(3):  # np.einsum("fij,fkj->fki") times the lengths, then start + the running sum
        world = ((rot[i, 0][:, None] * seg[0] + rot[i, 2][:, None] * seg[2]) + rot[i, 1][:, None] * seg[1]) * scale
        np.cumsum(world, axis=1, out=joints[:, 1:, i])
        joints[:, 1:, i] += start[:, i, None]
    return joints


def spine(pelvis, sacrum_rot, sacrum_length, lengths, skull_base, top_right=None, two_pass=True,
          rest_segments=None) -> SpineResult:
    """Trunk IK (Delahaye 2023, appendix D, "Trunk animation"; DESIGN.md §6).

    pelvis: (F, 3) sacrum origin; sacrum_rot: (F, 3, 3) the sacrum frame (+Y pelvis -> spine root,
    +X the hip axis, rigid on the pelvis tracker); sacrum_length: pelvis -> spine root distance;
    lengths: (n,) vertebra lengths bottom-up; skull_base: (F, 3) the spine's target;
    top_right: (F, 3) the right direction wanted at the top (head/shoulders), for the twist.

    Pass 1: equal-angle arc from the spine root whose chord matches the distance to the skull
    base, aimed at it, its first vertebra leaning toward the sacrum's +Y. Pass 2 (two_pass): the
    sacrum turns about its hip axis (+X) to line its +Y up with that first vertebra, which moves
    the spine root, and the arc is solved again. Twist: the hip axis turns uniformly about the
    chord up to `top_right`, vertebra by vertebra. When the skull base is straight above the
    sacrum's +Y but closer than the spine's length, the first vertebra leans toward the sacrum's
    -Z (backward for a sacrum whose +X is the performer's left).

    rest_segments: (n, 3) the vertebrae at rest in the sacrum's frame. When given (Decision), the
    bend comes from the chord's DIRECTION in the sacrum instead of its length (`bend_rest_spine`),
    and `lengths` / `two_pass` are not used."""
    pelvis = np.asarray(pelvis, float)
    sacrum_rot = np.asarray(sacrum_rot, float)
    target = np.asarray(skull_base, float)
    if rest_segments is not None and len(pelvis) == 1 and one_frame.ENABLED:  # one frame: mathutils
        return _spine_one(pelvis, sacrum_rot, sacrum_length, np.asarray(rest_segments, float), target, top_right)
    start = pelvis + sacrum_length * sacrum_rot[..., 1]
    if rest_segments is not None:
        joints, theta = bend_rest_spine(start, sacrum_rot, np.asarray(rest_segments, float), target)
        two_pass = False
    else:
        joints, theta = _place_arc(start, np.asarray(lengths, float), target, sacrum_rot[..., 1], -sacrum_rot[..., 2])
    if two_pass:
        x = sacrum_rot[..., 0]
        first = _unit(joints[:, 1] - joints[:, 0], sacrum_rot[..., 1])[0]
        y0 = sacrum_rot[..., 1]
        fp = _perp_unit(first, x, y0)[0]
        ang = np.arctan2(_dot(cross(y0, fp), x), _dot(y0, fp))
        c, s = np.cos(ang)[..., None], np.sin(ang)[..., None]

        def turn(v):  # Rodrigues about x (v perpendicular parts only matter for frame columns)
            return v * c + cross(x, v) * s + x * _dot(x, v)[..., None] * (1 - c)

        sacrum_rot = np.stack([x, turn(sacrum_rot[..., 1]), turn(sacrum_rot[..., 2])], axis=-1)
        start = pelvis + sacrum_length * sacrum_rot[..., 1]
        joints, theta = _place_arc(start, lengths, target, sacrum_rot[..., 1], -sacrum_rot[..., 2])
    # Uniform twist from the hip axis to the top's right, about the chord.
    chord = _unit(joints[:, -1] - joints[:, 0], sacrum_rot[..., 1])[0]
    hip = _perp_unit(sacrum_rot[..., 0], chord, lambda: _any_perpendicular(chord))[0]
    total = np.zeros(len(pelvis))
    if top_right is not None:
        top = _perp_unit(np.asarray(top_right, float), chord, hip)[0]
        total = np.arctan2(_dot(cross(hip, top), chord), _dot(hip, top))
    n = joints.shape[1] - 1
    frac = (np.arange(n) + 1.0) / n
    ang = total[:, None] * frac
    other = cross(chord, hip)
    return SpineResult(joints, _twist_vertebrae(joints, chord, hip, other, ang), sacrum_rot, theta)


def _twist_vertebrae(joints, chord, hip, other, ang):
    """`spine`'s vertebra frames, components first ((F, n) arrays, as `_bend_vertebrae`): the right
    turned from the hip axis by `ang` (F, n) about the chord, +Y along each vertebra (the chord
    where a vertebra vanishes), +X the right made perpendicular to it (any perpendicular where it
    vanishes), +Z their cross product; sums as `_dot`'s einsum adds them, (0 + 2) + 1."""
    cos, sin = np.cos(ang), np.sin(ang)
    right = [cos * hip[:, i, None] + sin * other[:, i, None] for i in range(3)]
    step = [joints[:, 1:, i] - joints[:, :-1, i] for i in range(3)]
    norm = np.sqrt((step[0] * step[0] + step[2] * step[2]) + step[1] * step[1])
    ok = norm > EPS
    if all_true(ok):
        y = [v / norm for v in step]
    else:
        y = [np.where(ok, v / np.where(ok, norm, 1.0), chord[:, i, None]) for i, v in enumerate(step)]
    along = (right[0] * y[0] + right[2] * y[2]) + right[1] * y[1]
    w = [right[i] - along * y[i] for i in range(3)]
    norm = np.sqrt((w[0] * w[0] + w[2] * w[2]) + w[1] * w[1])
    ok = norm > EPS
    if all_true(ok):
        x = [v / norm for v in w]
    else:
        spare = _any_perpendicular(np.stack(y, axis=-1))
        x = [np.where(ok, v / np.where(ok, norm, 1.0), spare[..., i]) for i, v in enumerate(w)]
    out = np.empty(ang.shape + (3, 3))
    for i in range(3):
        out[..., i, 0] = x[i]
        out[..., i, 1] = y[i]
    out[..., 0, 2] = x[1] * y[2] - x[2] * y[1]  # `cross`'s differences
    out[..., 1, 2] = x[2] * y[0] - x[0] * y[2]
    out[..., 2, 2] = x[0] * y[1] - x[1] * y[0]
    return out


@lru_cache(maxsize=16)
def _rest_spine_one(data: bytes, shape: tuple) -> tuple:
    """`_rest_spine` for `_spine_one`, once per spine: the lengths and segment numbers as Python
    floats, the unit directions and the rest chord's as mathutils Vectors (never changed in place),
    and each vertebra's share of the twist, (m + 1) / n."""
    lengths, seg0, u0, k, ratio = _rest_spine(data, shape)
    n = len(lengths)
    return (lengths.tolist(), [Vector(v) for v in seg0.tolist()], Vector(u0.tolist()), k.tolist(), ratio,
            [(m + 1.0) / n for m in range(n)])


def _spine_one(pelvis, sacrum_rot, sacrum_length, rest_segments, target, top_right) -> SpineResult:
    """`spine` with `rest_segments` (`bend_rest_spine`, then the twist) of ONE frame in mathutils
    (float32: core/one_frame.py): the numpy path's steps on single Vectors, each vertebra's turn
    about a unit axis as a Quaternion (Rodrigues' formula), the scalars in Python floats, and each
    vertebra's joint and twisted frame in Python floats too (cheaper than a Vector operation per
    step: DESIGN.md "Prepared solver"); the joints relative to the spine's start, added to it in
    float64 (as `_two_bone_one`'s)."""
    lengths, seg0, u0, k, ratio, shares = _rest_spine_one(rest_segments.tobytes(), rest_segments.shape)
    sac = sacrum_rot[0].tolist()
    rot = Matrix(sac)
    # the spine's start (`spine`'s pelvis + sacrum_length +Y, float64 as numpy's) and the target
    (p0, p1, p2), (g0, g1, g2), sl = pelvis[0].tolist(), target[0].tolist(), float(sacrum_length)
    s0, s1, s2 = p0 + sl * sac[0][1], p1 + sl * sac[1][1], p2 + sl * sac[2][1]
    ut, reach = _m_unit(Vector((g0 - s0, g1 - s1, g2 - s2)) @ rot, u0)  # rot^T (target - start)
    axis, sin_phi = _m_unit(u0.cross(ut), lambda: _m_any_perpendicular(u0))
    delta = math.atan2(sin_phi, u0.dot(ut)) * ratio[0] / ratio[1]
    seg = [Quaternion(axis, delta * kk) @ v for v, kk in zip(seg0, k)]
    chord = seg[0] * lengths[0]
    for v, ln in zip(seg[1:], lengths[1:]):
        chord = chord + v * ln
    cdir, clen = _m_unit(chord, ut)
    turn_axis, sin_t = _m_unit(cdir.cross(ut), axis)
    # the last rigid turn and the sacrum's frame, one matrix
    world = rot @ Quaternion(turn_axis, math.atan2(sin_t, cdir.dot(ut))).to_matrix()
    stretch = min(max(reach / max(clen, EPS), MIN_SPINE_STRETCH), MAX_SPINE_STRETCH)
    # From here on each vertebra's few scalars are Python floats (a float operation costs about a
    # hundred instructions, a mathutils one on a Vector 1,500-2,500: the loops below were two
    # thirds of the kernel's): its unit direction, world, its top joint relative to the start.
    dirs = [(world @ v)[:] for v in seg]
    joints = [s0, s1, s2]  # the start plus each joint relative to it (float64, as numpy's sum)
    jx = jy = jz = 0.0
    for (vx, vy, vz), ln in zip(dirs, lengths):
        step = ln * stretch
        jx, jy, jz = jx + vx * step, jy + vy * step, jz + vz * step
        joints += (s0 + jx, s1 + jy, s2 + jz)
    # the twist: the hip axis turned uniformly about the chord up to the top's right
    y_sac, x_sac = rot.col[1], rot.col[0]
    chord = _m_unit(Vector((jx, jy, jz)), y_sac)[0]
    hip = _m_unit(x_sac - chord * x_sac.dot(chord), lambda: _m_any_perpendicular(chord))[0]
    total = 0.0
    if top_right is not None:
        tr = Vector(np.asarray(top_right, float)[0].tolist())
        top = _m_unit(tr - chord * tr.dot(chord), hip)[0]
        total = math.atan2(hip.cross(top).dot(chord), hip.dot(top))
    (hx, hy, hz), (ox, oy, oz), (cx, cy, cz) = hip[:], chord.cross(hip)[:], chord[:]
    n = len(seg)
    rows = []
    cos, sin, sqrt = math.cos, math.sin, math.sqrt
    for (vx, vy, vz), ln, share in zip(dirs, lengths, shares):
        ang = total * share
        ca, sa = cos(ang), sin(ang)
        r0, r1, r2 = hx * ca + ox * sa, hy * ca + oy * sa, hz * ca + oz * sa  # the right, turned
        # +Y along the vertebra (the chord where it vanishes), +X the right made perpendicular to it
        size = sqrt(vx * vx + vy * vy + vz * vz)
        if ln * stretch * size > EPS:
            y0, y1, y2 = vx / size, vy / size, vz / size
        else:
            y0, y1, y2 = cx, cy, cz
        along = r0 * y0 + r1 * y1 + r2 * y2
        x0, x1, x2 = r0 - y0 * along, r1 - y1 * along, r2 - y2 * along
        size = sqrt(x0 * x0 + x1 * x1 + x2 * x2)
        if size > EPS:
            x0, x1, x2 = x0 / size, x1 / size, x2 / size
        else:
            x0, x1, x2 = _m_any_perpendicular(Vector((y0, y1, y2)))[:]
        rows += (x0, y0, x1 * y2 - x2 * y1, x1, y1, x2 * y0 - x0 * y2, x2, y2, x0 * y1 - x1 * y0)
    rotations = np.array(rows).reshape(1, n, 3, 3)
    return SpineResult(np.array(joints).reshape(1, n + 1, 3), rotations, sacrum_rot,
                       np.array([delta]))
