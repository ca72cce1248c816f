"""Rotations on numpy arrays with any leading axes (frames first).

Quaternions are `w, x, y, z` (mathutils order, FORMATS.md §1), Hamilton product, active
rotations: `rotate(q, v)` turns vector v by q. Matrices act on column vectors: `R @ v`.
"""

from __future__ import annotations

import math

import numpy as np

EPS = 1e-12

def normalize(v: np.ndarray, axis: int = -1) -> np.ndarray:
    """Unit vectors; zero vectors stay zero (never NaN)."""
    return unit_and_norm(np.asarray(v, dtype=float), 0.0, axis)[0]


def unit_and_norm(v: np.ndarray, fallback=0.0, axis: int = -1) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors of `v` along `axis` and their norms; `fallback` (broadcast like `v`) where a
    norm is EPS or less, so never NaN. `v`'s float type is kept (the egocentric kernels run in
    float32, their vectors components first: `axis=0`). The norm sums the squared components in
    order, as `np.linalg.norm` does, one component at a time (several times faster on a short
    trailing axis)."""
    last = axis in (-1, v.ndim - 1)
    if last and v.shape[-1] < 8:
        # numpy sums fewer than 8 items one after the other: the same sum in two numpy calls
        s = np.add.reduce(v * v, -1)  # ndarray.sum's reduction
    else:
        comps = [v[..., k] for k in range(v.shape[-1])] if last else v if axis == 0 else np.moveaxis(v, axis, 0)
        s = comps[0] * comps[0]
        for c in comps[1:]:
            s += c * c
    n = np.sqrt(s)
    ok = n > EPS

    def along(a):  # (..., ) -> broadcast against v along `axis`
        return a[..., None] if last else a[None] if axis == 0 else np.expand_dims(a, axis)

    if all_true(ok):  # the usual case: no vector to replace, nothing to guard the division against
        return v / along(n), n
    return np.where(along(ok), v / along(np.where(ok, n, 1.0)), fallback), n


def broadcast_shape(a: tuple, b: tuple) -> tuple:
    """np.broadcast_shapes of two shapes, in Python for those of as many axes (numpy's builds
    arrays to find it: several microseconds, on the live solve's every few-vector product)."""
    if len(a) != len(b):
        return np.broadcast_shapes(a, b)
    out = []
    for x, y in zip(a, b):
        if x != y and x != 1 and y != 1:
            return np.broadcast_shapes(a, b)  # raises numpy's error
        out.append(y if x == 1 else x)
    return tuple(out)


def all_true(a: np.ndarray) -> bool:
    """a.all() of a bool array; a few items in Python (the method's wrapper costs more than the
    test on the live solve's one-frame arrays)."""
    return a.all() if a.size > 32 else False not in a.ravel().tolist()


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """`np.cross` of (..., 3) vectors, written out: the same products and differences in the same
    order (so the same bits), without its bookkeeping, which dominates on a few vectors."""
    a, b = np.asarray(a), np.asarray(b)
    shape = a.shape if a.shape == b.shape else broadcast_shape(a.shape, b.shape)
    if math.prod(shape[:-1]) <= SMALL_CROSS:
        # A few vectors: the components gathered in rolled order, the same three products and
        # differences in eight numpy calls instead of fifteen (measured: 52,000 instructions of a
        # rotations frame's 4.15 M, 118,000 of an egocentric one's 18.95 M, bench_instructions' take).
        # The result is still allocated first: a later 3x3 product's BLAS path depends on its
        # operands' alignment, and a result allocated after the temporaries moved one-frame solves
        # by 1e-16.
        out = np.empty(shape, np.result_type(a, b))
        return np.subtract(a.take(_ROLL1, -1) * b.take(_ROLL2, -1), a.take(_ROLL2, -1) * b.take(_ROLL1, -1), out=out)
    out = np.empty(shape, np.result_type(a, b))
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    np.subtract(a1 * b2, a2 * b1, out=out[..., 0])
    np.subtract(a2 * b0, a0 * b2, out=out[..., 1])
    np.subtract(a0 * b1, a1 * b0, out=out[..., 2])
    return out


# cross: (a1 b2 - a2 b1, a2 b0 - a0 b2, a0 b1 - a1 b0); index arrays, gathered with `take` (a list
# index is converted on every call: several times slower on a few vectors)
_ROLL1, _ROLL2 = np.array([1, 2, 0]), np.array([2, 0, 1])
SMALL_CROSS = 64  # vectors up to which `cross` gathers (beyond: views and in-place differences)


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    aw, ax, ay, az = np.moveaxis(np.asarray(a, float), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b, float), -1, 0)
    return np.stack([
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ], axis=-1)


