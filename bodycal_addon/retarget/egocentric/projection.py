"""Projection kernels: each target point projected on each surface element, with the surface
coordinates that re-pose the projection on another body and the angular factor of its weight
(Delahaye 2023, appendix D)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ...core.transforms import EPS, broadcast_shape, unit_and_norm
from .surface import PosedSurface

FACTOR_BLEND = 0.002  # m: distance beyond the nearest over which a mesh triangle's factor fades (project_components)
PENETRATION_TOLERANCE = 0.01  # m: see _triangle_factor

@dataclass
class Projections:
    """Projections of P target points on the E elements of a PosedSurface, per frame.

    x, v: (F, P, E, 3) closest points and v = p - x; dist: (F, P, E) |v|; factor: (F, P, E) the
    angular factor of the raw weight (capsule |sin(v, axis)|, sphere 1, triangle max(0, cos(v, n)));
    surface coordinates: capsules `cap_t` (F, P, C) axial fraction and `cap_dir` (F, P, C, 3) unit
    direction from the axis in the bone frame; spheres `sph_dir` (F, P, S, 3) in the bone frame;
    meshes `tri_index` (F, P, M) the closest triangle (index into surface.tri) and `tri_bary`
    (F, P, M, 3) its barycentric coordinates."""

    x: np.ndarray
    v: np.ndarray
    dist: np.ndarray
    factor: np.ndarray
    cap_t: np.ndarray
    cap_dir: np.ndarray
    sph_dir: np.ndarray
    tri_index: np.ndarray
    tri_bary: np.ndarray


def _comp(a) -> np.ndarray:
    """(..., 3) -> (3, ...) contiguous. The hot path keeps vector components first, so every
    operation runs over contiguous arrays (numpy is several times slower on a trailing axis of 3)."""
    a = _floating(a)
    return np.ascontiguousarray(a.transpose((a.ndim - 1,) + tuple(range(a.ndim - 1))))


def _rot_comp(rot) -> np.ndarray:
    """(F, X, 3, 3) -> (3, 3, F, 1, X): R_ij as contiguous (F, 1, X) arrays (1 = the target axis)."""
    return np.ascontiguousarray(_floating(rot).transpose(2, 3, 0, 1))[:, :, :, None, :]


def _floating(a) -> np.ndarray:
    """float32 stays float32 (the pipeline maps in single precision); anything else is float64."""
    a = np.asarray(a)
    return a if a.dtype == np.float32 else a.astype(float, copy=False)


def dot3(a, b):
    """The dot product of vectors in components-first layout (3, ...), over their first axis."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _apply(rc, v):
    """R v for (3, 3, ...) rotation components and (3, ...) vectors."""
    return _rows_dot(rc, v, transpose=False)


def _apply_t(rc, v):
    """R^T v (world -> bone frame)."""
    return _rows_dot(rc, v, transpose=True)


SMALL_ROWS = 4096  # items per row up to which `_rows_dot` computes the three rows at once


def _rows_dot(rc, v, transpose):
    shape = broadcast_shape(rc.shape[2:], v.shape[1:])
    if math.prod(shape) <= SMALL_ROWS:
        # A few items (a live frame): the three rows in three products and two sums, each row's
        # the same r0 v0 + r1 v1 + r2 v2 in the same order as the loop below, in a fifth of the calls.
        r = rc if transpose else rc.swapaxes(0, 1)  # r[k] holds every row's k-th entry
        out = r[0] * v[0]
        out += r[1] * v[1]
        out += r[2] * v[2]
        return out
    out = np.empty((3,) + shape, np.result_type(rc, v))
    tmp = np.empty(out.shape[1:], out.dtype)
    for i in range(3):
        r = rc[:, i] if transpose else rc[i]
        np.multiply(r[0], v[0], out=out[i])
        for k in (1, 2):  # in place: no temporaries beyond one
            np.multiply(r[k], v[k], out=tmp)
            out[i] += tmp
    return out


