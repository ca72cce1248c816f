"""Rotation helpers of the outside tool (its own, on purpose: nothing shared with the engine, so a
convention slip on either side shows up instead of cancelling out). Matrices act on column
vectors; quaternions are (w, x, y, z); leading axes are frames."""

from __future__ import annotations

import numpy as np


def unit(v):
    v = np.asarray(v, float)
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return v / np.where(n > 1e-15, n, 1.0)


def axis_angle(axis, angle):
    """Rotation matrices (..., 3, 3) about unit-ised `axis` (..., 3) by `angle` (...) radians."""
    axis = unit(axis)
    angle = np.asarray(angle, float)
    shape = np.broadcast_shapes(axis.shape[:-1], angle.shape)
    x, y, z = (np.broadcast_to(axis[..., i], shape) for i in range(3))
    c, s = np.cos(angle), np.sin(angle)
    t = 1.0 - c
    return np.stack([
        np.stack([c + x * x * t, x * y * t - z * s, x * z * t + y * s], -1),
        np.stack([y * x * t + z * s, c + y * y * t, y * z * t - x * s], -1),
        np.stack([z * x * t - y * s, z * y * t + x * s, c + z * z * t], -1),
    ], -2)


def about(axis_name: str, angle):
    """Elementary rotation about X, Y or Z."""
    return axis_angle(np.eye(3)["XYZ".index(axis_name)], angle)


def log(m):
    """Rotation vectors (..., 3) of rotation matrices (angle in [0, pi])."""
    m = np.asarray(m, float)
    c = np.clip((np.trace(m, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    angle = np.arccos(c)
    v = np.stack([m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], -1)
    s = np.sin(angle)
    small = s < 1e-6
    out = v / np.where(small, 1.0, 2.0 * s)[..., None] * angle[..., None]
    # near pi: the axis from the symmetric part
    near_pi = small & (angle > 1.0)
    if np.any(near_pi):
        sym = (m[near_pi] + np.eye(3)) / 2.0
        k = np.argmax(np.diagonal(sym, axis1=-2, axis2=-1), axis=-1)
        ax = unit(sym[np.arange(len(k)), :, k])
        out[near_pi] = ax * angle[near_pi][..., None]
    return np.where(small[..., None] & ~near_pi[..., None], v / 2.0, out)


def exp(v):
    v = np.asarray(v, float)
    angle = np.linalg.norm(v, axis=-1)
    return axis_angle(np.where(angle[..., None] > 1e-15, v, np.array([1.0, 0, 0])), angle)


def to_quat(m):
    """(w, x, y, z) of rotation matrices, w >= 0."""
    m = np.asarray(m, float)
    w = np.sqrt(np.maximum(0.0, 1.0 + m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2])) / 2.0
    x = np.sqrt(np.maximum(0.0, 1.0 + m[..., 0, 0] - m[..., 1, 1] - m[..., 2, 2])) / 2.0
    y = np.sqrt(np.maximum(0.0, 1.0 - m[..., 0, 0] + m[..., 1, 1] - m[..., 2, 2])) / 2.0
    z = np.sqrt(np.maximum(0.0, 1.0 - m[..., 0, 0] - m[..., 1, 1] + m[..., 2, 2])) / 2.0
    x = np.copysign(x, m[..., 2, 1] - m[..., 1, 2])
    y = np.copysign(y, m[..., 0, 2] - m[..., 2, 0])
    z = np.copysign(z, m[..., 1, 0] - m[..., 0, 1])
    q = np.stack([w, x, y, z], -1)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def from_quat(q):
    q = unit(q)
    w, x, y, z = (q[..., i] for i in range(4))
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def interpolate(m0, m1, t):
    """Geodesic interpolation between rotation matrices m0 and m1 (broadcast) at fractions t."""
    t = np.asarray(t, float)
    rel = np.swapaxes(m0, -1, -2) @ m1
    return m0 @ exp(log(rel) * t[..., None])


def basis(d0, a0, d, a):
    """The rotation taking the orthonormalised pair (d0, a0) onto (d, a): d0 -> d exactly, a0 onto
    the part of a perpendicular to d."""
    def frame(u, v):
        u = unit(u)
        v = unit(v - np.sum(v * u, -1, keepdims=True) * u)
        return np.stack([u, v, np.cross(u, v)], -1)

    return frame(d, a) @ np.swapaxes(frame(d0, a0), -1, -2)


def yaw(angle):
    """Rotation about +Z (the outside tool's lab frame is Z up)."""
    return about("Z", angle)
