"""Array kernels of the rig posing (`avatar_pose.AvatarRig`) for long stacks (a bake's chunks): the
same operations in the same order as the general helpers of `core.transforms` they stand for, so
the same bits, with fewer passes over memory (no transposed copies of whole stacks, no strided
products over them, no stacked argmax). DESIGN.md "Prepared solver". Also a few frames' kernels
(a live frame's: `quat_of_few`, `few_matmul`), fewer instructions for the same values to the
sums' rounding."""

from __future__ import annotations

import numpy as np

from ..core.transforms import SHEPPERD_CANDIDATES

_ENTRY_OF_TRANSPOSE = np.array([0, 3, 6, 1, 4, 7, 2, 5, 8])  # row-major 3x3: entry (i, j) -> (j, i)


def entry_rows(a: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
    """The entries of a stack of 3x3 matrices (..., 3, 3) as contiguous rows (9, ...): row 3i + j
    holds entry (i, j) of every matrix (`rows`: which entry each row takes instead, e.g. a
    transpose's). Nine copies, each reading one entry of every matrix."""
    flat = a.reshape(-1, 9)
    out = np.empty((9, flat.shape[0]))
    for r, e in enumerate(range(9) if rows is None else rows.tolist()):
        out[r] = flat[:, e]
    return out.reshape((9,) + a.shape[:-2])


def product_t_into(out: np.ndarray, child: np.ndarray, parent: np.ndarray) -> None:
    """out[..., i, k] = (C[0, i] P[0, k] + C[1, i] P[1, k]) + C[2, i] P[2, k] for entry rows C, P
    (9, ...) (`entry_rows`): C^T P item by item, `transforms.matmul_stack`'s sums of many items
    (a_i0 b_0k + a_i1 b_1k) + a_i2 b_2k with a = C^T, b = P, each entry over contiguous rows and
    written once where it goes."""
    tmp = np.empty(child.shape[1:])
    for i in range(3):
        for k in range(3):
            entry = out[..., i, k]
            np.multiply(child[i], parent[k], out=tmp)
            acc = child[3 + i] * parent[3 + k]
            np.add(tmp, acc, out=tmp)
            np.multiply(child[6 + i], parent[6 + k], out=acc)
            np.add(tmp, acc, out=entry)


def quat_from_entries(comp: np.ndarray) -> np.ndarray:
    """`transforms.quat_from_rows` (Shepperd's method on entry rows (9, M): m00, m01, ..., m22 ->
    (4, M), w >= 0) with the same values, for many matrices: the best conditioned candidate is
    found by three comparisons instead of a stacked argmax (the first largest of trace, m00, m11,
    m22 as argmax takes it, NaN included: a NaN diagonal makes the trace NaN, which stays chosen),
    and the trace's candidate, most items' choice, is computed for every item without a gather;
    the other three for the items that pick them only."""
    trace = comp[0] + comp[4] + comp[8]
    best = np.zeros(trace.shape, np.intp)
    top = trace
    chosen = []  # the other candidates any item may pick
    for k, row in ((1, 0), (2, 4), (3, 8)):
        more = comp[row] > top
        if more.any():
            best[more] = k
            top = np.where(more, comp[row], top)
            chosen.append(k)
    q = np.empty((4, comp.shape[1]))
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = comp
    np.add(1, m00, out=q[0])  # SHEPPERD_CANDIDATES[0]: (1 + m00 + m11 + m22, m21 - m12, m02 - m20, m10 - m01)
    q[0] += m11
    q[0] += m22
    np.subtract(m21, m12, out=q[1])
    np.subtract(m02, m20, out=q[2])
    np.subtract(m10, m01, out=q[3])
    for k in chosen:
        cols = (best == k).nonzero()[0]
        if len(cols):
            q[:, cols] = SHEPPERD_CANDIDATES[k](*comp[:, cols])
    q /= np.sqrt((q * q).sum(0))
    q *= np.where(q[0] < 0, -1.0, 1.0)
    return q


def _shepperd_affine() -> np.ndarray:
    """(20, 10): rows 4k..4k+3 are SHEPPERD_CANDIDATES[k] as an affine map of (1, m00, ..., m22),
    rows 16-19 the trace, m00, m11 and m22 whose largest picks the candidate."""
    out = np.zeros((20, 10))
    for k, cand in enumerate(SHEPPERD_CANDIDATES):
        base = np.array(cand(*np.zeros(9)), float)
        out[4 * k:4 * k + 4, 0] = base
        for e in range(9):
            unit = np.zeros(9)
            unit[e] = 1.0
            out[4 * k:4 * k + 4, 1 + e] = np.array(cand(*unit), float) - base
    out[16, [1, 5, 9]] = 1.0
    out[17, 1], out[18, 5], out[19, 9] = 1.0, 1.0, 1.0
    out.setflags(write=False)
    return out


_SHEPPERD_AFFINE = _shepperd_affine()


def quat_of_few(comp: np.ndarray) -> np.ndarray:
    """`quat_from_entries` (Shepperd's method on entry rows (9, M) -> (4, M), w >= 0) of a few
    matrices (a live frame's bones): all four candidates and the four pickers of every item in ONE
    product by a constant affine map, the pick by argmax (the first largest, NaN included, as
    `quat_from_entries` takes it). Decision (speed): the masked candidates' gathers and scatters
    were 470,000 instructions for one frame's 53 bones, this about a tenth; the sums are the same
    terms in BLAS's order (the last bit may differ, ~1e-16)."""
    m = comp.shape[1]
    aug = np.empty((10, m))
    aug[0] = 1.0
    aug[1:] = comp
    cand = _SHEPPERD_AFFINE @ aug  # (20, M)
    q = cand[:16].reshape(4, 4, m)[cand[16:].argmax(0), :, np.arange(m)]  # (M, 4)
    q /= np.sqrt((q * q).sum(1))[:, None]
    q *= np.where(q[:, :1] < 0, -1.0, 1.0)
    return q.T


def quat_of_rows(aug: np.ndarray) -> np.ndarray:
    """`quat_of_few` of a few matrices whose entry rows come after a row of ones (10, M) (one
    frame's basis writes them there), as (M, 4) quaternion rows: its values, the same products
    and picks."""
    m = aug.shape[1]
    cand = _SHEPPERD_AFFINE @ aug  # (20, M)
    q = cand[:16].reshape(4, 4, m)[cand[16:].argmax(0), :, _arange(m)]  # (M, 4)
    # w >= 0 and unit length in one division: q / -|q| is -(q / |q|) to the bit (a sign is exact),
    # and w's sign is the same before and after the division by |q| > 0 (NaN: neither flips).
    # Decision (speed): the sign as a second pass (a where and a product) cost 42,000
    # instructions a frame's 53 bones, the negated norms' masked pass a fraction of it.
    norm = np.sqrt((q * q).sum(1))
    np.negative(norm, out=norm, where=q[:, 0] < 0)
    q /= norm[:, None]
    return q


_ARANGES: dict = {}


def _arange(m: int) -> np.ndarray:
    """np.arange(m), made once per m (a frame's fancy index)."""
    r = _ARANGES.get(m)
    if r is None:
        r = _ARANGES[m] = np.arange(m)
    return r


def few_matmul(a: np.ndarray, b: np.ndarray, shape: tuple) -> np.ndarray:
    """np.matmul(a, b) of stacks of a few small matrices (a live frame's bones), the result of
    shape `shape` written into a strided buffer (a view whose last axis steps two items).
    Decision (speed, measured in instructions): numpy hands each product of a stack to BLAS when
    the operands and the output are laid out as BLAS takes them, about 1,500 instructions a 3x3
    product (76,000 for 50); an output BLAS cannot take sends the whole stack through numpy's own
    loop, 35,000. Its sums are the plain (a_i0 b_0k + a_i1 b_1k) + a_i2 b_2k (BLAS's may fuse a
    multiply-add): the last bit may differ from the BLAS product (~1e-16)."""
    return np.matmul(a, b, out=np.empty(shape + (2,))[..., 0])
