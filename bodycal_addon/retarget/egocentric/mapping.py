"""Planning and mapping: the retro-projection of Delahaye 2023, eq. 1, with the kinematic
normalisation of eq. 2 and the floor singularity, blocked over frames x targets x elements."""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ...body import skeleton as sk
from ...core.errors import BodyCalError
from ...core.transforms import EPS, unit_and_norm
from .graph import GRAPH_BONES, GRAPH_NODES, kinematic_path, own_chain_elements
from .projection import PENETRATION_TOLERANCE, ProjectionsCF, dot3, project_components, repose_components
from .surface import JointTable, PosedSurface
from .weights import normalise_weights, raw_weights

SUPPORT_BLEND = 0.02  # m: ankle height difference over which the supporting foot hands over (_map_block)

ZERO_BONE = len(GRAPH_BONES)  # a zero vector: the one entry of an empty path


@dataclass
class _Plan:
    exclude: np.ndarray  # (P, E)
    chain_pe: np.ndarray  # (N,) flat (target, element) index p * E + e of each chain, ascending
    dense: bool  # every pair has a chain (chain_pe is 0..P*E-1: no gather needed)
    chain_root: np.ndarray  # (N,) index into GRAPH_NODES of the element's root
    # Paths by position: with the chains in `order` (longest path first), the chains that have a
    # j-th bone are a prefix, and slot_bones[j] lists those j-th bones: a sum over every chain's
    # bones is a few prefix additions, with no gather of v̂ per bone.
    order: np.ndarray  # (N,)
    unorder: np.ndarray  # (N,) its inverse
    slot_bones: list[np.ndarray]
    # The same as one (L, N) table, each slot's row padded with ZERO_BONE (whose vector is zero):
    # a few frames sum every slot in one call (adding the padding's exact zeros changes no bit).
    slot_table: np.ndarray
    entry_bone: np.ndarray  # every GRAPH_BONES index used (for the joint check)
    floor_bone: list[np.ndarray]  # per side: entries of the paths ankle_s -> target
    floor_starts: list[np.ndarray]  # per side: (P,)
    # Both sides' entries one after the other, and their starts (2P,): one reduceat for both
    floor_both: tuple[np.ndarray, np.ndarray] | None = None
    # (E,) each element's root when every pair has a chain and every target's row of elements has
    # the same roots (a group's plan): the chains' roots broadcast over the targets, not gathered
    root_cols: np.ndarray | None = None


def _entries(paths):
    bones, starts = [], []
    for path in paths:
        starts.append(len(bones))
        bones += list(path) or [ZERO_BONE]
    return np.array(bones, int), np.array(starts, int)


@lru_cache(maxsize=64)
def _plan(target_names: tuple[str, ...], element_ids: tuple[str, ...], roots: tuple[str, ...]) -> _Plan:
    """Everything frame-independent: exclusions and kinematic paths as index arrays (Delahaye 2023,
    appendix C: "chains are pre-computed and stored so that the tree search is not performed in
    every frame"). Excluded (own-chain) pairs have no chain at all: their weight is zero."""
    P = len(target_names)
    return _row_plan(target_names, (element_ids,) * P, (roots,) * P,
                     tuple(own_chain_elements(n) for n in target_names))


@lru_cache(maxsize=64)
def _row_plan(target_names: tuple[str, ...], row_ids: tuple[tuple[str, ...], ...],
              row_roots: tuple[tuple[str, ...], ...], row_excluded: tuple[frozenset, ...]) -> _Plan:
    """`_plan` with each target's own elements (`row_ids`, as many per target) and roots, and the
    elements it excludes (`row_excluded`): several groups' targets side by side (_fused_groups)."""
    P, E = len(target_names), len(row_ids[0]) if row_ids else 0
    exclude = np.zeros((P, E), bool)
    pe, cr, paths = [], [], []
    for p, name in enumerate(target_names):
        for e, (eid, root) in enumerate(zip(row_ids[p], row_roots[p])):
            if eid in row_excluded[p]:
                exclude[p, e] = True
                continue
            paths.append(kinematic_path(root, name))
            pe.append(p * E + e)
            cr.append(GRAPH_NODES.index(root))
    order = np.array(sorted(range(len(paths)), key=lambda i: -len(paths[i])), int)
    longest = len(paths[order[0]]) if paths else 0
    slots = [np.array([paths[i][j] for i in order if len(paths[i]) > j], int) for j in range(longest)]
    table = np.full((longest, len(paths)), ZERO_BONE, int)
    for j, bones in enumerate(slots):
        table[j, :len(bones)] = bones
    used = np.array(sorted({b for path in paths for b in path}), int)
    floor_bone, floor_starts = [], []
    for s in sk.SIDES:
        b, st = _entries([kinematic_path(f"ankle_{s}", name) for name in target_names])
        floor_bone.append(b)
        floor_starts.append(st)
    both = (np.concatenate(floor_bone), np.concatenate([floor_starts[0], floor_starts[1] + len(floor_bone[0])]))
    chain_root = np.array(cr, int)
    root_cols = None
    if len(pe) == P * E and P and E and np.all(chain_root.reshape(P, E) == chain_root[:E]):
        root_cols = chain_root[:E].copy()
    return _Plan(exclude, np.array(pe, int), len(pe) == P * E, chain_root, order, np.argsort(order), slots,
                 table, used, floor_bone, floor_starts, both, root_cols)