def ericson_terms(ap, ab, ac, dot=None) -> tuple:
    """The dot products and areas Ericson's regions are tested on (Real-Time Collision Detection
    5.1.5), components first (3, ...): d1..d6 and the barycentric areas va, vb, vc. `dot`: the
    components-first dot product (`dot3` by default; one frame's takes fewer calls)."""
    dot = dot or dot3
    d1 = dot(ab, ap)
    d2 = dot(ac, ap)
    abab = dot(ab, ab)
    acac = dot(ac, ac)
    abac = dot(ab, ac)
    d3, d4 = d1 - abab, d2 - abac  # (p - b).ab, (p - b).ac
    d5, d6 = d1 - abac, d2 - acac  # (p - c).ab, (p - c).ac
    vc = d1 * d4 - d3 * d2
    vb = d5 * d2 - d1 * d6
    va = d3 * d6 - d5 * d4
    return d1, d2, d3, d4, d5, d6, va, vb, vc


def safe_divide(num, den):
    """num / den, 0 where den is 0 (a degenerate triangle's region)."""
    return num / np.where(den != 0, den, 1.0)


def closest_on_triangles(ap, ab, ac, dot=None):
    """Ericson's closest point on a triangle (Real-Time Collision Detection 5.1.5), branch-free
    over arrays in components-first layout: ap = p - a (3, F, P, T), ab, ac (3, F, 1, T).
    Returns the barycentric weights (v, w) of b and c, (F, P, T). `dot`: ericson_terms' (one
    frame's pairs (3, N) take its two-call dot product: the same values, fewer calls)."""
    d1, d2, d3, d4, d5, d6, va, vb, vc = ericson_terms(ap, ab, ac, dot)
    denom = va + vb + vc
    inside_v, inside_w = safe_divide(vb, denom), safe_divide(vc, denom)
    e_ab = safe_divide(d1, d1 - d3)
    e_ac = safe_divide(d2, d2 - d6)
    e_bc = safe_divide(d4 - d3, (d4 - d3) + (d5 - d6))
    # Ericson's early returns in order A, B, AB, C, AC, BC, inside: applied in reverse so the
    # first region that holds wins.
    # (in place on the inside's arrays, this call's own: np.where's selection without its copies)
    bv, bw = inside_v, inside_w
    bc = (va <= 0) & (d4 >= d3) & (d5 >= d6)
    ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    c = (d6 >= 0) & (d5 <= d6)
    ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    b = (d3 >= 0) & (d4 <= d3)
    a = (d1 <= 0) & (d2 <= 0)
    # Decision (speed): consecutive regions that set the same constant are one pass on their
    # masks' union (the same values: 9 float passes instead of 12, the 3 unions on bytes).
    np.putmask(bv, bc, 1 - e_bc)
    np.putmask(bw, bc, e_bc)
    np.putmask(bw, ac, e_ac)
    np.putmask(bw, c, 1.0)
    np.putmask(bv, np.bitwise_or(ac, c, out=ac), 0.0)  # AC then C: v = 0
    np.putmask(bv, ab, e_ab)
    np.putmask(bv, b, 1.0)
    np.putmask(bv, a, 0.0)
    ab |= b
    ab |= a
    np.putmask(bw, ab, 0.0)  # AB, B then A: w = 0
    return bv, bw


@dataclass
class ProjectionsCF:
    """Projections in components-first layout (the hot path); see Projections for the meaning."""

    x: np.ndarray  # (3, F, P, E)
    v: np.ndarray  # (3, F, P, E)
    dist: np.ndarray  # (F, P, E)
    factor: np.ndarray  # (F, P, E)
    cap_t: np.ndarray  # (F, P, C)
    cap_dir: np.ndarray  # (3, F, P, C) unit direction from the axis, in the bone frame
    sph_dir: np.ndarray  # (3, F, P, S) in the bone frame
    tri_index: np.ndarray  # (F, P, M)
    tri_bary: np.ndarray  # (3, F, P, M)

    def public(self, surface: PosedSurface) -> Projections:
        m = np.moveaxis
        return Projections(m(self.x, 0, -1), m(self.v, 0, -1), self.dist, self.factor, self.cap_t,
                           m(self.cap_dir, 0, -1), m(self.sph_dir, 0, -1), self.tri_index, m(self.tri_bary, 0, -1))