def quat_conj(q: np.ndarray) -> np.ndarray:
    q = np.asarray(q, float)
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def quat_normalize(q: np.ndarray) -> np.ndarray:
    """Unit quaternions with w >= 0 (one of the two covers, for stable comparisons)."""
    q = normalize(q)
    return np.where(q[..., :1] < 0, -q, q)


def rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors v (..., 3) by unit quaternions q (..., 4)."""
    q = np.asarray(q, float)
    v = np.asarray(v, float)
    w = q[..., :1]
    u = q[..., 1:]
    t = 2.0 * cross(u, v)
    return v + w * t + cross(u, t)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) of unit quaternions (..., 4). The nine entries are the usual
    1 - 2 (y² + z²), 2 (xy - wz), ... computed three at a time (the same products and sums, so the
    same bits as entry by entry, in a third of the numpy calls). Decision: one path for any count;
    a few quaternions' own (fewer numpy calls, no Python scalars) saved 11,000 instructions of a
    rotations frame's 4.15 M and 6,000 of an egocentric one's 18.95 M (bench_instructions'
    take): not worth its 30 lines."""
    q = np.asarray(q, float)
    sq = q * q
    pair = q.take(_QP, -1) * q.take(_QQ, -1)  # xy, xz, yz
    turn = q[..., :1] * q.take(_QW, -1)  # wz, wy, wx
    m = np.empty(q.shape[:-1] + (9,))
    m[..., _DIAG] = 1 - 2 * (sq.take(_SA, -1) + sq.take(_SB, -1))
    m[..., _MINUS] = 2 * (pair - turn)
    m[..., _PLUS] = 2 * (pair + turn)
    return m.reshape(q.shape[:-1] + (3, 3))


# quat_to_matrix's index arrays (arrays, not lists: see cross)
_QP, _QQ, _QW = np.array([1, 1, 2]), np.array([2, 3, 3]), np.array([3, 2, 1])
_SA, _SB, _DIAG = np.array([2, 1, 1]), np.array([3, 3, 2]), np.array([0, 4, 8])  # y²+z², x²+z², x²+y² on the diagonal
_MINUS, _PLUS = np.array([1, 6, 5]), np.array([3, 2, 7])  # xy-wz, xz-wy, yz-wx; xy+wz, xz+wy, yz+wx


def stack_mul(a: np.ndarray, m: np.ndarray) -> np.ndarray:
    """a @ m for a stack of 3x3 matrices a (..., 3, 3) and ONE 3x3 m, as one BLAS call on the stack
    seen as (3N, 3) rows: numpy's broadcast matmul makes one call per 3x3 product (~7x slower)."""
    a = np.asarray(a, float)
    return (a.reshape(-1, 3) @ m).reshape(a.shape)


MANY_PRODUCTS = 256  # items from which `matmul_stack` sums entries over the stack (a live frame's stay np.matmul)


def mul_stack(m: np.ndarray, a: np.ndarray) -> np.ndarray:
    """m @ a for ONE 3x3 m and a stack a (..., 3, 3): (a^T m^T)^T, `stack_mul` on the transposed
    stack. Many matrices: transposed in and out by `transposed` (a C-ordered result); a few (a
    live frame's): numpy's copy of the swapaxes view in, a view out (fewer numpy calls)."""
    a = np.asarray(a, float)
    if a.size < 9 * MANY_PRODUCTS:
        return stack_mul(a.swapaxes(-1, -2), np.asarray(m).T).swapaxes(-1, -2)
    return transposed(stack_mul(transposed(a), np.asarray(m).T))


