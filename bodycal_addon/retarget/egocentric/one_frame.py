"""One frame's egocentric mapping (Delahaye 2023, appendix C; DESIGN.md §5 and "Prepared solver"):
the same projection, weights, kinematic normalisation and floor as `mapping.prepare_targets` and
`PreparedTargets.map`, for ONE frame, over flat arrays of the (target, element) pairs that carry
weight, with every index array made once per (targets, elements, exclusions) layout.

Why a second implementation: a live frame or a preview's is a few hundred pairs, where numpy's
per-call cost (several thousand instructions) is the whole cost; the bake's kernels keep a frame
axis, a group axis and a padded element axis for every target (their sums run over the same
elements in the same order as the bake's, bit for bit), so one frame paid for their bookkeeping.
Here every stage is one call over all pairs: the pairs of every target side by side (capsules
and the sphere, then the meshes), each target's sums by `np.bincount` over its own pairs (in
float64), each chain's sum over its bones as rows of a (bone, pair) mask (no BLAS product: its
last bit follows the operands' alignment, and a live worker process must give this process's pose
bit for bit), and the pairs a target excludes (its own chain, a stage's elements) not computed at all (their weight is
zero, eq. 1).

Decision (precision): the mapping runs in float32 as the bake's does (solver_methods.MAPPING_DTYPE)
but its sums are float64 and run in pair order, not the bake's: one frame agrees with the bake's
targets to float32's rounding (measured on a CMU take: tests/engine/test_egocentric_one_frame.py),
as the other one-frame kernels do (core/one_frame.py). So it is taken where one frame may differ by
that rounding (`one_frame.ENABLED`); the numpy fallback keeps the bake's own kernels, bit for bit.
The layout is refused (`OneFrameMapping.build` gives None: the bake's kernels then) where its
assumptions do not hold: mesh elements with other triangles on the two bodies (the bone-frame
fallback), a target or a palm with no element to map onto."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...body import skeleton as sk
from ...body.skeleton import JOINT_INDEX as JI
from ...core.transforms import EPS
from .graph import GRAPH_BONES, kinematic_path, own_chain_elements
from .mapping import SUPPORT_BLEND
from .projection import FACTOR_BLEND, PENETRATION_TOLERANCE
from .surface import SurfacePoser
from .weights import MIN_DISTANCE

F32 = np.float32
_BONE_HEADS = np.array([JI[sk.BONE_BY_NAME[b].head] for b in GRAPH_BONES], int)
_BONE_TAILS = np.array([JI[sk.BONE_BY_NAME[b].tail] for b in GRAPH_BONES], int)
_ANKLES = np.array([JI[f"ankle_{s}"] for s in sk.SIDES], int)
_YZX, _ZXY = np.array([1, 2, 0]), np.array([2, 0, 1])  # components rolled (a cross product's)


@dataclass
class FlatSurface:
    """One frame of the user's posed surface, float32, components first: the capsules' heads and
    axes, then the spheres' centres and a zero axis (3, C + S), their frames (3, 3, C + S) (R_ij
    at [i, j]), each triangle's rows `_triangles` reads (`tri`: its first corner, both edges from
    it, their three dot products, its unit normal), every canonical joint (3, J).

    Decision (speed, the same values): what Ericson's closest point reads of a triangle alone (its
    edges and their dot products, float32 as each pair computed them) is computed once a triangle
    here and gathered with its corner and normal in one take, not again for each of its pairs.

    Decision: a sphere is a capsule of no length (t = 0, |sin| = 1: the sphere's projection and
    factor), whose frame's columns are rolled (y, z, x) so that its first column is the bone's +Y,
    the sphere's fallback direction at its centre; its direction is kept and re-posed in that
    rolled frame on both bodies (R' P (R P)^T = R' R^T): one kernel for both, and fewer calls
    (the avatar's columns are gathered in that order: `OneFrameMapping._avatar_gathers`)."""

    cap_head: np.ndarray
    cap_axis: np.ndarray
    cap_rot: np.ndarray
    tri: np.ndarray  # (15, T) per triangle: corner a, ab, ac (3 rows each), |ab|², |ac|², ab·ac, unit normal
    joints: np.ndarray


def pose_flat(poser: SurfacePoser, joints: np.ndarray, frames: np.ndarray) -> FlatSurface:
    """`SurfacePoser.pose` of one frame (joints (J, 3), bone frames (B, 3, 3), float64), as a
    FlatSurface: posed in float64 as the poser does, then converted once. (The user's: the
    avatar's side is gathered from its pose for each map, `OneFrameMapping._avatar_points`.)"""
    head, tail, cap_rot, sph_center, sph_rot = poser.placed(joints, frames)
    C, S = len(head), len(sph_center)
    # the points' vectors and the joints in one conversion, components first
    vecs = np.concatenate([head, sph_center, tail, sph_center, joints]).T.astype(F32, order="C")
    rots = np.concatenate([cap_rot, sph_rot.take(_YZX, axis=2)]).transpose(1, 2, 0).astype(F32, order="C")
    if poser.point_count:
        pts = joints.take(poser.pad_heads, axis=0)[:, :, None] + np.matmul(frames.take(poser.pad_bones, axis=0),
                                                                          poser.pad_local)  # (G, 3, K)
        tri = pts.transpose(1, 0, 2).reshape(3, -1).take(poser.pad_tri.T, axis=1)  # (3, corner, T), float64
        e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
        n = e1.take(_YZX, axis=0) * e2.take(_ZXY, axis=0) - e1.take(_ZXY, axis=0) * e2.take(_YZX, axis=0)  # cross
        nn = np.sqrt(dot3(n, n))
        tri = tri.astype(F32)
        pack = np.empty((15, tri.shape[-1]), F32)
        pack[0:3] = tri[:, 0]
        edges = pack[3:9].reshape(2, 3, -1)  # ab, ac
        np.subtract(tri[:, 1:].swapaxes(0, 1), tri[:, 0], out=edges)
        np.add.reduce(edges * edges, axis=1, out=pack[9:11])  # |ab|², |ac|² (dot3's order)
        np.add.reduce(edges[0] * edges[1], axis=0, out=pack[11])  # ab·ac
        pack[12:15] = np.divide(n, nn, out=np.zeros_like(n), where=nn > 1e-15)
    else:
        pack = np.zeros((15, 0), F32)
    n = C + S
    head = vecs[:, :n]
    return FlatSurface(head, vecs[:, n:2 * n] - head, rots, pack, vecs[:, 2 * n:])


def dot3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """`projection.dot3` (components first, (3, N)) in two numpy calls: the reduction over the first
    axis adds the three products in the same order, a0 b0 + a1 b1 + a2 b2 (dot3 makes eleven
    calls: six subscripts, three products, two sums)."""
    return np.add.reduce(a * b, axis=0)


def _apply_t(rot: np.ndarray, v: np.ndarray) -> np.ndarray:
    """R^T v (world -> bone frame)."""
    return np.add.reduce(rot * v[:, None], axis=0)


def _unit(w: np.ndarray, fallback) -> tuple[np.ndarray, np.ndarray]:
    """(unit w, |w|) over components-first vectors (3, N); `fallback` where |w| <= EPS."""
    n = np.sqrt(dot3(w, w))
    ok = n > EPS
    if ok.all():
        return w / n, n
    return np.where(ok, w / np.where(ok, n, 1.0), fallback), n


class _Pairs:
    """The (point, element) pairs of a few points on a surface layout, each point on the elements
    it is not excluded from, and each mesh pair's triangles (consecutive). Pairs of a type are
    in point order: capsule and sphere pairs (FlatSurface), mesh pairs; every flat array over all
    pairs takes them as two stages, the first `first` points' then the others' (`join`), each a
    type's then the other's, so that a stage is one slice (`stages`: (every pair's, the capsules',
    the meshes') slices of each)."""

    def __init__(self, excluded: list[frozenset], ids: list[str], counts: tuple, mesh_slices: list, first: int = 0):
        C, S, M = counts
        kept = [[e for e in range(len(ids)) if ids[e] not in ex] for ex in excluded]
        self.empty = any(not k for k in kept)
        by_type = ([(p, e) for p, k in enumerate(kept) for e in k if e < C + S],
                   [(p, e - C - S) for p, k in enumerate(kept) for e in k if e >= C + S])
        (self.cap_p, self.cap_e), (self.mesh_p, self.mesh_m) = (
            (np.array([a for a, _ in rows], int), np.array([b for _, b in rows], int)) for rows in by_type)
        cl, ml = int(np.sum(self.cap_p < first)), int(np.sum(self.mesh_p < first))
        nc, nm = len(self.cap_p), len(self.mesh_p)
        self.cut = cl, ml
        self.stages = ((slice(0, cl + ml), slice(0, cl), slice(0, ml)),
                       (slice(cl + ml, nc + nm), slice(cl, nc), slice(ml, nm)))
        self.element = self.join(self.cap_e, self.mesh_m + C + S)  # each pair's element
        self.point = self.join(self.cap_p, self.mesh_p)  # each pair's point
        # the triangles of each mesh pair, consecutive: (point, triangle), each one's mesh pair
        tri_p, tri_t, tri_of, starts = [], [], [], []
        for k, (p, m) in enumerate(zip(self.mesh_p, self.mesh_m)):
            a, b = mesh_slices[m]
            starts.append(len(tri_t))
            tri_p += [p] * (b - a)
            tri_t += range(a, b)
            tri_of += [k] * (b - a)
        self.tri_p, self.tri_t, self.tri_of = (np.array(x, int) for x in (tri_p, tri_t, tri_of))
        self.tri_starts = np.array(starts, int)
        # each mesh pair's triangles as a row, padded with the index of a +inf (argmin's rows)
        width = max((b - a for a, b in mesh_slices), default=0)
        self.tri_rows = np.full((len(starts), width), len(tri_t), int)
        for k, s in enumerate(starts):
            n = (len(tri_t) if k + 1 == len(starts) else starts[k + 1]) - s
            self.tri_rows[k, :n] = np.arange(s, s + n)

    def join(self, caps: np.ndarray, meshes: np.ndarray) -> np.ndarray:
        """Capsule pairs' and mesh pairs' values (..., Nc), (..., Nm) in every pair's order."""
        cl, ml = self.cut
        return np.concatenate([caps[..., :cl], meshes[..., :ml], caps[..., cl:], meshes[..., ml:]], axis=-1)


def _capsules(pr: _Pairs, pts: np.ndarray, s: FlatSurface, radius: np.ndarray):
    """The capsule (and sphere) pairs' t (axial fraction), unit direction from the axis d and its
    norm n, the radius there r, the axis ab, |ab|^2 and the frames (`projection.project_components`'
    capsule and sphere parts)."""
    p = pts.take(pr.cap_p, axis=1)
    a, ab = s.cap_head.take(pr.cap_e, axis=1), s.cap_axis.take(pr.cap_e, axis=1)
    rot = s.cap_rot.take(pr.cap_e, axis=2)
    abab = np.maximum(dot3(ab, ab), 1e-24)
    ap = p - a
    t = np.minimum(np.maximum(dot3(ap, ab) / abab, 0.0), 1.0)
    d, n = _unit(ap - t * ab, rot[:, 0])  # on the axis: the bone's +X
    r = radius[0] + t * radius[1]
    return t, d, n, r, ab, abab, rot


def _triangles(pr: _Pairs, pts: np.ndarray, s: FlatSurface):
    """Every triangle pair's barycentric (v, w) of its closest point, p - x, |p - x|^2 and its
    triangle's unit normal."""
    tri = s.tri.take(pr.tri_t, axis=1)  # (15, N): FlatSurface.tri's rows
    tab, tac = tri[3:6], tri[6:9]
    tap = pts.take(pr.tri_p, axis=1) - tri[0:3]
    bv, bw = _closest_on_triangles(tap, tri[3:9].reshape(2, 3, -1), tri[9], tri[10], tri[11])
    tv = tap - bv * tab - bw * tac
    return bv, bw, tv, dot3(tv, tv), tri[12:15]


# Ericson's regions (`projection.closest_on_triangles`), one frame: each region's tests as rows
# `x <= 0` of _closest_on_triangles' `terms` (d1, d2, d3, d6, va, vb, vc, d4 - d3, d5 - d6, then
# the same negated (x >= 0), then a zero: a test that holds), in Ericson's order A, B, AB, C, AC,
# BC; the first region that holds wins (his early returns), else the inside.
_REGION_TESTS = np.array([[0, 11, 6, 12, 5, 4],  # A: d1 <= 0, B: d3 >= 0, AB: vc <= 0, C: d6 >= 0, ...
                          [1, 7, 9, 8, 10, 16],  # A: d2 <= 0, B: d4 - d3 <= 0, AB: d1 >= 0, ...
                          [18, 18, 2, 18, 3, 17]]).reshape(-1)  # AB: d3 <= 0, AC: d6 <= 0, BC: d5 - d6 >= 0
# each region's (v, w) as rows of `vals`: 0 the inside's v, 1 its w, 2 e_ab, 3 e_ac, 4 e_bc,
# 5 1 - e_bc, 6 zero, 7 one
_REGION_VALUES = np.array([[6, 7, 2, 6, 6, 5, 0],
                           [6, 6, 6, 7, 3, 4, 1]])
_DIV_ROWS = np.array([5, 6, 0, 1, 7])  # the divisions' numerators: vb, vc, d1, d2, d4 - d3


def _closest_on_triangles(ap, edges, abab, acac, abac):
    """`projection.closest_on_triangles` of one frame's triangle pairs (3, N), the same values
    (the same float32 operations on each pair, each region's the same), from `edges` (ab, ac)
    (2, 3, N) and the triangles' dot products (FlatSurface.tri): in about 30 numpy calls, not
    60 (each region's test three calls and two putmasks there): every region's tests in one
    comparison, the first that holds by one argmax."""
    N = ap.shape[1]
    terms = np.empty((19, N), F32)  # d1, d2, d3, d6, va, vb, vc, d4 - d3, d5 - d6, the same negated, 0
    terms[18] = 0.0  # (np.zeros of the whole costs more than its rows written)
    d12 = terms[0:2]
    np.add.reduce(edges * ap, axis=1, out=d12)  # ab·ap, ac·ap
    d1, d2, d3, d6 = terms[0], terms[1], terms[2], terms[3]
    np.subtract(d1, abab, out=d3)
    np.subtract(d2, acac, out=d6)
    d4, d5 = d2 - abac, d1 - abac
    np.subtract(d3 * d6, d5 * d4, out=terms[4])  # va
    np.subtract(d5 * d2, d1 * d6, out=terms[5])  # vb
    np.subtract(d1 * d4, d3 * d2, out=terms[6])  # vc
    np.subtract(d4, d3, out=terms[7])
    np.subtract(d5, d6, out=terms[8])
    np.negative(terms[0:9], out=terms[9:18])
    tests = terms.take(_REGION_TESTS, axis=0) <= 0
    holds = np.ones((N, 7), bool)  # (pair, region): argmax over a row takes the first that holds
    cond = holds[:, :6].T
    np.logical_and(tests[0:6], tests[6:12], out=cond)
    cond &= tests[12:18]
    # the divisions (safe_divide's: num / den, den 1 where it is 0): vb, vc by va + vb + vc,
    # d1 by d1 - d3, d2 by d2 - d6, d4 - d3 by (d4 - d3) + (d5 - d6)
    den = np.empty((5, N), F32)
    np.add(terms[4], terms[5], out=den[0])
    den[0] += terms[6]
    den[1] = den[0]
    np.subtract(d12, terms[2:4], out=den[2:4])
    np.add(terms[7], terms[8], out=den[4])
    vals = np.empty((8, N), F32)
    np.divide(terms.take(_DIV_ROWS, axis=0), den if den.all() else np.where(den != 0, den, F32(1.0)), out=vals[:5])
    np.subtract(F32(1.0), vals[4], out=vals[5])
    vals[6] = 0.0
    vals[7] = 1.0
    pick = _REGION_VALUES.take(holds.argmax(axis=1), axis=1)
    pick *= N
    pick += np.arange(N)
    bv, bw = vals.take(pick)
    return bv, bw


@dataclass
class StageUser:
    """What `map` reads of one stage's pairs (`_Pairs.stages`: one slice of every pair's arrays).
    Decision (speed): float64 where `map` computes in float64 (cast once here, not in each map:
    a ufunc over mixed dtypes casts through buffers, several times a same-dtype one's cost)."""

    cap_coef: np.ndarray  # (5, Nc) capsule pairs' x' as a sum of the avatar's pose (`_avatar_points`)
    mesh_rows: np.ndarray  # (12, Nm) the columns of the pose the mesh pairs' x' sums (closest triangle's)
    mesh_coef: np.ndarray  # (12, Nm) and their coefficients
    v: np.ndarray  # (3, N) p - x
    weights: np.ndarray  # (3, N) λ, λ, λg: each pair's weight in the x, y and z sums
    vhat: np.ndarray  # (3, N)
    dots: np.ndarray  # (NB, N) |v̂·b_k| of each chain's bones (0: not on its path)
    tau: np.ndarray  # (N,) τ
    tau_ok: np.ndarray | None  # τ > EPS (None: every τ is)


@dataclass
class FrameUser:
    """The user's side of one frame (OneFrameMapping.prepare): what `map` reads for each avatar pose."""

    pts: np.ndarray  # (3, P) the targets
    stages: list  # [StageUser] per stage
    none_xy: np.ndarray | None  # (2, P) the user's x, y of the targets with no element of weight, else 0 (None: none)
    lam_gf: np.ndarray  # (P,) the floor's λg
    ulen: np.ndarray  # (NB,) the user's bone lengths
    ulen_ok: np.ndarray | None  # ulen > EPS (None: every length is)
    floor_uz: np.ndarray  # (2P, NB) |b_z| of the user's bones on each ankle's path to each target (0: off it),
    # by stage: each stage's targets from the left ankle, then from the right (OneFrameMapping.floor_mask)
    floor_tau: np.ndarray  # (2P,)
    floor_ok: np.ndarray | None  # floor_tau > EPS (None: every one is)
    w_left: float


def _if_any_not(ok: np.ndarray) -> np.ndarray | None:
    """`ok`, or None where it holds everywhere (`map` then divides without a mask)."""
    return None if ok.all() else ok


def _ratio(a: np.ndarray, b: np.ndarray, ok: np.ndarray | None) -> np.ndarray:
    """a / b, 1 where not `ok` (None: a / b everywhere; the same values, without `where`'s masked loop)."""
    return a / b if ok is None else np.divide(a, b, out=np.ones_like(a), where=ok)


class OneFrameMapping:
    """One frame's egocentric mapping of `names` (canonical joints) through the surfaces posed by
    `user_poser` and `avatar_poser` (the same element ids), each target not mapped on its own
    chain's elements nor on `exclude`'s (per target, element ids); `palms`: the sides whose hand
    is mapped through its palm's centre where that is near the body (`prepare`). Made by `build`:
    None where the layout does not fit (module docstring).

    Decision (the palms, DESIGN.md §5 "The hand's point"): each palm centre is one more point of the
    same pass as the targets, on its own pairs (the elements not on its own arm and hand: its
    wrist target's), whose nearest distance gives the hand's palm weight w. Where w is 0 or 1 (a
    hand away from the body or on it: most frames) the wrist target's point is the wrist or the
    palm centre, both already projected: the other's pairs get weight 0, and the mapping is the
    one it would be for that point alone (adding zeros leaves each sum as it was). Between them
    the point is neither, and the pass runs again with the wrists moved. One pass, not two: a
    pass is ~150 numpy calls whatever its size."""

    @classmethod
    def build(cls, names, user_poser: SurfacePoser, avatar_poser: SurfacePoser, exclude=None, palms=(), first=0):
        if user_poser.element_ids != avatar_poser.element_ids or user_poser.mesh_slices != avatar_poser.mesh_slices:
            return None
        fm = cls(names, user_poser, avatar_poser, exclude, palms, first)
        return None if fm.pairs.empty else fm

    def __init__(self, names, user_poser: SurfacePoser, avatar_poser: SurfacePoser, exclude=None, palms=(),
                 first=0):
        self.names = list(names)
        self.posers = user_poser, avatar_poser
        ids = list(user_poser.element_ids)
        layout = (user_poser.cap_radius.shape[0], user_poser.sph_radius.shape[0], len(user_poser.mesh_slices))
        excluded = [own_chain_elements(n) | (frozenset(exclude[i]) if exclude else frozenset())
                    for i, n in enumerate(self.names)]
        P, H = len(self.names), len(palms)
        self.wrist_rows = np.array([self.names.index(f"wrist_{s}") for s in palms], int)
        # the points: the targets, then the palm centres (each on its own arm's exclusions)
        self.pairs = pr = _Pairs(excluded + [own_chain_elements(f"wrist_{s}") for s in palms], ids, layout,
                                 user_poser.mesh_slices, first)
        self.row = np.concatenate([np.arange(P), self.wrist_rows]).take(pr.point)  # each pair's target
        # the palms' pairs grouped by palm (np.minimum.reduceat's segments), and each pair's weight
        # 1 or 0 for each case: {hands on their palm (bools): weights}, None: the pass with moved wrists
        by_type = np.concatenate([pr.cap_p, pr.mesh_p])  # (_palm_near's values are by type)
        palm_pairs = np.flatnonzero(by_type >= P)
        self.palm_order = palm_pairs[np.argsort(by_type[palm_pairs], kind="stable")]
        self.palm_starts = np.searchsorted(by_type[self.palm_order], P + np.arange(H))
        self.active = {None: (pr.point < P).astype(F32)}
        for case in np.ndindex(*(2,) * H):
            on = np.array(case, bool)
            off = np.isin(pr.point, self.wrist_rows[on]) | np.isin(pr.point, P + np.flatnonzero(~on))
            self.active[tuple(on)] = (~off).astype(F32)
        # capsule and sphere radii per pair (at the head, tail - head), both bodies
        radii = [np.concatenate([ps.cap_radius, np.repeat(ps.sph_radius[:, None], 2, axis=1)]) for ps in self.posers]
        self.radius = [np.stack([r[pr.cap_e, 0], r[pr.cap_e, 1] - r[pr.cap_e, 0]]).astype(F32) for r in radii]
        self._avatar_gathers(avatar_poser)
        # each pair's chain: its element's root joint, and the (pair, bone) entries of the path from
        # it to the target (eq. 2)
        # it to the target (eq. 2), as a (pair, bone) mask: a chain's sum over its bones is one row of
        # a product with every bone (a few thousand (pair, bone) entries gathered one by one cost
        # more than the dense product of every pair with every bone, ~20,000 multiply-adds)
        roots = list(user_poser.element_roots)
        self.root_joint = np.array([JI[roots[e]] for e in pr.element], int)
        self.path_mask = np.zeros((len(GRAPH_BONES), len(pr.point)), F32)  # (bone, pair): rows are contiguous
        for k, (r, e) in enumerate(zip(self.row, pr.element)):
            self.path_mask[list(kinematic_path(roots[e], self.names[r])), k] = 1.0
        # the floor's paths: from each ankle to each target, stage by stage (each stage's rows one
        # slice: its targets from the left ankle, then from the right)
        self.stage_targets = [slice(0, first), slice(first, P)]
        order = [(side, p) for st in self.stage_targets for side in range(2) for p in range(st.start, st.stop)]
        self.floor_mask = np.zeros((2 * P, len(GRAPH_BONES)), F32)
        for k, (side, p) in enumerate(order):
            self.floor_mask[k, list(kinematic_path(f"ankle_{sk.SIDES[side]}", self.names[p]))] = 1.0
        self.floor_side = np.array([side for side, _ in order], int)
        # each stage's x, y, z sums' bins and its pairs' root joints
        self.sums = [np.concatenate([self.row[a], self.row[a] + P, self.row[a] + 2 * P]) for a, _, _ in pr.stages]
        self.stage_root = [self.root_joint[a] for a, _, _ in pr.stages]
        self.stage_cap_rows = [np.ascontiguousarray(self.cap_rows[:, c]) for _, c, _ in pr.stages]

    # --- the surfaces ---------------------------------------------------------------------------

    def user_surface(self, joints: np.ndarray, frames: np.ndarray) -> FlatSurface:
        return pose_flat(self.posers[0], joints, frames)

    def _avatar_gathers(self, ap: SurfacePoser) -> None:
        """What `map` gathers of the avatar's pose for each pair's re-posed x' (Decision in
        `_avatar_points`): columns of G = (the joints (3, J), then each bone frame's columns
        (3, 3B)). A capsule pair: its head and tail joints, its bone's three columns (a sphere's
        rolled, FlatSurface) (5, Nc), and its axis offsets in those columns (head, tail - head:
        (2, 3, Nc)). A triangle: per corner its bone's head joint and three columns (12, T), and
        the corner's offset in them (corner, component, T)."""
        pr, C, J = self.pairs, len(ap.cap_bone), len(sk.JOINTS)
        e = pr.cap_e
        cap, sph = e < C, np.maximum(e - C, 0)
        ce = np.minimum(e, max(C - 1, 0))
        if C:
            head, tail, bone = ap.cap_ends[0][ce], ap.cap_ends[1][ce], ap.cap_bone[ce]
            off = ap.cap_off[ce].transpose(1, 2, 0)  # (2, 3, Nc): head, tail
        else:
            head = tail = bone = np.zeros(len(e), int)
            off = np.zeros((2, 3, len(e)))
        if len(ap.sph_bone):
            s_head, s_bone = ap.sph_head[sph], ap.sph_bone[sph]
            s_off = ap.sph_local[sph].T.take(_YZX, axis=0)  # in the rolled frame
        else:
            s_head = s_bone = np.zeros(len(e), int)
            s_off = np.zeros((3, len(e)))
        head, tail = np.where(cap, head, s_head), np.where(cap, tail, s_head)
        cols = 3 * np.where(cap, bone, s_bone)[:, None] + np.where(cap[:, None], np.arange(3), _YZX)
        self.cap_rows = np.concatenate([head[None], tail[None], J + cols.T])  # (5, Nc)
        off0 = np.where(cap, off[0], s_off)
        self.cap_off = np.stack([off0, np.where(cap, off[1], s_off) - off0])  # (2, 3, Nc)
        K = ap.pad_local.shape[-1] if len(ap.pad_local) else 1
        q = ap.pad_tri  # (T, 3) each corner's point, g K + k
        g, k = q // K, q % K
        b = ap.pad_bones[g] if len(ap.pad_bones) else np.zeros_like(g)
        rows = np.concatenate([(ap.pad_heads[g] if len(ap.pad_heads) else g)[..., None],
                               J + 3 * b[..., None] + np.arange(3)], axis=-1)  # (T, 3, 4)
        self.tri_rows = np.ascontiguousarray(rows.reshape(len(q), 12).T)  # (12, T)
        local = ap.pad_local[g, :, k] if len(ap.pad_local) else np.zeros(q.shape + (3,))  # (T, corner, 3)
        self.tri_local = np.ascontiguousarray(local.transpose(1, 2, 0))  # (corner, 3, T)

    def _avatar_points(self, u: StageUser, g: np.ndarray, stage: int) -> np.ndarray:
        """(3, N) the re-posed x' of `stage`'s pairs (`projection.repose_components`) on the avatar
        posed as canonical joints (J, 3) and bone frames (B, 3, 3), float64, given as `g`: the
        joints, then each frame's columns, components first (3, J + 3B) (`map`).

        Decision (speed): x' is linear in the pose, a sum of joints and bone-frame columns with the
        pair's own coefficients (a capsule's 1 - t, t and its offset plus rho times the direction;
        a triangle's barycentric weights and its corners' offsets), found once on the user's side
        (`prepare`). So each map gathers those rows of the pose and sums them: two gathers, not
        the avatar's whole surface posed for each map (25 numpy calls) and re-posed pair by pair.
        (One gather of every term and a bincount of each pair's: 40 % more instructions, measured:
        a gather or a bincount costs per item, ~10-30 instructions, not per call.)"""
        cap = g.take(self.stage_cap_rows[stage], axis=1)  # (3, 5, Nc): (component, term, pair)
        cap *= u.cap_coef
        mesh = g.take(u.mesh_rows, axis=1)  # (3, 12, Nm)
        mesh *= u.mesh_coef
        return np.concatenate([np.add.reduce(cap, axis=1), np.add.reduce(mesh, axis=1)], axis=1)

    # --- the palms ------------------------------------------------------------------------------

    def _palm_near(self, n: np.ndarray, r: np.ndarray, td: np.ndarray) -> np.ndarray:
        """(H,) each palm centre's distance to the nearest element it is paired with (`project`'s
        |v|: |n - r| on a capsule or the sphere, the closest triangle's on a mesh), from a pass's
        capsule pairs' n and r and mesh pairs' closest distance td."""
        every = np.concatenate([np.abs(n - r), td])
        return np.minimum.reduceat(every.take(self.palm_order), self.palm_starts).astype(float)

    # --- the user's side ------------------------------------------------------------------------

    def prepare(self, us: FlatSurface, pts: np.ndarray, bones: np.ndarray, levers: np.ndarray,
                palm_weight) -> tuple[FrameUser, np.ndarray]:
        """The user's side of one frame: targets `pts` (P, 3) and the user's GRAPH_BONES vectors
        `bones` (NB, 3) (tail - head) on the user's surface `us` (`prepare_targets`' work), each
        wrist target moved by w times its hand's `levers` (H, 3) (wrist to palm centre), w the
        palm's `palm_weight` (of the palms' (H,) nearest distances, (H,) in [0, 1]); and w."""
        pr, P = self.pairs, len(self.names)
        palms = pts.take(self.wrist_rows, axis=0) + levers
        p_all = np.concatenate([pts, palms]).T.astype(F32, order="C")
        # Projections (projection.project_components)
        t, d, n, r, ab, abab, rot = _capsules(pr, p_all, us, self.radius[0])
        mesh_v, tri, bary, mesh_factor, td = self._meshes(p_all, us)
        w = np.asarray(palm_weight(self._palm_near(n, r, td)), float).reshape(-1) if len(levers) else np.zeros(0)
        # (a hand's weight is 0 or 1 in most frames: their case in Python, the wrists moved only
        # where a weight is not 0)
        ws = w.tolist()
        eff = pts
        if any(ws):
            eff = pts.copy()
            eff[self.wrist_rows] += w[:, None] * levers
        case = tuple(x == 1.0 for x in ws) if all(x == 0.0 or x == 1.0 for x in ws) else None
        if case is None:  # a hand between wrist and palm: the pass again, the wrists moved (Decision)
            p_all = np.concatenate([eff, palms]).T.astype(F32, order="C")
            t, d, n, r, ab, abab, rot = _capsules(pr, p_all, us, self.radius[0])
            mesh_v, tri, bary, mesh_factor, _ = self._meshes(p_all, us)
        active = self.active[case]
        p3 = eff.T.astype(F32, order="C")
        cap_v = (n - r) * d
        cos_ax = dot3(d, ab) / np.sqrt(abab)
        cap_factor = np.sqrt(np.minimum(np.maximum(1.0 - cos_ax * cos_ax, 0.0), 1.0))
        cap_dir = _apply_t(rot, d)
        v = pr.join(cap_v, mesh_v)
        x = p_all.take(pr.point, axis=1) - v
        dist2 = dot3(v, v)
        factor = pr.join(cap_factor, mesh_factor)
        # Weights (weights.raw_weights, normalise_weights), each target's sums over its own pairs
        lam_raw = factor / np.maximum(dist2, MIN_DISTANCE ** 2) * active  # (the other point's pairs: 0)
        h = p3[2].astype(float)
        floor_raw = 1.0 / np.maximum(h * h, MIN_DISTANCE ** 2)
        s = np.bincount(self.row, lam_raw, minlength=P)
        sg = s + floor_raw
        none = s <= 0
        weights = np.empty((3, len(lam_raw)))  # (np.stack's own Python costs more than its copies)
        np.divide(lam_raw, np.where(none, 1.0, s).take(self.row), out=weights[0])
        weights[1] = weights[0]
        np.divide(lam_raw, sg.take(self.row), out=weights[2])
        # τ (eq. 2): Σ_k |v̂·b_k| over the chain's bones + |v̂·(x - r)|
        vhat, _ = _unit(v, 0.0)
        ub = bones.T.astype(F32, order="C")
        # (einsum's own loops, not a BLAS product: a BLAS kernel's last bit follows the operands'
        # alignment, and a worker process must give this process's pose bit for bit; einsum's
        # loops take half the instructions of a product and a sum over a (3, NB, N) array; the
        # (pair, bone) entries of the chains alone, gathered, take more: a gather costs per item)
        dots = np.abs(np.einsum("ck,cn->kn", ub, vhat))  # (NB, N) every bone against every v̂
        dots *= self.path_mask  # each chain's own bones
        tau = np.add.reduce(dots, axis=0) + np.abs(dot3(vhat, x - us.joints.take(self.root_joint, axis=1)))
        # the floor's user side (mapping._floor_user): both ankles' paths
        ankles = us.joints[2].take(_ANKLES).astype(float)
        floor_uz = self.floor_mask * np.abs(ub[2])  # (exact: the mask's ones and zeros)
        floor_tau = np.add.reduce(floor_uz, axis=1) + np.abs(ankles).take(self.floor_side)
        w_left = 0.5 + 0.5 * np.tanh((ankles[1] - ankles[0]) / SUPPORT_BLEND)
        stages = self._stage_sides(t, cap_dir, tri, bary, v, weights, vhat, dots, tau)
        ulen = np.sqrt(dot3(ub, ub)).astype(float)
        none_xy = np.where(none, p3[:2], 0.0) if none.any() else None
        return FrameUser(p3, stages, none_xy, floor_raw / sg, ulen, _if_any_not(ulen > EPS), floor_uz.astype(float),
                         floor_tau, _if_any_not(floor_tau > EPS), float(w_left)), w

    def _stage_sides(self, t, cap_dir, tri, bary, v, weights, vhat, dots, tau) -> list:
        """Each stage's `StageUser` from the user's side of every pair (`prepare`)."""
        pr = self.pairs
        # x' on the avatar (projection.repose_components) as sums of its pose (_avatar_points):
        # a capsule's head (1 - t), tail t, and in its bone's columns its offset there plus ρ' d
        cap_coef = np.empty((5, len(t)))
        cap_coef[0] = 1.0 - t
        cap_coef[1] = t
        # (its offset plus ρ' d, in place: off0 + t off1, then ρ' = r0' + t Δr' in float32 times d)
        rho = self.radius[1][1] * t
        rho += self.radius[1][0]
        rho_d = cap_dir * rho
        np.multiply(self.cap_off[1], t, out=cap_coef[2:])
        cap_coef[2:] += self.cap_off[0]
        cap_coef[2:] += rho_d
        # a triangle's corners: each its bone's head and columns, by the barycentric weight
        mesh_coef = np.empty((3, 4, len(tri)))  # (corner, head and columns, pair)
        mesh_coef[:, 0] = bary
        np.multiply(self.tri_local.take(tri, axis=2), bary[:, None], out=mesh_coef[:, 1:])
        mesh_coef = mesh_coef.reshape(12, -1)
        mesh_rows = self.tri_rows.take(tri, axis=1)  # (12, Nm)
        v64, vhat64, tau64, tau_ok = v.astype(float), vhat.astype(float), tau.astype(float), _if_any_not(tau > EPS)
        # (each stage's dots contiguous, float64: einsum's loops over them take a quarter of its
        # loops casting a strided float32 slice, measured)
        stages = [StageUser(cap_coef[:, c], mesh_rows[:, m], mesh_coef[:, m], v64[:, a], weights[:, a], vhat64[:, a],
                            dots[:, a].astype(float), tau64[a], None if tau_ok is None else tau_ok[a])
                  for a, c, m in pr.stages]
        return stages

    def _meshes(self, p3: np.ndarray, us: FlatSurface):  # p3: every point (targets, palms)
        """The mesh pairs' p - x (3, Nm), closest triangle, its barycentric coordinates (3, Nm), the
        angular factor (the triangles' own, blended by how near each is to the closest) and the
        closest triangle's distance."""
        pr = self.pairs
        if not len(pr.tri_starts):
            empty = np.zeros((3, 0), F32)
            return empty, np.zeros(0, int), empty, np.zeros(0, F32), np.zeros(0, F32)
        bv, bw, tv, td2, normal = _triangles(pr, p3, us)
        sel = np.concatenate([td2, np.full(1, np.inf, td2.dtype)]).take(pr.tri_rows).argmin(axis=1) + pr.tri_starts
        mesh_v = tv.take(sel, axis=1)
        bv_s, bw_s = bv.take(sel), bw.take(sel)
        w = tv + PENETRATION_TOLERANCE * normal
        wn = np.sqrt(dot3(w, w))
        tri_factor = np.maximum(np.divide(dot3(w, normal), wn, out=np.ones_like(wn), where=wn > EPS), 0.0)
        td = np.sqrt(td2)
        td_sel = td.take(sel)
        near = np.exp((td_sel.take(pr.tri_of) - td) * (1.0 / FACTOR_BLEND))
        mesh_factor = np.add.reduceat(near * tri_factor, pr.tri_starts) / np.add.reduceat(near, pr.tri_starts)
        return mesh_v, pr.tri_t.take(sel), np.stack([1.0 - bv_s - bw_s, bv_s, bw_s]), mesh_factor, td_sel

    # --- the avatar's side ----------------------------------------------------------------------

    def map(self, u: FrameUser, joints: np.ndarray, frames: np.ndarray, stage: int) -> np.ndarray:
        """(P, 3) float64: the targets of `stage` (0: the first `first`, 1: the others; the rest
        of the rows are not) mapped onto the avatar posed as canonical joints (J, 3) and bone
        frames (B, 3, 3) (`PreparedTargets.map`): over that stage's pairs alone (one slice:
        _Pairs), each target's sums in the same order."""
        P = len(self.names)
        su = u.stages[stage]
        g = np.concatenate([joints.T, frames.transpose(1, 0, 2).reshape(3, -1)], axis=1)  # _avatar_points
        x_av = self._avatar_points(su, g, stage)  # x' re-posed
        # τ' = Σ_k |v̂·b_k| L'_k/L_k + |v̂·(x' - r')| (eq. 2)
        ab = joints.take(_BONE_TAILS, axis=0) - joints.take(_BONE_HEADS, axis=0)  # (NB, 3)
        lratio = _ratio(np.sqrt(np.add.reduce(ab * ab, axis=1)), u.ulen, u.ulen_ok)
        roots = g.take(self.stage_root[stage], axis=1)  # r' of each pair's chain
        tau_a = np.einsum("kn,k->n", su.dots, lratio) + np.abs(dot3(su.vhat, x_av - roots))
        est = x_av + su.v * _ratio(tau_a, su.tau, su.tau_ok)  # (3, N)
        est *= su.weights
        out = np.bincount(self.sums[stage], est.reshape(-1), minlength=3 * P).reshape(3, P)
        if u.none_xy is not None:  # no element with weight (a sum of zeros): the user's horizontal position
            out[:2] += u.none_xy
        # the floor: h' = h τ'/τ along the path from the supporting ankle, both feet blended (this
        # stage's targets alone: the floor's rows by stage, FrameUser.floor_uz)
        st = self.stage_targets[stage]
        Ps, rows = st.stop - st.start, slice(2 * st.start, 2 * st.stop)
        tfa = np.add.reduce(u.floor_uz[rows] * lratio, axis=1) + np.abs(joints[_ANKLES, 2]).repeat(Ps)
        ratios = _ratio(tfa, u.floor_tau[rows], None if u.floor_ok is None else u.floor_ok[rows])
        out[2, st] += u.pts[2, st] * (ratios[Ps:] + u.w_left * (ratios[:Ps] - ratios[Ps:])) * u.lam_gf[st]
        return out.T