# index arrays (a list index is converted on every call)
_GRAPH_HEADS = np.array([sk.JOINT_INDEX[sk.BONE_BY_NAME[b].head] for b in GRAPH_BONES], int)
_GRAPH_TAILS = np.array([sk.JOINT_INDEX[sk.BONE_BY_NAME[b].tail] for b in GRAPH_BONES], int)
_GRAPH_NODE_INDEX = np.array([sk.JOINT_INDEX[n] for n in GRAPH_NODES], int)
_ANKLES = np.array([sk.JOINT_INDEX[f"ankle_{s}"] for s in sk.SIDES], int)


def _bone_vectors(surface: PosedSurface, bones, F: int, dtype=float) -> np.ndarray:
    """(3, F, NB + 1) vectors of GRAPH_BONES (from `bones` if given: a dict of (F, 3), or one
    (F, NB, 3) array in GRAPH_BONES order; else from the surface's joints), plus the zero bone."""
    out = np.zeros((3, F, len(GRAPH_BONES) + 1), dtype)
    if isinstance(bones, np.ndarray):
        out[:, :, :-1] = bones.transpose(2, 0, 1)
        return out
    if bones is None and isinstance(surface.joints, JointTable):
        j = surface.joints.array
        out[:, :, :-1] = (j.take(_GRAPH_TAILS, axis=1) - j.take(_GRAPH_HEADS, axis=1)).transpose(2, 0, 1)
        return out
    for i, name in enumerate(GRAPH_BONES):
        if bones is not None and name in bones:
            out[:, :, i] = np.asarray(bones[name], float).T
            continue
        b = sk.BONE_BY_NAME[name]
        if b.head in surface.joints and b.tail in surface.joints:
            out[:, :, i] = (surface.joints[b.tail] - surface.joints[b.head]).T
    return out


def _node_positions(surface: PosedSurface, F: int, dtype=float) -> np.ndarray:
    out = np.zeros((3, F, len(GRAPH_NODES)), dtype)
    if isinstance(surface.joints, JointTable):
        out[...] = surface.joints.array.take(_GRAPH_NODE_INDEX, axis=1).transpose(2, 0, 1)
        return out
    for i, name in enumerate(GRAPH_NODES):
        if name in surface.joints:
            out[:, :, i] = surface.joints[name].T
    return out


def _check_joints(surface: PosedSurface, plan: _Plan, target_names, who: str):
    if isinstance(surface.joints, JointTable):  # every canonical joint
        return
    need = {GRAPH_NODES[i] for i in np.unique(plan.chain_root)} | {"ankle_l", "ankle_r"}
    for idx in np.unique(np.concatenate([plan.entry_bone, *plan.floor_bone])):
        if idx == ZERO_BONE:
            continue
        b = sk.BONE_BY_NAME[GRAPH_BONES[idx]]
        need |= {b.head, b.tail}
    missing = sorted(need - set(surface.joints))
    if missing:
        raise BodyCalError(f"the {who} pose lacks joints needed by the egocentric mapping: {', '.join(missing[:6])}",
                           hint="pose every joint of the kinematic paths (pose_surface joints)")


def retarget_points(user_pts: np.ndarray, target_names: list[str], user_surface: PosedSurface,
                    avatar_surface: PosedSurface, user_bones: dict[str, np.ndarray] | None = None,
                    avatar_bones: dict[str, np.ndarray] | None = None, *, floor: bool = True, falloff: float = 2.0,
                    turn_v: bool = False, chunk: int | None = None,
                    penetration_tolerance: float = PENETRATION_TOLERANCE, details: dict | None = None,
                    dtype=np.float64) -> np.ndarray:
    """Retro-project the user's targets onto the avatar (Delahaye 2023, appendix C, eq. 1 and 2).

    user_pts: (F, P, 3) the user's target positions, one column per name of `target_names`
    (canonical joints on the kinematic tree: wrists, elbows, ankles, knees, fingertips, skull base).
    user_surface / avatar_surface: the two bodies posed for the same F frames with the same
    element_ids (the avatar posed by FK from the user's bone rotations, DESIGN.md §1 step 2).
    user_bones / avatar_bones: optional bone -> (F, 3) vectors (tail - head) overriding the ones
    derived from the posed joints; only the user's directions and the avatar's lengths are used
    (τ' = the avatar's bone lengths along the user's current bone directions).
    floor: include the floor contribution (the vertical singularity handled as eq. 1).
    falloff: exponent of the raw weights' distance law (paper: 2); the invariants hold for any.
    turn_v: carry each v_ij by its element's local frame (bone / triangle frame) onto the avatar's
    instead of adding it as a world vector (eq. 1 as printed); see repose_components.
    details: if a dict is given, it receives the weights of every frame ("lam", "lam_g",
    "lam_g_floor", "ratio" = τ'/τ, each (F, P, E) or (F, P)) for inspection.
    chunk: frames per block (default: sized so a block's temporaries stay in the CPU caches).
    dtype: float64, or float32 (see prepare_targets); the result has this dtype.

    Returns (F, P, 3): the avatar's targets p'_j. Equivalent to
    `prepare_targets(...).map(avatar_surface, ...)`, which maps the same user targets onto
    several avatar poses without projecting them on the user again."""
    prepared = prepare_targets(user_pts, target_names, user_surface, user_bones, floor=floor, falloff=falloff,
                               chunk=chunk, penetration_tolerance=penetration_tolerance, dtype=dtype)
    return prepared.map(avatar_surface, avatar_bones, turn_v=turn_v, details=details)


