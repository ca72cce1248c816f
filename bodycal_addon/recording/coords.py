"""Coordinate conventions of recording files (FORMATS.md §1, §2): the `coords` object, the
conversion of positions and device rotations to and from the internal frame (Blender's:
right-handed, Z up, metres), and the refusal of damaged values before any arithmetic runs on them.
Shared by every reader (JSON, CSV, C3D) and the writer; numpy only.

Conventions of the files (`coords`):

- `up="Y", handedness="right"` (SteamVR / OpenXR: x right, y up, -z forward): (x, y, z) -> (x, -z, y),
  a +90 degree turn about X, so the performer's forward (-z) becomes +Y.
- `up="Y", handedness="left"` (Unity: x right, y up, +z forward): (x, y, z) -> (x, z, y); the same
  physical scene lands where the SteamVR one does.
- `up="Z", handedness="right"`: unchanged. `up="Z", handedness="left"` (Unreal: x forward, y right,
  z up): (x, y, z) -> (x, -y, z).
- units `m`, `cm`, `mm` scale positions.

Device rotations: world positions go through the conversion matrix M; device-local frames keep
the OpenXR / Blender-camera convention (x right, y up, -z forward), so R' = M R for right-handed
files. A left-handed file also has left-handed device frames: they are mirrored along their local
z (R' = M R P, P = diag(1, 1, -1)) so that local -z stays the device's forward. A device-local point
l (with l' = P l) therefore maps to the same world point before and after conversion.
"""

from __future__ import annotations

import functools

import numpy as np

from ..core import transforms as tf
from ..core.errors import BodyCalError, short_repr

UNITS = {"m": 1.0, "cm": 0.01, "mm": 0.001}
UPS = ("Y", "Z")
HANDEDNESS = ("right", "left")
QUAT_TOLERANCE = 1e-3  # FORMATS.md §1: renormalise within 1e-3, reject beyond
MAX_POSITION_M = 1e4  # FORMATS.md §1: a position 10 km or more from the origin is a damaged value

_AXIS_MAPS = {
    ("Y", "right"): np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]),
    ("Y", "left"): np.array([[1.0, 0, 0], [0, 0, 1], [0, 1, 0]]),
    ("Z", "right"): np.eye(3),
    ("Z", "left"): np.diag([1.0, -1.0, 1.0]),
}
_LOCAL_MIRROR = np.diag([1.0, 1.0, -1.0])


def check_coords(coords, source: str) -> tuple[str, str, str]:
    """(up, handedness, units) from a `coords` object, with the FORMATS.md defaults."""
    if coords is None:
        coords = {}
    if not isinstance(coords, dict):
        raise BodyCalError("must be an object like {\"up\": \"Y\", \"handedness\": \"right\", \"units\": \"m\"}",
                           source=source, field="coords")
    unknown = set(coords) - {"up", "handedness", "units"}
    if unknown:
        raise BodyCalError(f"unknown field(s) {sorted(unknown)}", source=source, field="coords",
                           hint="allowed: up, handedness, units")
    up = coords.get("up", "Y")
    hand = coords.get("handedness", "right")
    units = coords.get("units", "m")
    if not isinstance(up, str) or up.upper() not in UPS:
        raise BodyCalError(f"'{up}' is not an up axis", source=source, field="coords.up", hint="use \"Y\" or \"Z\"")
    if not isinstance(hand, str) or hand.lower() not in HANDEDNESS:
        raise BodyCalError(f"'{hand}' is not a handedness", source=source, field="coords.handedness",
                           hint="use \"right\" or \"left\"")
    if not isinstance(units, str) or units.lower() not in UNITS:
        raise BodyCalError(f"'{units}' is not a unit", source=source, field="coords.units",
                           hint="use \"m\", \"cm\" or \"mm\"")
    return up.upper(), hand.lower(), units.lower()


def conversion(up: str, handedness: str, units: str) -> tuple[np.ndarray, np.ndarray]:
    """(M, P): internal = scale * M @ file for points; R_internal = M R_file P for device frames."""
    m = _AXIS_MAPS[(up, handedness)] * UNITS[units]
    p = _LOCAL_MIRROR if handedness == "left" else np.eye(3)
    return m, p


def to_internal(positions: np.ndarray, rotations: np.ndarray | None, up="Y", handedness="right", units="m"):
    """Convert positions (..., 3) and rotations (..., 4) from a file convention to the internal frame."""
    m, p = conversion(up, handedness, units)
    pos = np.asarray(positions, float) @ m.T
    if rotations is None:
        return pos, None
    rot = _convert_rotations(np.asarray(rotations, float), m / UNITS[units], p)
    return pos, rot