def project_components(p, surface: PosedSurface, tol: float, coords: bool = True) -> ProjectionsCF:
    """Every point of p (F, P, 3) projected on every element of `surface`, components first.
    `coords=False` gives v and dist only (the rest None): what a nearest distance reads
    (`distances`), without the angular factors and surface coordinates the mapping needs."""
    F, P = p.shape[:2]
    pc = _comp(p)[..., None]  # (3, F, P, 1)
    C, S, M = surface.counts
    # Capsules: closest point on the axis segment pushed out by the radius interpolated along it.
    a = _comp(surface.caps_head)[:, :, None, :]
    ab = _comp(surface.caps_tail)[:, :, None, :] - a
    abab = np.maximum(dot3(ab, ab), 1e-24)
    ap = pc - a
    t = np.minimum(np.maximum(dot3(ap, ab) / abab, 0.0), 1.0)  # np.clip's values
    rc = _rot_comp(surface.caps_rot)
    d, n = unit_and_norm(ap - t * ab, rc[:, 0], axis=0)  # on the axis: the bone's +X
    r = surface.caps_radius[:, 0] + t * (surface.caps_radius[:, 1] - surface.caps_radius[:, 0])
    cap_v = (n - r) * d
    # Spheres.
    sc = _comp(surface.sph_center)[:, :, None, :]
    src = _rot_comp(surface.sph_rot)
    sd, sn = unit_and_norm(pc - sc, src[:, 1], axis=0)
    sph_v = (sn - surface.sph_radius) * sd
    # Meshes: the closest triangle of each element.
    if M:
        ta = _comp(surface.tri[:, :, 0])[:, :, None, :]
        tab = _comp(surface.tri[:, :, 1])[:, :, None, :] - ta
        tac = _comp(surface.tri[:, :, 2])[:, :, None, :] - ta
        tap = pc - ta
        bv, bw = closest_on_triangles(tap, tab, tac)
        tv = tap - bv * tab - bw * tac  # p - x
        td2 = dot3(tv, tv)
        starts, of_tri = _mesh_layout(tuple(surface.mesh_slices))
        T = td2.shape[-1]
        # Each mesh's closest triangle: one argmin per mesh over its triangles (argmin takes the
        # first minimum). Decision (speed, the same indices): once one argmin over the meshes'
        # triangles gathered side by side, each row padded with +inf to the largest mesh; the
        # gather and padding cost more than the argmins they saved (a bake block of 105 frames x 7
        # targets x 24 triangles in 5 meshes: 15.2 -> 14.6 M instructions).
        sel = np.empty((F, P, M), np.intp)
        for m, (a, b) in enumerate(surface.mesh_slices):
            np.add(td2[..., a:b].argmin(axis=-1), a, out=sel[..., m])
        # The closest triangles' values gathered by one flat index (F P T -> F P M).
        flat = (np.arange(F * P)[:, None] * T + sel.reshape(F * P, M)).reshape(-1)
        mesh_v = tv.reshape(3, -1).take(flat, axis=1).reshape(3, F, P, M)
    else:
        sel = np.zeros((F, P, 0), int)
        mesh_v = np.zeros((3, F, P, 0), pc.dtype)
    v = np.concatenate([cap_v, sph_v, mesh_v], axis=-1)
    dist = np.sqrt(dot3(v, v))
    if not coords:
        return ProjectionsCF(None, v, dist, *([None] * 6))
    cos_ax = dot3(d, ab) / np.sqrt(abab)  # v is parallel to d, also when v -> 0
    cap_factor = np.sqrt(np.minimum(np.maximum(1.0 - cos_ax * cos_ax, 0.0), 1.0))
    if M:
        bv, bw = bv.reshape(-1).take(flat).reshape(F, P, M), bw.reshape(-1).take(flat).reshape(F, P, M)
        tri_bary = np.stack([1.0 - bv - bw, bv, bw])
        # Decision: the angular factor is every triangle's own, weighted by how close the triangle
        # is to being the nearest (exp(-(d_t - d_min) / FACTOR_BLEND)). A closest point on an
        # edge or a corner is the closest point of every triangle that shares it, whose normals
        # differ: taking the nearest triangle's factor let rounding pick it, and a point leaving a
        # corner for an edge dropped the corner's other triangles at once (steps of 1 cm in the
        # mapped target for 0.3 mm of motion beside the crude torso). Each triangle's factor and
        # distance move continuously, so the blend does.
        tri_factor = _triangle_factor(tv, _comp(surface.tri_normal)[:, :, None, :], tol)  # (F, P, T)
        td = np.sqrt(td2)
        closest = td.reshape(-1).take(flat).reshape(F, P, M).take(of_tri, axis=2)  # (F, P, T) its mesh's min
        near = np.exp((closest - td) * (1.0 / FACTOR_BLEND))
        mesh_factor = np.add.reduceat(near * tri_factor, starts, axis=2) / np.add.reduceat(near, starts, axis=2)
    else:
        tri_bary = np.zeros((3, F, P, 0), pc.dtype)
        mesh_factor = np.zeros((F, P, 0), pc.dtype)
    x = pc - v
    factor = np.concatenate([cap_factor, np.ones((F, P, S), pc.dtype), mesh_factor], axis=-1)
    # Surface coordinates in the bone frames: what re-poses the projection on another body.
    return ProjectionsCF(x, v, dist, factor, t, _apply_t(rc, d), _apply_t(src, sd), sel, tri_bary)