# frames x targets x elements per block. Decision (speed, the same values: every operation is per
# pair or per target row): fewer, larger numpy calls; the quick take's bake 20,000 -> 160,000 took
# 0.90-0.95 of the CPU time and fewer instructions (docs/PERFORMANCE.md "Bake"); 400,000 was slower
BLOCK_PAIRS = 160_000


@dataclass
class _UserBlock:
    """The user's side of one block of frames of one target group (see PreparedTargets)."""

    start: int
    stop: int
    p: np.ndarray  # (F, P, 3) the targets
    us: PosedSurface  # the user's surface for these frames and the group's elements
    pr: ProjectionsCF
    lam: np.ndarray  # (F, P, E) λ
    lam_g: np.ndarray  # (F, P, E) λg
    lam_gf: np.ndarray  # (F, P) λg of the floor
    vhat: np.ndarray  # (3, F, N) unit v of each chain
    tau: np.ndarray  # (F, N) τ
    dots: list | np.ndarray  # per path slot (_Plan.slot_bones), (n, F) |v̂·b_k| (τ' weighs them by the bone
    # length ratios); or all at once, (L, N, F) in `_Plan.slot_table`'s layout
    floor_user: tuple | None = None  # the floor ratios' user side, once mapped (_floor_user)
    tau_ok: np.ndarray | None = None  # (F, N) τ > EPS (the chains whose ratio is not 1)
    none: np.ndarray | None = None  # (F, P) targets with no element of weight (None: there are none)
    floor_ok: np.ndarray | None = None  # (F, 2P) the floor's τ > EPS, once mapped


@dataclass
class _Group:
    """Targets that exclude the same elements (own_chain_elements), mapped on the others only:
    an excluded pair has no weight, so projecting on it is wasted work. Or, for a few frames,
    several such groups side by side (`_fused_groups`), each target on its own elements."""

    targets: np.ndarray  # indices into the target names
    names: tuple[str, ...]
    elements: np.ndarray | None  # indices of the elements kept (None: all), the same for every target
    plan: _Plan
    blocks: list[_UserBlock]
    # Fused groups: (P E') each pair's flat index p E + e into every target on every element (E'
    # elements per target), and (P, E') each pair's element
    pairs: np.ndarray | None = None
    columns: np.ndarray | None = None

    def cols(self, E: int) -> np.ndarray:
        """(P, E') the element of each of the group's pairs."""
        if self.columns is not None:
            return self.columns
        keep = np.arange(E) if self.elements is None else self.elements
        return np.broadcast_to(keep, (len(self.targets), len(keep)))


