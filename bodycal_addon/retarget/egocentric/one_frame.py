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
from .projection import FACTOR_BLEND, PENETRATION_TOLERANCE, closest_on_triangles
from .surface import SurfacePoser
from .weights import MIN_DISTANCE

F32 = np.float32
_BONE_HEADS = np.array([JI[sk.BONE_BY_NAME[b].head] for b in GRAPH_BONES], int)
_BONE_TAILS = np.array([JI[sk.BONE_BY_NAME[b].tail] for b in GRAPH_BONES], int)
_ANKLES = np.array([JI[f"ankle_{s}"] for s in sk.SIDES], int)
_YZX, _ZXY = np.array([1, 2, 0]), np.array([2, 0, 1])  # components rolled (a cross product's)


@dataclass
class FlatSurface:
    """One frame of a posed surface, float32, components first: the capsules' heads and axes, then
    the spheres' centres and a zero axis (3, C + S), their frames (3, 3, C + S) (R_ij at [i, j]),
    the triangles' corners (3, 3, T) (component, corner, triangle), their unit normals (3, T)
    (None: not made), every canonical joint (3, J).

    Decision: a sphere is a capsule of no length (t = 0, |sin| = 1: the sphere's projection and
    factor), whose frame's columns are rolled (y, z, x) so that its first column is the bone's +Y,
    the sphere's fallback direction at its centre; its direction is kept and re-posed in that
    rolled frame on both bodies (R' P (R P)^T = R' R^T): one kernel for both, and fewer calls."""

    cap_head: np.ndarray
    cap_axis: np.ndarray
    cap_rot: np.ndarray
    tri: np.ndarray
    tri_normal: np.ndarray | None
    joints: np.ndarray


def pose_flat(poser: SurfacePoser, joints: np.ndarray, frames: np.ndarray, normals: bool) -> FlatSurface:
    """`SurfacePoser.pose` of one frame (joints (J, 3), bone frames (B, 3, 3), float64), as a
    FlatSurface: posed in float64 as the poser does, then converted once."""
    head, tail, cap_rot, sph_center, sph_rot = poser.placed(joints, frames)
    C, S = len(head), len(sph_center)
    # the points' vectors and the joints in one conversion, components first
    vecs = np.concatenate([head, sph_center, tail, sph_center, joints]).T.astype(F32, order="C")
    rots = np.concatenate([cap_rot, sph_rot.take(_YZX, axis=2)]).transpose(1, 2, 0).astype(F32, order="C")
    tri = tri_normal = None
    if poser.point_count:
        pts = joints.take(poser.pad_heads, axis=0)[:, :, None] + np.matmul(frames.take(poser.pad_bones, axis=0),
                                                                          poser.pad_local)  # (G, 3, K)
        tri = pts.transpose(1, 0, 2).reshape(3, -1).take(poser.pad_tri.T, axis=1)  # (3, corner, T), float64
        if normals:
            e1, e2 = tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
            n = e1.take(_YZX, axis=0) * e2.take(_ZXY, axis=0) - e1.take(_ZXY, axis=0) * e2.take(_YZX, axis=0)  # cross
            nn = np.sqrt(dot3(n, n))
            tri_normal = np.divide(n, nn, out=np.zeros_like(n), where=nn > 1e-15).astype(F32)
        tri = tri.astype(F32)
    else:
        tri = np.zeros((3, 3, 0), F32)
        tri_normal = np.zeros((3, 0), F32) if normals else None
    n = C + S
    head = vecs[:, :n]
    return FlatSurface(head, vecs[:, n:2 * n] - head, rots, tri, tri_normal, vecs[:, 2 * n:])