@lru_cache(maxsize=64)
def _mesh_layout(mesh_slices: tuple) -> tuple[np.ndarray, np.ndarray]:
    """Once per mesh layout: each mesh's first triangle (M,) and each triangle's mesh (T,)."""
    starts = np.array([a for a, _ in mesh_slices], int)
    sizes = [b - a for a, b in mesh_slices]
    return starts, np.repeat(np.arange(len(mesh_slices)), sizes)


def project(points: np.ndarray, surface: PosedSurface, penetration_tolerance: float = PENETRATION_TOLERANCE
            ) -> Projections:
    """Project (F, P, 3) points on every element of `surface` (Delahaye 2023, appendix C, Figure 12)."""
    return project_components(_floating(points), surface, penetration_tolerance).public(surface)


def distances(points: np.ndarray, surface: PosedSurface) -> np.ndarray:
    """(F, P, E) each of (F, P, 3) points' distance to each element of `surface`: `project`'s
    dist, bit for bit, without the weights' factors and surface coordinates it does not read."""
    return project_components(_floating(points), surface, PENETRATION_TOLERANCE, coords=False).dist


def _triangle_factor(v, normal, tol):
    """max(0, cos(v, n)) (Delahaye 2023, appendix C, raw contributions), components first. Decision:
    the angle is taken from the triangle plane shifted `tol` into the body, so a target that sinks
    a few millimetres into the crude mesh (calibration noise) keeps its contact weight instead of
    dropping to zero; at v = 0 the factor is 1 (a target on the surface)."""
    w = v + tol * normal
    wn = np.sqrt(dot3(w, w))
    cos = np.divide(dot3(w, normal), wn, out=np.ones_like(wn), where=wn > EPS)
    return np.maximum(cos, 0.0)


def _triangle_frames(tri, normal):
    """(F, T, 3, 3) frames of triangles: columns first edge, normal x edge, normal."""
    e1 = tri[:, :, 1] - tri[:, :, 0]
    e1 = e1 / np.maximum(np.linalg.norm(e1, axis=-1, keepdims=True), 1e-15)
    return np.stack([e1, np.cross(normal, e1), normal], axis=-1)


@lru_cache(maxsize=64)
def _mesh_pairing(user_slices: tuple, avatar_slices: tuple) -> tuple[np.ndarray, np.ndarray]:
    """(whether each mesh has as many triangles on both bodies, the offset that takes the user's
    triangle index to the avatar's: the same position inside the element), once per mesh layout."""
    same = np.array([(ue - us) == (ae - as_) for (us, ue), (as_, ae) in zip(user_slices, avatar_slices)])
    offset = np.array([as_ - us for (us, _), (as_, _) in zip(user_slices, avatar_slices)])
    return same, offset, bool(same.all())