class PreparedTargets:
    """The user's side of the egocentric mapping (Delahaye 2023, appendix C) of F frames of targets:
    their projections on the user's surface, the weights of eq. 1 and the user's τ of eq. 2,
    which do not depend on the avatar. `map` finishes the mapping against an avatar pose; the
    pipeline maps the arms twice (against the arms where the first pass put them) and pays for
    the user's side once. Built by `prepare_targets`."""

    def __init__(self, pts, names, user_surface, ub, floor, groups, whole=None, layout=None):
        self.pts, self.names, self.user_surface, self.floor, self.groups = pts, names, user_surface, floor, groups
        # `_todo`'s and `_avatar_rows`' answers depend on the targets, elements and grouping only:
        # kept per `layout` (a few frames' key, the same every live frame), else per instance
        self._cache = {} if layout is None else _layout_cache(layout)
        self.whole = whole  # every target on every element at once (project_components), when the groups share it
        self.ulen = np.sqrt(dot3(ub, ub))  # (F, NB + 1)
        self.ubt = np.ascontiguousarray(ub.transpose(0, 2, 1))  # (3, NB + 1, F): bones first for the gathers
        self._bone_tau_a = None  # (length ratios, {(group, block): τ' over the bones}) of the last map

    @property
    def frames(self) -> int:
        return self.pts.shape[0]

    def map(self, avatar_surface: PosedSurface, avatar_bones: dict[str, np.ndarray] | None = None, *,
            turn_v: bool = False, details: dict | None = None, targets: list[str] | None = None) -> np.ndarray:
        """The avatar's targets (F, P, 3) for the avatar posed as `avatar_surface` (same frames and
        element_ids as the user's surface); see retarget_points. `targets`: map only these (of the
        names prepared), (F, len(targets), 3) in their order; a block of frames mapped group by
        group (not `whole`) may then take an avatar surface of fewer elements, those the groups of
        these targets are mapped on (the bake's trunk stage: the body without the arms)."""
        us = self.user_surface
        F = self.frames
        if avatar_surface.frames != F:
            raise BodyCalError(f"targets have {F} frames, avatar surface {avatar_surface.frames}")
        wanted, todo = self._todo(None if targets is None else tuple(targets))
        rows = self._avatar_rows(None if targets is None else tuple(targets), tuple(avatar_surface.element_ids))
        for _, g in todo:
            _check_joints(avatar_surface, g.plan, g.names, "avatar")
        dtype = self.pts.dtype
        ab = _bone_vectors(avatar_surface, avatar_bones, F, dtype)
        lratio = np.divide(np.sqrt(dot3(ab, ab)), self.ulen, out=np.ones_like(self.ulen), where=self.ulen > EPS)
        lrt = np.ascontiguousarray(lratio.T)
        # τ' over the bones depends on the avatar's bone lengths only: the same for poses that
        # differ by rotations (the pipeline's arm passes), so it is kept for the next call.
        cached = self._bone_tau_a if self._bone_tau_a is not None and np.all(
            np.abs(self._bone_tau_a[0] - lrt) <= EPS * np.abs(lrt)) else None  # allclose(rtol=EPS, atol=0)
        bone_tau_a = (lrt, cached[1] if cached else {})
        self._bone_tau_a = bone_tau_a
        nodes_a = _node_positions(avatar_surface, F, dtype)
        union, local = rows
        if union is not None:  # only the elements these groups are mapped on, converted
            avatar_surface = avatar_surface.select(union)
        avatar_surface = avatar_surface.astype(dtype, normals=turn_v)
        out = np.empty_like(self.pts)
        # Every target re-posed on every element at once, each group's pairs taken from it (the
        # same values: the re-posing is per pair); see prepare_targets.
        whole = None if self.whole is None else repose_components(self.whole, us, avatar_surface, turn_v)
        E = len(us.element_ids)
        if details is not None:
            P = len(self.names)
            details.update(lam=np.zeros((F, P, E)), lam_g=np.zeros((F, P, E)), lam_g_floor=np.zeros((F, P)),
                           ratio=np.ones((F, P, E)))
        for gi, g in todo:
            av = avatar_surface if local[gi] is None else avatar_surface.select(local[gi])
            for bi, b in enumerate(g.blocks):
                s, e = b.start, b.stop
                if (gi, bi) not in bone_tau_a[1]:
                    bone_tau_a[1][gi, bi] = _bone_tau(b, g.plan, lrt[:, s:e])
                reposed = None
                if whole is not None:
                    reposed = (_take_pairs(whole[0], g.pairs, g.columns.shape),
                               _take_pairs(whole[1], g.pairs, g.columns.shape) if turn_v else b.pr.v)
                res, ratio = _map_block(b, g.plan, av.take(s, e), self.ubt[:, :, s:e], lrt[:, s:e],
                                        bone_tau_a[1][gi, bi], nodes_a[:, s:e], self.floor, turn_v, reposed)
                out[s:e, g.targets] = res
                if details is not None:
                    rows = (np.arange(s, e)[:, None, None], g.targets[:, None], g.cols(E))
                    details["lam"][rows] = b.lam
                    details["lam_g"][rows] = b.lam_g
                    details["ratio"][rows] = ratio
                    details["lam_g_floor"][np.ix_(np.arange(s, e), g.targets)] = b.lam_gf
        return out if wanted is None else out.take(wanted, axis=1)

    def _avatar_rows(self, targets: tuple | None, avatar_ids: tuple) -> tuple:
        """(the avatar surface's elements the groups of `targets` are mapped on, ascending (None:
        all of them), {group: its elements among those (None: all)}), once per target set and
        avatar element list; refuses a surface that lacks an element a group is mapped on."""
        cache = self._cache
        key = ("rows", targets, avatar_ids)
        if key not in cache:
            user_ids = tuple(self.user_surface.element_ids)
            at = {eid: i for i, eid in enumerate(avatar_ids)}
            _, todo = self._todo(targets)
            if self.whole is not None or avatar_ids == user_ids:
                if avatar_ids != user_ids:
                    raise BodyCalError("user and avatar surfaces have different elements",
                                       hint="pose both with element_ids=common_elements(user_model, avatar_model)")
                # a few frames map from every element at once; a block by group selects each group's
                cache[key] = (None, {gi: None if g.elements is None or self.whole is not None else g.elements
                                     for gi, g in todo})
                return cache[key]
            need = sorted({int(e) for _, g in todo for e in (range(len(user_ids)) if g.elements is None
                                                            else g.elements)})
            if any(user_ids[e] not in at for e in need):
                raise BodyCalError("the avatar surface lacks elements the targets are mapped on",
                                   hint="pose both with element_ids=common_elements(user_model, avatar_model)")
            union = np.array([at[user_ids[e]] for e in need], int)
            if np.any(np.diff(union) <= 0):
                raise BodyCalError("the avatar surface's elements are not in the user surface's order",
                                   hint="pose both with element_ids=common_elements(user_model, avatar_model)")
            row = {e: k for k, e in enumerate(need)}
            local = {gi: np.array([row[int(e)] for e in (range(len(user_ids)) if g.elements is None else g.elements)],
                                  int) for gi, g in todo}
            whole_set = len(union) == len(avatar_ids)
            kept_all = {gi for gi, g in todo if g.elements is None}
            cache[key] = (None if whole_set else union,
                          {gi: None if whole_set and gi in kept_all else v for gi, v in local.items()})
        return cache[key]

    def _todo(self, targets: tuple | None) -> tuple:
        """(the rows of `targets` (None: all), [(index, group)] of the groups that map them]), once
        per target set."""
        cache = self._cache
        key = ("todo", targets)
        if key not in cache:
            wanted = None if targets is None else np.array([self.names.index(n) for n in targets], int)
            cache[key] = (wanted, tuple(gi for gi, g in enumerate(self.groups)
                                        if wanted is None or not set(wanted.tolist()).isdisjoint(g.targets.tolist())))
        wanted, gis = cache[key]
        return wanted, [(gi, self.groups[gi]) for gi in gis]