_TRANSPOSE9 = np.array([0, 3, 6, 1, 4, 7, 2, 5, 8])  # row-major 3x3 -> its transpose


def transposed(a: np.ndarray) -> np.ndarray:
    """A stack of 3x3 matrices (..., 3, 3) transposed, as a new C-ordered array. Many matrices:
    entry by entry, nine copies each over the whole stack (numpy's copy of a swapaxes view loops
    over rows of 3: about four times the instructions); a few: one gather of the nine entries."""
    if a.size < 9 * MANY_PRODUCTS:
        return a.reshape(-1, 9).take(_TRANSPOSE9, axis=1).reshape(a.shape)
    out = np.empty(a.shape)
    for i in range(3):
        for j in range(3):
            out[..., i, j] = a[..., j, i]
    return out


def stack_apply(a: np.ndarray, v: np.ndarray) -> np.ndarray:
    """a @ v for a stack of 3x3 matrices a (..., 3, 3) and ONE vector v (3,) (see stack_mul)."""
    a = np.asarray(a, float)
    return (a.reshape(-1, 3) @ v).reshape(a.shape[:-1])


def matmul_stack(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a @ b item by item for stacks of 3x3 matrices (..., 3, 3) (b broadcast against a). numpy's
    stacked matmul makes one BLAS call per 3x3 product (over a thousand instructions each): from
    MANY_PRODUCTS items on, each entry is its three products summed over the whole stack at once,
    (a_i0 b_0k + a_i1 b_1k) + a_i2 b_2k. Decision: BLAS fuses each multiply-add (FMA), these sums
    round each step, so the last bit of an entry may differ (~1e-16) from np.matmul's."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    shape = a.shape if a.shape == b.shape else broadcast_shape(a.shape, b.shape)
    if math.prod(shape[:-2]) < MANY_PRODUCTS:
        return a @ b
    out = np.empty(shape)
    for i in range(3):
        for k in range(3):
            entry = out[..., i, k]
            np.multiply(a[..., i, 0], b[..., 0, k], out=entry)
            entry += a[..., i, 1] * b[..., 1, k]
            entry += a[..., i, 2] * b[..., 2, k]
    return out


# A stack of 3x3 products with fewer frames than this is one stacked matmul (one BLAS call per
# product, no Python loop); with more, one BLAS call per stack (`stack_mul`): the same products,
# bit for bit, either way.
STACKED_FRAMES = 8


def stacks_mul(a: np.ndarray, m: np.ndarray, rows=None) -> np.ndarray:
    """a[k] @ m[k] for K stacks a (K, F, 3, 3) (or a[rows[k]] of a bigger stack when `rows` is
    given) and K matrices m (K, 3, C): `stack_mul` stack by stack, with the Python loop only where
    the stacks are long (STACKED_FRAMES)."""
    m = np.asarray(m, float)
    if a.shape[1] < STACKED_FRAMES:
        return np.matmul(a if rows is None else _rows(a, rows), m[:, None])
    idx = range(len(a)) if rows is None else rows
    out = np.empty((len(idx),) + a.shape[1:-1] + (m.shape[-1],))
    for k, r in enumerate(idx):  # each product written where it goes (no temporary to copy)
        np.matmul(a[r].reshape(-1, 3), m[k], out=out[k].reshape(-1, m.shape[-1]))
    return out


def _rows(a: np.ndarray, rows) -> np.ndarray:
    """a[rows] (a copy): `take` on an index array (fancy indexing's bookkeeping costs several times
    more on a few rows)."""
    return a.take(rows, axis=0) if isinstance(rows, np.ndarray) else a[rows]


def stacks_apply(a: np.ndarray, v: np.ndarray, rows=None) -> np.ndarray:
    """a[k] @ v[k] for K stacks a (K, F, 3, 3) (or a[rows[k]]) and K vectors v (K, 3) -> (K, F, 3):
    `stack_apply` stack by stack (see stacks_mul)."""
    v = np.asarray(v, float)
    if a.shape[1] < STACKED_FRAMES:
        return np.matmul(a if rows is None else _rows(a, rows), v[:, None, :, None])[..., 0]
    idx = range(len(a)) if rows is None else rows
    out = np.empty((len(idx),) + a.shape[1:-1])
    for k, r in enumerate(idx):
        np.matmul(a[r].reshape(-1, 3), v[k], out=out[k].reshape(-1))
    return out


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) to unit quaternions, w >= 0 (Shepperd's method: per item, the
    best conditioned of the four candidates, computed for the items that pick it only)."""
    m = np.asarray(m, float)
    q = quat_from_rows(np.ascontiguousarray(m.reshape(-1, 9).T))  # (9, N): every operation on contiguous rows
    return q.T.reshape(m.shape[:-2] + (4,))


def quat_from_rows(comp: np.ndarray) -> np.ndarray:
    """`matrix_to_quat` of N matrices given as their entries' rows (9, N) (m00, m01, ..., m22):
    the quaternions' components (4, N)."""
    trace = comp[0] + comp[4] + comp[8]
    best = np.argmax(np.stack([trace, comp[0], comp[4], comp[8]]), axis=0)
    q = np.empty((4, comp.shape[1]))
    for k in range(4):
        cols = np.flatnonzero(best == k)
        if not len(cols):
            continue
        if len(cols) == len(best):
            cols = slice(None)
        q[:, cols] = SHEPPERD_CANDIDATES[k](*comp[:, cols])  # only the candidate these items pick
    q /= np.sqrt((q * q).sum(0))
    q *= np.where(q[0] < 0, -1.0, 1.0)
    return q