def from_internal(positions: np.ndarray, rotations: np.ndarray | None, up="Y", handedness="right", units="m"):
    """Inverse of `to_internal`."""
    m, p = conversion(up, handedness, units)
    minv = np.linalg.inv(m)
    pos = np.asarray(positions, float) @ minv.T
    if rotations is None:
        return pos, None
    a = m / UNITS[units]
    rot = _convert_rotations(np.asarray(rotations, float), a.T, p)  # R = A^T R' P (A, P orthogonal, P = P^T)
    return pos, rot


def turns_to_internal(rotations: np.ndarray, up="Y", handedness="right") -> np.ndarray:
    """Quaternions (..., 4) of turns written in a file convention (a bone's rotation relative to its
    parent's, a pose relative to a rest pose: rotations between two frames of one body, not a
    device's frame in the room) as the same turns in the internal frame: R' = A R A^T, A the axis
    map. Unlike a device frame there is no local mirror: the identity stays the identity, and a
    turn about the file's up axis by +a is a turn about +Z by +a (right-handed) or -a (left-handed,
    as a mirror reverses the sense of every turn)."""
    a = _AXIS_MAPS[(up, handedness)]
    return tf.matrix_to_quat(a @ tf.quat_to_matrix(np.asarray(rotations, float)) @ a.T)


def turns_from_internal(rotations: np.ndarray, up="Y", handedness="right") -> np.ndarray:
    """Inverse of `turns_to_internal`: R = A^T R' A."""
    a = _AXIS_MAPS[(up, handedness)]
    return tf.matrix_to_quat(a.T @ tf.quat_to_matrix(np.asarray(rotations, float)) @ a)


def _convert_rotations(q: np.ndarray, a: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Quaternions of A R P (A, P orthogonal, det(A P) = +1), by quaternion products only, so that
    the sign of the input (and the continuity of a track) is kept."""
    q = np.array(q, float)
    if p[2, 2] < 0:  # P is the identity or the mirror along z (`conversion`)
        # A R P = (A P)(P R P); for the mirror P = diag(1, 1, -1), P R P = (-P) R (-P)^-1 with -P a half
        # turn about z, whose quaternion keeps w and turns the vector part: (w, -x, -y, z).
        q *= np.array([1.0, -1.0, -1.0, 1.0])
        a = a @ p
    qa = _turn_of(np.ascontiguousarray(a, float).tobytes())
    return q if qa is None else tf.quat_mul(qa, q)


@functools.lru_cache(maxsize=32)
def _turn_of(a_bytes: bytes) -> np.ndarray | None:
    """The quaternion of a conversion's axis map (None: the identity), once per map: a live source
    converts every frame it receives (recording/live/vmc.py)."""
    a = np.frombuffer(a_bytes).reshape(3, 3)
    return None if np.allclose(a, np.eye(3)) else tf.matrix_to_quat(a)


def check_positions(values: np.ndarray, valid: np.ndarray, unit_scale: float, source: str, fields, where_of) -> None:
    """Refuse a tracked position (file units, (F, N, 3)) at MAX_POSITION_M or more from the origin
    once in metres: one line naming the file, `fields[n]` and `where_of(frame, n)`. Compared in the
    file's units, so no arithmetic ever runs on the absurd value (no overflow warnings)."""
    if values.size == 0:
        return
    limit = MAX_POSITION_M / unit_scale
    with np.errstate(invalid="ignore"):
        bad = valid & ~(np.abs(values) < limit).all(axis=-1)
    if bad.any():
        f, i = (int(x) for x in np.argwhere(bad)[0])
        raise BodyCalError(f"position {short_repr(values[f, i].tolist())} is {MAX_POSITION_M:g} m or more from "
                           "the origin",
                           source=source, field=fields[i], where=where_of(f, i),
                           hint="positions are in the declared units from the room's origin; the value is damaged")


def check_quaternions(rotations, valid, time, devices, source, unit="frame", where_of=None):
    """Renormalise quaternions within QUAT_TOLERANCE of unit length, reject the others (in place)."""
    if rotations.size == 0:
        return
    with np.errstate(over="ignore", invalid="ignore"):  # a damaged 1e300 component: refused below, no warning
        norm = np.linalg.norm(rotations, axis=-1)
        bad = valid & ~(np.abs(norm - 1.0) <= QUAT_TOLERANCE)
    if bad.any():
        f, i = (int(x) for x in np.argwhere(bad)[0])
        what = "zero" if norm[f, i] < 1e-9 else f"not unit length (|q| = {norm[f, i]:.6g})"
        where = where_of(f, i) if where_of else f"{unit} {f}"
        raise BodyCalError(f"quaternion is {what}", source=source, field=f"poses.{devices[i].name}", where=where,
                           hint="write w, x, y, z of a unit quaternion")
    ok = valid & (norm > 0)
    rotations[ok] /= norm[ok][:, None]
    rotations[~valid] = (1.0, 0.0, 0.0, 0.0)
