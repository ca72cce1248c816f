"""The basis solve (DESIGN.md §1, "The rig posed"): armature-space pose rotations -> the pose bones'
`rotation_quaternion` (Blender's `matrix_basis`) and the root bone's `location`. Blender's pose rule
(rotation part, armature space): P_child = P_parent M_parent^-1 M_child basis, so
basis = M_child^-1 M_parent P_parent^-1 P_child (a parentless bone: M^-1 P); the root bone's
location is in its rest frame."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...core.transforms import MANY_PRODUCTS, STACKED_FRAMES, matmul_stack, stacks_mul, transposed
from .. import pose_kernels
from .pose_plan import rows_of


@dataclass
class BasisPlan:
    """The basis solve's frame-independent factors."""

    kids: np.ndarray  # the bones with a parent
    parents: np.ndarray  # their parents
    fixed: np.ndarray  # (N, 3, 3) per bone the fixed left factor's transpose: (M^-1 M_p)^T, (M^-1)^T parentless
    rows: list[int]  # per bone, its row among `kids`, -1 for none
    root: int
    root_parent: int
    root_head: np.ndarray  # (3,) the root bone's rest head
    root_rest: np.ndarray  # (3, 3) its M
    # with a parent: (M_i^-1 M_p)^T and M_i^-1 (h_i - h_p) (None: a parentless root)
    root_rel: tuple | None
    # one frame's (`_solve_one`): the fixed left factors M^-1 M_p (M^-1 parentless), (N, 3, 3)
    one_fixed: np.ndarray | None = None
    one_root: tuple | None = None
    # and per bone its parent's row in P (a parentless bone's its own, written over with the
    # identity: a slice's copy, where an identity row concatenated after P cost 10,000 more)
    one_gather: np.ndarray | None = None
    one_parentless: slice | np.ndarray | None = None

    def __post_init__(self):
        self.one_gather = np.array([b if r < 0 else int(self.parents[r]) for b, r in enumerate(self.rows)], int)
        self.one_parentless = rows_of([b for b, r in enumerate(self.rows) if r < 0])
        self.one_fixed = np.ascontiguousarray(self.fixed.swapaxes(-1, -2))
        # one frame's root location in floats (`_root_location_one`): (columns, constant) as lists
        if self.root_rel is None:
            self.one_root = (self.root_rest.T.tolist(), self.root_head.tolist())
        else:
            self.one_root = (self.root_rel[0].T.tolist(), self.root_rel[1].tolist())

    @classmethod
    def of(cls, parent: np.ndarray, rest: np.ndarray, head: np.ndarray, root: int) -> BasisPlan:
        rel_t = rest.swapaxes(-1, -2)
        kids = np.flatnonzero(parent >= 0)
        fixed = np.stack([(rel_t[i] if p < 0 else rel_t[i] @ rest[p]).T for i, p in enumerate(parent)])
        kid_list = kids.tolist()
        rows = [kid_list.index(b) if b in kid_list else -1 for b in range(len(parent))]
        i, p = root, parent[root]
        root_rel = None if p < 0 else ((rest[i].T @ rest[p]).T, rest[i].T @ (head[i] - head[p]))
        return cls(kids, parent[kids], np.ascontiguousarray(fixed), rows, int(root), int(p), head[i], rest[i], root_rel)


def solve(plan: BasisPlan, P, turn=None):
    """Pose-bone quaternions (F, N, 4) from bones-first armature-space pose rotations P (N, F, 3, 3)
    (`turn`: one frame's turned rotations W P, with the armature's rotation W, `fk.posed`)."""
    kids, parents, fixed = plan.kids, plan.parents, plan.fixed
    if P.shape[1] == 1:
        return _solve_one(plan, P, turn)
    if P.shape[1] >= STACKED_FRAMES and len(kids) * P.shape[1] >= MANY_PRODUCTS:
        return _solve_many(plan, P)
    # X = P_parent^-1 P_child, built transposed (X^T = P_child^T P_parent: the same products)
    rel_t = transposed(P)
    n, nf = P.shape[:2]
    if nf < STACKED_FRAMES:  # a few frames: numpy's own loop for the stacked products (pose_kernels.few_matmul)
        rel_t[kids] = pose_kernels.few_matmul(P.take(kids, axis=0).swapaxes(-1, -2), P.take(parents, axis=0),
                                              (len(kids), nf, 3, 3))
        basis_t = pose_kernels.few_matmul(rel_t, fixed[:, None], (n, nf, 3, 3))
    else:
        rel_t[kids] = matmul_stack(P.take(kids, axis=0).swapaxes(-1, -2), P.take(parents, axis=0))
        # basis^T = X^T (M^-1 M_p)^T for each bone, one stacked product (as mul_stack, bone by bone)
        basis_t = stacks_mul(rel_t, fixed)  # (N, F, 3, 3)
    # the quaternions from basis entries' rows, frames first: basis[f, n, i, j] = basis_t[n, f, j, i]
    # quat_from_rows' values (pose_kernels.quat_of_few: one product for every candidate)
    return pose_kernels.quat_of_few(basis_t.transpose(3, 2, 1, 0).reshape(9, nf * n)).T.reshape(nf, n, 4)