SHEPPERD_CANDIDATES = (  # matrix_to_quat's four candidates (w, x, y, z) from m00, m01, ..., m22
    lambda m00, m01, m02, m10, m11, m12, m20, m21, m22: (1 + m00 + m11 + m22, m21 - m12, m02 - m20, m10 - m01),
    lambda m00, m01, m02, m10, m11, m12, m20, m21, m22: (m21 - m12, 1 + m00 - m11 - m22, m01 + m10, m02 + m20),
    lambda m00, m01, m02, m10, m11, m12, m20, m21, m22: (m02 - m20, m01 + m10, 1 - m00 + m11 - m22, m12 + m21),
    lambda m00, m01, m02, m10, m11, m12, m20, m21, m22: (m10 - m01, m02 + m20, m12 + m21, 1 - m00 - m11 + m22),
)


def euler_matrices(angles: np.ndarray, order: str) -> np.ndarray:
    """(F, 3, 3) of Blender Euler angles (F, 3) in rotation mode `order` ("XYZ": X applied first)."""
    angles = np.asarray(angles, float)
    out = np.broadcast_to(np.eye(3), (len(angles), 3, 3)).copy()
    for axis in order:
        k = "XYZ".index(axis)
        c, s = np.cos(angles[:, k]), np.sin(angles[:, k])
        m = np.zeros((len(angles), 3, 3))
        i, j = [(1, 2), (2, 0), (0, 1)][k]
        m[:, k, k] = 1.0
        m[:, i, i] = c
        m[:, j, j] = c
        m[:, i, j] = -s
        m[:, j, i] = s
        out = m @ out
    return out