def prepare_targets(user_pts: np.ndarray, target_names: list[str], user_surface: PosedSurface,
                    user_bones: dict[str, np.ndarray] | None = None, *, floor: bool = True, falloff: float = 2.0,
                    chunk: int | None = None, penetration_tolerance: float = PENETRATION_TOLERANCE,
                    dtype=np.float64, exclude: dict[str, set[str]] | tuple | None = None) -> PreparedTargets:
    """The user's side of `retarget_points` (same arguments), to `map` onto avatar poses.
    `dtype` float32 maps in single precision (about twice as fast; positions agree with float64
    to a few micrometres, the pipeline's choice). `exclude`: target name -> element ids it is not
    mapped on, besides its own chain's (the egocentric method's trunk targets: the arms); or, per
    target name in order, a frozenset of them (a caller that prepares the same targets again)."""
    dtype = np.dtype(dtype)
    if dtype not in (np.float32, np.float64):
        raise BodyCalError(f"the mapping computes in float32 or float64, not {dtype}")
    pts = np.asarray(user_pts, dtype)
    if pts.ndim != 3 or pts.shape[2] != 3 or pts.shape[1] != len(target_names):
        raise BodyCalError(f"targets must be (F, {len(target_names)}, 3), got {pts.shape}")
    F = pts.shape[0]
    if user_surface.frames != F:
        raise BodyCalError(f"targets have {F} frames, user surface {user_surface.frames}")
    ub = _bone_vectors(user_surface, user_bones, F, dtype)
    ubt = np.ascontiguousarray(ub.transpose(0, 2, 1))
    nodes_u = _node_positions(user_surface, F, dtype)
    user_surface = user_surface.astype(dtype)
    groups = []
    # Decision (speed, the same values): a few frames (a live frame, a preview) are projected and
    # re-posed for every target on every element at once, and the groups whose targets keep as
    # many elements run side by side, each target on its own elements (`_fused_groups`): the
    # projection is per (target, element) pair and a target's sums run over its own elements in
    # their order, so the values are the group's own, and one pass over a few more pairs costs far
    # less than one pass per group when numpy's per-call overhead is the cost. Longer blocks (the
    # bake's chunks) project each group on its own elements only: there the pairs are the cost.
    ids = tuple(user_surface.element_ids)
    names = tuple(target_names)
    extra = None if not exclude else exclude if isinstance(exclude, tuple) else tuple(
        frozenset(exclude.get(n, ())) for n in names)
    roots = tuple(user_surface.element_roots)
    if not chunk and F * len(names) * len(ids) <= MERGED_PAIRS:
        whole = project_components(pts, user_surface, penetration_tolerance)
        for members, group_names, pairs, columns, plan in _fused_groups(names, ids, roots, extra):
            _check_joints(user_surface, plan, group_names, "user")
            pr = ProjectionsCF(*(_take_pairs(a, pairs, columns.shape)
                                 for a in (whole.x, whole.v, whole.dist, whole.factor)), *([None] * 5))
            blocks = [_prepare_block(0, F, pts[:, members], plan, user_surface, ubt, nodes_u, floor,
                                     penetration_tolerance, falloff, pr)] if F else []
            groups.append(_Group(members, group_names, None, plan, blocks, pairs, columns))
        return PreparedTargets(pts, list(target_names), user_surface, ub, floor, groups, whole,
                               layout=(names, ids, roots, extra))
    for members, group_names, keep, plan, _ in _grouping(names, ids, roots, extra):
        sub = user_surface if keep is None else user_surface.select(keep)
        _check_joints(sub, plan, group_names, "user")
        step = int(chunk) if chunk else max(32, BLOCK_PAIRS // max(1, len(members) * len(sub.element_ids)))
        blocks = []
        for s in range(0, F, max(1, step)):
            e = min(F, s + step)
            blocks.append(_prepare_block(s, e, pts[s:e, members], plan, sub.take(s, e), ubt[:, :, s:e],
                                         nodes_u[:, s:e], floor, penetration_tolerance, falloff))
        groups.append(_Group(members, group_names, keep, plan, blocks))
    return PreparedTargets(pts, list(target_names), user_surface, ub, floor, groups)


MERGED_PAIRS = 2_000  # frames x targets x elements up to which every group shares one projection

_LAYOUTS: dict = {}


def _layout_cache(layout: tuple) -> dict:
    """The answers `PreparedTargets._todo` and `_avatar_rows` keep for a few frames' layout (the
    target names, element ids and roots, the exclusions), shared by every PreparedTargets of that
    layout (a live session prepares one a frame); at most 64 layouts kept."""
    if layout not in _LAYOUTS and len(_LAYOUTS) >= 64:
        _LAYOUTS.clear()
    return _LAYOUTS.setdefault(layout, {})


def _take_pairs(a: np.ndarray, pairs: np.ndarray, shape: tuple) -> np.ndarray:
    """(..., P, E) -> (..., *shape): the pairs at flat indices `pairs` (p E + e) of the last two axes."""
    lead = a.shape[:-2]
    return a.reshape(lead + (a.shape[-2] * a.shape[-1],)).take(pairs, axis=-1).reshape(lead + shape)


@lru_cache(maxsize=64)
def _grouping(target_names: tuple, ids: tuple, roots: tuple, extra: tuple | None = None) -> list:
    """The targets grouped by the elements they exclude (own_chain_elements, and `extra`: per
    target, more element ids), once per target and element set: [(the group's targets (indices),
    their names, the elements kept (None: all), the group's _Plan, the element ids it excludes)]."""
    rows: dict[frozenset, list[int]] = {}
    for i, name in enumerate(target_names):
        excluded = own_chain_elements(name) | (extra[i] if extra else frozenset())
        rows.setdefault(excluded & set(ids), []).append(i)
    out = []
    for excluded, members in rows.items():
        keep = np.array([k for k, eid in enumerate(ids) if eid not in excluded], int)
        # Decision: a target with every element excluded keeps them all (all weights zero: the
        # user's horizontal position, the floor's vertical one, as before grouping).
        keep = None if not excluded or not len(keep) else keep
        names = tuple(target_names[i] for i in members)
        cols = range(len(ids)) if keep is None else keep
        plan = _row_plan(names, (tuple(ids[k] for k in cols),) * len(names),
                         (tuple(roots[k] for k in cols),) * len(names), (excluded,) * len(names))
        out.append((np.array(members, int), names, keep, plan, excluded))
    return out


@lru_cache(maxsize=64)
def _fused_groups(target_names: tuple, ids: tuple, roots: tuple, extra: tuple | None = None) -> list:
    """`_grouping`'s groups side by side where their targets keep as many elements (each target's
    sums then run over its own elements, in their order, as in its group), or all fewer than
    SEQUENTIAL_SUM, padded to the widest of them with pairs of no weight (`_padding_is_exact`):
    [(the targets (indices), their names, each pair's flat index p E + e into every target on every
    element (P E'), each pair's element (P, E'), the _Plan of the targets on their own elements)],
    once per target and element set."""
    E = len(ids)
    pad = _padding_is_exact()
    by_width: dict[int, list] = {}
    for members, names, keep, _, excluded in _grouping(target_names, ids, roots, extra):
        cols = np.arange(E) if keep is None else keep
        for i, name in zip(members, names):
            key = 0 if pad and len(cols) < SEQUENTIAL_SUM else len(cols)
            by_width.setdefault(key, []).append((int(i), name, cols, excluded))
    out = []
    for rows in by_width.values():
        width = max(len(cols) for _, _, cols, _ in rows)
        padded = []
        for i, name, cols, excluded in rows:
            # a padding pair: an element the target is not mapped on (its weight is zero; its
            # values are a real projection's, finite), marked excluded by the sentinel id ""
            spare = [k for k in range(E) if k not in set(cols.tolist())][:1] * (width - len(cols))
            padded.append((i, name, np.concatenate([cols, np.array(spare, int)]),
                           tuple(ids[k] for k in cols) + ("",) * len(spare),
                           tuple(roots[k] for k in cols) + tuple(roots[k] for k in spare),
                           excluded | {""} if spare else excluded))
        members = np.array([r[0] for r in padded], int)
        columns = np.stack([r[2] for r in padded])
        plan = _row_plan(tuple(r[1] for r in padded), tuple(r[3] for r in padded), tuple(r[4] for r in padded),
                         tuple(r[5] for r in padded))
        pairs = (members[:, None] * E + columns).reshape(-1)
        out.append((members, tuple(r[1] for r in padded), pairs, columns, plan))
    return out


SEQUENTIAL_SUM = 8  # numpy sums a contiguous row of fewer items than this one after the other


@lru_cache(maxsize=1)
def _padding_is_exact() -> bool:
    """Whether this numpy sums a row of fewer than SEQUENTIAL_SUM float32 or float64 items one after
    the other, so that zeros after them change no bit (its pairwise sum does; checked once)."""
    rng = np.random.default_rng(0)
    for dtype in (np.float32, np.float64):
        for n in range(1, SEQUENTIAL_SUM):
            a = (rng.standard_normal((64, n)) * 10.0 ** rng.uniform(-6, 2, (64, n))).astype(dtype)
            padded = np.zeros((64, SEQUENTIAL_SUM - 1), dtype)
            padded[:, :n] = a
            if not np.array_equal(a.sum(-1), padded.sum(-1)):
                return False
    return True


def _prepare_block(start, stop, p, plan: _Plan, us: PosedSurface, ub, nodes_u, floor, tol, falloff,
                   pr: ProjectionsCF | None = None) -> _UserBlock:
    """The user's side of one block of one group (`pr`: its projections, when already made)."""
    F, P = p.shape[:2]
    pr = project_components(p, us, tol) if pr is None else pr
    lam_raw, floor_raw = raw_weights(pr, p[..., 2], plan.exclude, falloff)
    if not floor:
        floor_raw = np.zeros_like(floor_raw)
    lam, lam_g, lam_gf = normalise_weights(lam_raw, floor_raw)
    # Kinematic normalisation (eq. 2, DESIGN.md Decision: absolute values), the user's τ for
    # every chain: τ = Σ_k |v̂·b_k| + |v̂·(x - r)|.
    vhat, _ = unit_and_norm(_chains(pr.v, plan), 0.0, axis=0)  # (3, F, N)
    vt = vhat.transpose(0, 2, 1).take(plan.order, axis=1)  # (3, N, F) contiguous, longest first: one copy
    if F * vt.shape[1] <= MERGED_PAIRS and len(plan.slot_table):
        # A few frames: every slot at once (the padding's dots are exact zeros; the sum over the
        # slots runs in their order, as the loop below adds them).
        dots = np.abs(dot3(vt[:, None], ub.take(plan.slot_table, axis=1)))  # (L, N, F)
        tau = np.add.reduce(dots, axis=0)
    else:
        tau = np.zeros(vt.shape[1:], vt.dtype)
        dots = []
        for bones in plan.slot_bones:
            n = len(bones)
            dots.append(np.abs(dot3(vt[:, :n], ub.take(bones, axis=1))))
            tau[:n] += dots[-1]
    # (F, N) contiguous (a transposed view made every use strided): the rows put back in order, then
    # transposed (`_unordered_t`)
    tau = _unordered_t(tau, plan)
    tau += np.abs(dot3(vhat, _from_roots(pr.x, nodes_u, plan)))
    pr.dist = pr.factor = None  # spent on the weights
    none = lam.sum(-1) <= 0  # no element with weight (all excluded)
    return _UserBlock(start, stop, p, us, pr, lam, lam_g, lam_gf, vhat, tau, dots, tau_ok=tau > EPS,
                      none=none if none.any() else None)


def _chains(a, plan: _Plan):
    """(3, F, P, E) -> (3, F, N): the pairs that have a chain (a view when all do)."""
    flat = a.reshape(a.shape[:2] + (-1,))
    return flat if plan.dense else flat.take(plan.chain_pe, axis=2)


def _from_roots(x, nodes, plan: _Plan) -> np.ndarray:
    """(3, F, N) x - r of each chain, x (3, F, P, E), r the chain's root node (nodes (3, F, nodes))."""
    if plan.root_cols is None:
        return _chains(x, plan) - nodes.take(plan.chain_root, axis=2)
    F = x.shape[1]
    return (x - nodes.take(plan.root_cols, axis=2)[:, :, None, :]).reshape(3, F, -1)


def _bone_tau(b: _UserBlock, plan: _Plan, lratio) -> np.ndarray:
    """(F, N) Σ_k |v̂·b_k| L'_k/L_k over each chain's bones: τ' without its extremity term."""
    if isinstance(b.dots, np.ndarray):  # every slot at once (_prepare_block)
        out = np.add.reduce(b.dots * lratio.take(plan.slot_table, axis=0), axis=0)
    else:
        out = np.zeros(b.tau.shape[::-1], b.tau.dtype)
        for bones, d in zip(plan.slot_bones, b.dots):
            out[:len(bones)] += d * lratio.take(bones, axis=0)
    return _unordered_t(out, plan)


def _unordered_t(a: np.ndarray, plan: _Plan) -> np.ndarray:
    """(N, F) rows in `plan.order` -> (F, N) contiguous in the chains' order. Decision (speed, the
    same values): the rows gathered whole, then one transposed copy; `a.T.take(unorder, axis=1)`
    copied the transpose and then gathered it item by item."""
    return np.ascontiguousarray(a.take(plan.unorder, axis=0).T)


def _map_block(b: _UserBlock, plan: _Plan, av: PosedSurface, ub, lratio, bone_tau_a, nodes_a, floor, turn_v,
               reposed=None):
    """One block of frames against the avatar: eq. 1 with τ'/τ of eq. 2 (`bone_tau_a`: `_bone_tau`;
    `reposed`: the block's (x', v') when already made). Returns ((F, P, 3), ratio)."""
    p, us, pr = b.p, b.us, b.pr
    F, P = p.shape[:2]
    E = pr.v.shape[-1]
    x_av, v_av = repose_components(pr, us, av, turn_v) if reposed is None else reposed  # (3, F, P, E)
    # τ' = Σ_k |v̂·b_k| L'_k/L_k + |v̂·(x' - r')|
    tau_a = bone_tau_a + np.abs(dot3(b.vhat, _from_roots(x_av, nodes_a, plan)))
    chain_ratio = np.divide(tau_a, b.tau, out=np.ones_like(b.tau), where=b.tau_ok)
    if plan.dense:
        ratio = chain_ratio.reshape(F, P, E)
    else:
        ratio = np.ones((F, P * E), chain_ratio.dtype)
        ratio[:, plan.chain_pe] = chain_ratio
        ratio = ratio.reshape(F, P, E)

    est = x_av + v_av * ratio  # (3, F, P, E)
    lam = b.lam
    out = np.empty((F, P, 3), est.dtype)
    # x and y in one product and sum (each row summed on its own, as apart)
    out[..., :2] = (est[:2] * lam).sum(-1).transpose(1, 2, 0)
    # No element with weight (all excluded): keep the user's horizontal position.
    if b.none is not None:
        out[..., :2] = np.where(b.none[..., None], p[..., :2], out[..., :2])
    vertical = (est[2] * b.lam_g).sum(-1)
    if floor:
        # h'_j = h_j τ'/τ along the path from the supporting (lower) ankle, v̂ = up (DESIGN.md §5).
        if b.floor_user is None:  # the user's side, the same for every map of this block
            b.floor_user = _floor_user(b, plan, ub)
            b.floor_ok = b.floor_user[1] > EPS
        # both sides at once: (F, 2P), the left side's targets first (as _floor_user stacks them)
        ent, st = plan.floor_both
        uz, tf, w_left = b.floor_user
        tfa = np.add.reduceat(uz * lratio.take(ent, axis=0), st, axis=0).T
        ankles = _ankle_heights(av)  # (F, 2)
        tfa += np.abs(ankles).repeat(P, axis=1)
        ratios = np.divide(tfa, tf, out=np.ones_like(tf), where=b.floor_ok)
        fratio = ratios[:, P:] + w_left[:, None] * (ratios[:, :P] - ratios[:, P:])
        vertical = vertical + p[..., 2] * fratio * b.lam_gf
    out[..., 2] = vertical
    return out, ratio


def _ankle_heights(surface: PosedSurface) -> np.ndarray:
    """(F, 2) both ankles' heights, left first."""
    if isinstance(surface.joints, JointTable):
        return surface.joints.array.take(_ANKLES, axis=1)[..., 2]
    return np.stack([surface.joints[f"ankle_{name}"][:, 2] for name in sk.SIDES], axis=1)


def _floor_user(b: _UserBlock, plan: _Plan, ub) -> tuple:
    """The user's side of the floor ratios of a block, both sides at once (`_Plan.floor_both`: the
    left side's paths, then the right's): (|b_z| of the bones from each ankle (K, F), their τ with
    the ankle's height (F, 2P)), and the left foot's share of the support (F,).
    Decision: the two feet's ratios are blended by which ankle is lower (SUPPORT_BLEND): with both
    feet on the floor, picking the lower ankle flips with millimetres of noise, and each flip moved
    every target's height by h (τ'_l/τ_l - τ'_r/τ_r), up to a few mm."""
    us = b.us
    ent, st = plan.floor_both
    uz = np.abs(ub[2].take(ent, axis=0))  # (K, F)
    ankles = _ankle_heights(us)  # (F, 2)
    tau = np.add.reduceat(uz, st, axis=0).T + np.abs(ankles).repeat(len(st) // 2, axis=1)
    w_left = 0.5 + 0.5 * np.tanh((ankles[:, 1] - ankles[:, 0]) / SUPPORT_BLEND)
    return uz, tau, w_left