def _solve_one(plan: BasisPlan, P, turn=None):
    """`solve` of one frame, the same products in fewer numpy calls: every bone's X = P_p^T P
    at once (a parentless bone's parent the identity), basis = (M^-1 M_p) X written
    straight into the entry rows the quaternions are read from (`pose_kernels.quat_of_rows`).
    The same terms in the same order as `solve`'s transposed products (a parentless bone's
    1 x + 0 y + 0 z may turn a -0.0 into 0.0). Decision (speed, measured in instructions): one
    frame's basis took 304,000 instructions, mostly numpy's per-call cost on 53 bones. Turned
    rotations P' = W P (`turn` W): a child's P'_p^T P' is P_p^T P, and a parentless bone's parent
    row is W instead of the identity (W^T P' = P)."""
    n = P.shape[0]
    a = P.reshape(n, 3, 3)
    par = a.take(plan.one_gather, axis=0)  # the parents' rows, a parentless bone's the identity (W)
    par[plan.one_parentless] = _EYE if turn is None else turn
    rel = pose_kernels.few_matmul(par.swapaxes(-1, -2), a, (n, 3, 3))
    aug = np.empty((10, n))  # a ones row, then the basis entries m00, m01, ..., m22 of every bone
    aug[0] = 1.0
    np.matmul(plan.one_fixed, rel, out=aug[1:].T.reshape(n, 3, 3))
    return pose_kernels.quat_of_rows(aug)[None]


_EYE = np.eye(3)[None]


def _solve_many(plan: BasisPlan, P):
    """`solve` of many frames (a bake's chunk), the same values: the products and quaternions
    read the rotations' entries as contiguous rows (`pose_kernels`) instead of strided entries
    of gathered and transposed copies of the whole stack. Decision (speed, the same bits):
    X^T's entries are `matmul_stack`'s sums, each product by its fixed factor the same BLAS
    call on the same (3F, 3) rows as `stacks_mul`, the quaternions `quat_from_rows`'s."""
    kids, parents, fixed = plan.kids, plan.parents, plan.fixed
    n, nf = P.shape[:2]
    ent = pose_kernels.entry_rows(P)  # (9, N, F)
    rel_t = np.empty((len(kids), nf, 3, 3))  # X^T of the bones with a parent
    pose_kernels.product_t_into(rel_t, ent.take(kids, axis=1), ent.take(parents, axis=1))
    row = plan.rows
    basis_t = np.empty((n, nf, 3, 3))
    for b in range(n):  # basis^T = X^T (M^-1 M_p)^T, `stacks_mul`'s product bone by bone
        src = rel_t[row[b]] if row[b] >= 0 else np.ascontiguousarray(P[b].swapaxes(-1, -2))
        np.matmul(src.reshape(-1, 3), fixed[b], out=basis_t[b].reshape(-1, 3))
    # basis[f, n, i, j] = basis_t[n, f, j, i]: the basis's entry rows are basis_t's transposed
    q = pose_kernels.quat_from_entries(pose_kernels.entry_rows(basis_t, _TRANSPOSE_ROWS).reshape(9, -1))
    return q.reshape(4, n, nf).transpose(2, 1, 0)


def root_location(plan: BasisPlan, P, H, turn=None):
    """(F, 3) the root bone's pose location (its rest frame) from bones-first pose rotations P and
    heads H: where its head sits against where its parent's pose puts its rest head (`turn`: one
    frame's turned W P and W H, `solve`)."""
    i, p = plan.root, plan.root_parent
    if P.shape[1] == 1:
        return _root_location_one(plan, P, H, turn)
    if p < 0:
        return (H[i] - plan.root_head) @ plan.root_rest
    rel_t, rest_off = plan.root_rel
    local = (P[p].swapaxes(-1, -2) @ (H[i] - H[p])[..., None])[..., 0]
    return local @ rel_t - rest_off


def _root_location_one(plan: BasisPlan, P, H, turn=None) -> np.ndarray:
    """`root_location` of one frame in Python floats, the same terms in the same order (its
    numpy products on (1, 3) rows cost about 35,000 instructions, mostly per call). Turned (W P,
    W H): a parented root's P_p^T (H - H_p) is the same; a parentless one's head turned back."""
    i, p = plan.root, plan.root_parent
    cols, const = plan.one_root
    head = H[i, 0].tolist()
    if p < 0:
        if turn is not None:
            head = (H[i, 0] @ turn).tolist()
        d = [a - b for a, b in zip(head, const)]
        return np.array([[(d[0] * c[0] + d[1] * c[1]) + d[2] * c[2] for c in cols]])
    d = [a - b for a, b in zip(head, H[p, 0].tolist())]
    local = [(r[0] * d[0] + r[1] * d[1]) + r[2] * d[2] for r in P[p, 0].T.tolist()]  # P_p^T d
    return np.array([[((local[0] * c[0] + local[1] * c[1]) + local[2] * c[2]) - o for c, o in zip(cols, const)]])


_TRANSPOSE_ROWS = np.array([0, 3, 6, 1, 4, 7, 2, 5, 8])  # a 3x3's entries (i, j) -> (j, i), row-major