def dot3(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """`projection.dot3` (components first, (3, N)) in two numpy calls: the reduction over the first
    axis adds the three products in the same order, a0 b0 + a1 b1 + a2 b2 (dot3 makes eleven
    calls: six subscripts, three products, two sums)."""
    return np.add.reduce(a * b, axis=0)


def _apply(rot: np.ndarray, v: np.ndarray) -> np.ndarray:
    """R v for per-pair frames (3, 3, N) and vectors (3, N), in three numpy calls."""
    return np.add.reduce(rot * v[None], axis=1)


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
    """Every triangle pair's barycentric (v, w) of its closest point, p - x and |p - x|^2."""
    corners = s.tri.take(pr.tri_t, axis=2)  # (3, corner, N)
    ta = corners[:, 0]
    tab, tac, tap = corners[:, 1] - ta, corners[:, 2] - ta, pts.take(pr.tri_p, axis=1) - ta
    bv, bw = closest_on_triangles(tap, tab, tac, dot3)
    tv = tap - bv * tab - bw * tac
    return bv, bw, tv, dot3(tv, tv)


@dataclass
class FrameUser:
    """The user's side of one frame (OneOneFrameMapping.prepare): what `map` reads for each avatar pose."""

    pts: np.ndarray  # (3, P) the targets
    t: np.ndarray  # capsule pairs' axial fraction
    rho: np.ndarray  # the avatar's radius there
    cap_dir: np.ndarray  # (3, Nc) in the bone frame (a sphere's: its rolled frame)
    tri: np.ndarray  # mesh pairs' closest triangle
    bary: np.ndarray  # (3, Nm) its barycentric coordinates
    v: np.ndarray  # (3, N) p - x of every pair
    weights: np.ndarray  # (3, N) λ, λ, λg: each pair's weight in the x, y and z sums
    none: np.ndarray | None  # (P,) targets with no element of weight (None: there are none)
    lam_gf: np.ndarray  # (P,) the floor's λg
    vhat: np.ndarray  # (3, N)
    dots: np.ndarray  # (NB, N) |v̂·b_k| of each chain's bones (0: not on its path)
    tau: np.ndarray  # (N,) τ
    tau_ok: np.ndarray
    ulen: np.ndarray  # (NB,) the user's bone lengths
    floor_uz: np.ndarray  # (NB,) |b_z| of the user's bones
    floor_tau: np.ndarray  # (2P,)
    floor_ok: np.ndarray
    w_left: float


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
        # the floor's paths: from each ankle (left, then right) to each target
        self.floor_mask = np.zeros((2 * P, len(GRAPH_BONES)), F32)
        for side, s in enumerate(sk.SIDES):
            for p, n in enumerate(self.names):
                self.floor_mask[side * P + p, list(kinematic_path(f"ankle_{s}", n))] = 1.0
        # each stage's x, y, z sums' bins, its capsule pairs' elements and its pairs' root joints
        self.sums = [np.concatenate([self.row[a], self.row[a] + P, self.row[a] + 2 * P]) for a, _, _ in pr.stages]
        self.stage_cap_e = [pr.cap_e[c] for _, c, _ in pr.stages]
        self.stage_root = [self.root_joint[a] for a, _, _ in pr.stages]

    # --- the surfaces ---------------------------------------------------------------------------

    def user_surface(self, joints: np.ndarray, frames: np.ndarray) -> FlatSurface:
        return pose_flat(self.posers[0], joints, frames, normals=True)

    def avatar_surface(self, joints: np.ndarray, frames: np.ndarray) -> FlatSurface:
        return pose_flat(self.posers[1], joints, frames, normals=False)

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
        eff = pts.copy()
        eff[self.wrist_rows] += w[:, None] * levers
        on = w == 1.0
        case = tuple(on) if (on | (w == 0.0)).all() else None
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
        lam = lam_raw / np.where(none, 1.0, s).take(self.row)
        weights = np.stack([lam, lam, lam_raw / sg.take(self.row)])
        # τ (eq. 2): Σ_k |v̂·b_k| over the chain's bones + |v̂·(x - r)|
        vhat, _ = _unit(v, 0.0)
        ub = bones.T.astype(F32, order="C")
        # (einsum's own loops, not a BLAS product: a BLAS kernel's last bit follows the operands'
        # alignment, and a worker process must give this process's pose bit for bit; einsum's
        # loops take half the instructions of a product and a sum over a (3, NB, N) array)
        dots = np.abs(np.einsum("ck,cn->kn", ub, vhat))  # (NB, N) every bone against every v̂
        dots *= self.path_mask  # each chain's own bones
        tau = np.add.reduce(dots, axis=0) + np.abs(dot3(vhat, x - us.joints.take(self.root_joint, axis=1)))
        # the floor's user side (mapping._floor_user): both ankles' paths
        ankles = us.joints[2].take(_ANKLES).astype(float)
        uz = np.abs(ub[2])
        floor_tau = np.add.reduce(self.floor_mask * uz, axis=1) + np.abs(ankles).repeat(P)
        w_left = 0.5 + 0.5 * np.tanh((ankles[1] - ankles[0]) / SUPPORT_BLEND)
        return FrameUser(p3, t, self.radius[1][0] + t * self.radius[1][1], cap_dir, tri, bary, v,
                         weights, none if none.any() else None, floor_raw / sg, vhat, dots, tau, tau > EPS,
                         np.sqrt(dot3(ub, ub)), uz, floor_tau, floor_tau > EPS, float(w_left)), w

    def _meshes(self, p3: np.ndarray, us: FlatSurface):  # p3: every point (targets, palms)
        """The mesh pairs' p - x (3, Nm), closest triangle, its barycentric coordinates (3, Nm), the
        angular factor (the triangles' own, blended by how near each is to the closest) and the
        closest triangle's distance."""
        pr = self.pairs
        if not len(pr.tri_starts):
            empty = np.zeros((3, 0), F32)
            return empty, np.zeros(0, int), empty, np.zeros(0, F32), np.zeros(0, F32)
        bv, bw, tv, td2 = _triangles(pr, p3, us)
        sel = np.concatenate([td2, np.full(1, np.inf, td2.dtype)]).take(pr.tri_rows).argmin(axis=1) + pr.tri_starts
        mesh_v = tv.take(sel, axis=1)
        bv_s, bw_s = bv.take(sel), bw.take(sel)
        normal = us.tri_normal.take(pr.tri_t, axis=1)
        w = tv + PENETRATION_TOLERANCE * normal
        wn = np.sqrt(dot3(w, w))
        tri_factor = np.maximum(np.divide(dot3(w, normal), wn, out=np.ones_like(wn), where=wn > EPS), 0.0)
        td = np.sqrt(td2)
        td_sel = td.take(sel)
        near = np.exp((td_sel.take(pr.tri_of) - td) * (1.0 / FACTOR_BLEND))
        mesh_factor = np.add.reduceat(near * tri_factor, pr.tri_starts) / np.add.reduceat(near, pr.tri_starts)
        return mesh_v, pr.tri_t.take(sel), np.stack([1.0 - bv_s - bw_s, bv_s, bw_s]), mesh_factor, td_sel

    # --- the avatar's side ----------------------------------------------------------------------

    def map(self, u: FrameUser, av: FlatSurface, stage: int) -> np.ndarray:
        """(P, 3) float64: the targets of `stage` (0: the first `first`, 1: the others; the rest
        of the rows are not) mapped onto the avatar posed as `av` (`PreparedTargets.map`): over
        that stage's pairs alone (one slice: _Pairs), each target's sums in the same order."""
        P = len(self.names)
        a, c, m = self.pairs.stages[stage]
        # x' re-posed (projection.repose_components): capsule (and sphere), barycentric
        cap_e = self.stage_cap_e[stage]
        rot = av.cap_rot.take(cap_e, axis=2)
        cap = (av.cap_head.take(cap_e, axis=1) + u.t[c] * av.cap_axis.take(cap_e, axis=1)
               + u.rho[c] * _apply(rot, u.cap_dir[:, c]))
        corners = av.tri.take(u.tri[m], axis=2)  # (3, corner, Nm)
        bary = u.bary[:, m]
        mesh = bary[0] * corners[:, 0] + bary[1] * corners[:, 1] + bary[2] * corners[:, 2]
        x_av = np.concatenate([cap, mesh], axis=1)
        # τ' = Σ_k |v̂·b_k| L'_k/L_k + |v̂·(x' - r')| (eq. 2)
        j = av.joints
        ab = j.take(_BONE_TAILS, axis=1) - j.take(_BONE_HEADS, axis=1)
        lratio = np.divide(np.sqrt(dot3(ab, ab)), u.ulen, out=np.ones_like(u.ulen), where=u.ulen > EPS)
        tau_a = np.einsum("kn,k->n", u.dots[:, a], lratio) + np.abs(
            dot3(u.vhat[:, a], x_av - j.take(self.stage_root[stage], axis=1)))
        ratio = np.divide(tau_a, u.tau[a], out=np.ones_like(tau_a), where=u.tau_ok[a])
        est = x_av + u.v[:, a] * ratio  # (3, N)
        out = np.bincount(self.sums[stage], (est * u.weights[:, a]).reshape(-1), minlength=3 * P).reshape(3, P)
        if u.none is not None:  # no element with weight: the user's horizontal position
            out[:2] = np.where(u.none, u.pts[:2], out[:2])
        # the floor: h' = h τ'/τ along the path from the supporting ankle, both feet blended
        tfa = np.add.reduce(self.floor_mask * (u.floor_uz * lratio), axis=1) + np.abs(
            j[2].take(_ANKLES).astype(float)).repeat(P)
        ratios = np.divide(tfa, u.floor_tau, out=np.ones_like(tfa), where=u.floor_ok)
        out[2] += u.pts[2] * (ratios[P:] + u.w_left * (ratios[:P] - ratios[P:])) * u.lam_gf
        return out.T