def repose_components(pr: ProjectionsCF, user: PosedSurface, avatar: PosedSurface, turn_v: bool = False):
    """(x', v'): x' re-posed on the avatar (see `repose`); v' = v, or with `turn_v` the user's v
    carried by each element's local frame onto the avatar's (bone frame for capsules and spheres,
    triangle frame for meshes), so it keeps its angle to the avatar's surface."""
    F, P = pr.v.shape[1:3]
    C, S, M = avatar.counts
    a = _comp(avatar.caps_head)[:, :, None, :]
    ab = _comp(avatar.caps_tail)[:, :, None, :] - a
    t = pr.cap_t
    r = avatar.caps_radius[:, 0] + t * (avatar.caps_radius[:, 1] - avatar.caps_radius[:, 0])
    # The same direction in the avatar's bone frame.
    cap_rot, sph_rot = _rot_comp(avatar.caps_rot), _rot_comp(avatar.sph_rot)
    cap = a + t * ab + r * _apply(cap_rot, pr.cap_dir)
    sph = _comp(avatar.sph_center)[:, :, None, :] + avatar.sph_radius * _apply(sph_rot, pr.sph_dir)
    v_parts = None
    if turn_v:  # v turned by R' R^T
        v_parts = [_apply(cap_rot, _apply_t(_rot_comp(user.caps_rot), pr.v[..., :C])),
                   _apply(sph_rot, _apply_t(_rot_comp(user.sph_rot), pr.v[..., C:C + S]))]
    if M:
        same, offset, all_same = _mesh_pairing(tuple(user.mesh_slices), tuple(avatar.mesh_slices))
        idx = pr.tri_index + offset if all_same else np.where(same, pr.tri_index + offset, avatar.mesh_slices[0][0])
        fi = np.arange(F)[:, None, None]
        # The corners of every pair's triangle in one gather, (corner, component, F, P, M), from
        # the triangles made corner and component first (contiguous products below); the
        # barycentric sum corner by corner as before (0 + b0 c0 + b1 c1 + b2 c2, the same bits).
        T = avatar.tri.shape[1]
        corners = np.ascontiguousarray(avatar.tri.transpose(2, 3, 0, 1)).reshape(3, 3, F * T).take(
            (fi * T + idx).reshape(-1), axis=2).reshape(3, 3, F, P, M)
        mesh = (pr.tri_bary[0] * corners[0]).astype(pr.v.dtype, copy=False)
        mesh += pr.tri_bary[1] * corners[1]
        mesh += pr.tri_bary[2] * corners[2]
        if turn_v:
            to_avatar = np.concatenate([np.arange(us, ue) + (as_ - us) if ok else np.full(ue - us, as_)
                                        for (us, ue), (as_, _), ok in zip(user.mesh_slices, avatar.mesh_slices, same)])
            rel = (_triangle_frames(avatar.tri, avatar.tri_normal)[:, to_avatar]
                   @ _triangle_frames(user.tri, user.tri_normal).swapaxes(-1, -2))  # (F, T, 3, 3)
            rel = np.ascontiguousarray(rel.transpose(2, 3, 0, 1))[:, :, fi, pr.tri_index]  # (3, 3, F, P, M)
            mesh_v = _apply(rel, pr.v[..., C + S:])
        if not all_same:
            # Different triangles (e.g. palms with other point counts): the element bone's frame,
            # scaled by the bone length ratio.
            bad = np.flatnonzero(~same)
            xm = pr.x[:, :, :, C + S + bad]
            local = _apply_t(_rot_comp(user.mesh_rot[:, bad]), xm - _comp(user.mesh_head[:, bad])[:, :, None, :])
            scale = avatar.mesh_scale[bad] / np.maximum(user.mesh_scale[bad], 1e-9)
            bone_rel = _rot_comp(avatar.mesh_rot[:, bad] @ user.mesh_rot[:, bad].swapaxes(-1, -2))
            mesh[:, :, :, bad] = (_comp(avatar.mesh_head[:, bad])[:, :, None, :]
                                  + _apply(_rot_comp(avatar.mesh_rot[:, bad]), local * scale))
            if turn_v:
                mesh_v[:, :, :, bad] = _apply(bone_rel, pr.v[..., C + S + bad])
        if turn_v:
            v_parts.append(mesh_v)
    else:
        mesh = np.zeros((3, F, P, 0), pr.v.dtype)
        if turn_v:
            v_parts.append(np.zeros((3, F, P, 0), pr.v.dtype))
    x = np.concatenate([cap, sph, mesh], axis=-1)
    return x, (np.concatenate(v_parts, axis=-1) if turn_v else pr.v)


def repose(proj: Projections, user: PosedSurface, avatar: PosedSurface) -> np.ndarray:
    """x'_ij: the user's projections re-posed on the avatar's elements from their surface
    coordinates (capsule: axial fraction + direction in the bone frame; sphere: direction;
    triangle: barycentric). A mesh whose triangles differ between user and avatar falls back to
    the element bone's frame, scaled by the bone length ratio. Returns (F, P, E, 3)."""
    m = np.moveaxis
    pr = ProjectionsCF(m(proj.x, -1, 0), m(proj.v, -1, 0), proj.dist, proj.factor, proj.cap_t, m(proj.cap_dir, -1, 0),
                       m(proj.sph_dir, -1, 0), proj.tri_index, m(proj.tri_bary, -1, 0))
    return m(repose_components(pr, user, avatar)[0], 0, -1)