def axis_angle_to_quat(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Unit quaternions for turns by `angle` about `axis` (any length). A zero axis is no turn
    whatever the angle, as Blender reads a bone's axis-angle rotation."""
    unit = normalize(axis)
    half = 0.5 * np.asarray(angle, float)[..., None]
    q = np.concatenate([np.cos(half), np.sin(half) * unit], axis=-1)
    still = ~np.any(unit, axis=-1)
    return np.where(still[..., None], np.array([1.0, 0.0, 0.0, 0.0]), q)


def quat_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Shortest-arc rotation taking direction a to direction b; for opposite vectors, a half turn
    about an axis perpendicular to a."""
    a, b = normalize(a), normalize(b)
    if a.shape != b.shape:
        a, b = np.broadcast_arrays(a, b)
    d = (a * b).sum(-1)
    q = np.empty(d.shape + (4,))
    q[..., 0] = 1.0 + d
    q[..., 1:] = cross(a, b)
    opposite = d < -1.0 + 1e-9
    if opposite.any():
        perp = np.cross(a, np.array([1.0, 0.0, 0.0]))
        small = np.linalg.norm(perp, axis=-1, keepdims=True) < 1e-6
        perp = np.where(small, np.cross(a, np.array([0.0, 1.0, 0.0])), perp)
        q = np.where(opposite[..., None], np.concatenate([np.zeros(d.shape + (1,)), normalize(perp)], -1), q)
    return normalize(q)


def quat_angle(q: np.ndarray) -> np.ndarray:
    """Rotation angle in [0, pi]."""
    q = np.asarray(q, float)
    return 2.0 * np.arctan2(np.linalg.norm(q[..., 1:], axis=-1), np.abs(q[..., 0]))


def frame_from_axes(y_axis: np.ndarray, x_hint: np.ndarray) -> np.ndarray:
    """Rotation matrix whose columns are (x, y, z) with y along `y_axis` and x as close as
    possible to `x_hint` (Blender's bone convention: a bone points along its local +Y; for hinges
    local +X is the flexion axis)."""
    y = normalize(y_axis)
    x = normalize(x_hint - (x_hint * y).sum(-1, keepdims=True) * y)
    out = np.empty((y.shape if y.shape == x.shape else np.broadcast_shapes(y.shape, x.shape)) + (3,))
    out[..., 0], out[..., 1], out[..., 2] = x, y, cross(x, y)
    return out


def transform_points(pos: np.ndarray, rot: np.ndarray, local: np.ndarray) -> np.ndarray:
    """World positions of `local` points in frames (pos, rot quaternion): p + R local."""
    return np.asarray(pos, float) + rotate(rot, local)


def inverse_transform_points(pos: np.ndarray, rot: np.ndarray, world: np.ndarray) -> np.ndarray:
    """`world` points expressed in frames (pos, rot quaternion): R^-1 (w - p)."""
    return rotate(quat_conj(rot), np.asarray(world, float) - pos)


def continuous_quaternions(q: np.ndarray, *, in_place: bool = False) -> np.ndarray:
    """Flip signs along the frame axis (the first) so consecutive quaternions lie on one
    hemisphere: q and -q are the same rotation, but anything that interpolates or filters
    components (F-Curves, low-pass filters, key reduction) would swing through a half turn between
    them. Returns a new array, or `q` itself changed with `in_place` (a float64 array)."""
    q = q if in_place else np.array(q, dtype=float, copy=True)
    dots = np.einsum("...i,...i->...", q[1:], q[:-1])
    q[1:] *= np.cumprod(np.where(dots < 0, -1.0, 1.0), axis=0)[..., None]
    return q


def slerp(a: np.ndarray, b: np.ndarray, t: np.ndarray) -> np.ndarray:
    a, b = np.asarray(a, float), np.asarray(b, float)
    d = (a * b).sum(-1, keepdims=True)
    b = np.where(d < 0, -b, b)
    d = np.abs(d)
    t = np.asarray(t, float)[..., None] if np.ndim(t) else np.asarray(t, float)
    theta = np.arccos(np.clip(d, -1.0, 1.0))
    s = np.sin(theta)
    near = s < 1e-6
    wa = np.where(near, 1 - t, np.sin((1 - t) * theta) / np.where(near, 1, s))
    wb = np.where(near, t, np.sin(t * theta) / np.where(near, 1, s))
    return normalize(wa * a + wb * b)
