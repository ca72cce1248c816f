"""A Recording from sampled world matrices: the animated objects of a scene (trackers and
controllers recorded by another tool, empties of another add-on) read as devices and markers
(FORMATS.md §2.5). The Blender glue samples the matrices (`blender/scene_objects.py`); this module
turns them into device poses, numpy only.

- A device's pose is its object's world matrix without scale: the translation, and the rotation
  part with each column normalised (an object's own scale), or its nearest rotation (polar
  decomposition) where a non-uniformly scaled parent has sheared it. A mirrored object (negative
  determinant) has no device frame and is refused.
- An object whose name ends with a marker name of FORMATS.md §2.1 (`index_tip_r`, `hand_led2_l`,
  after a `.`, `_`, `:`, `-`, space or `|`) is that marker (its position only); the others are
  devices named after their objects.
- A device's kind is the one it is given, else guessed from its name (`guess_kind`); its role the
  one it is given, else none (the T-pose or the user assigns it).
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from ..body.skeleton import FINGERS
from ..core import transforms as tf
from ..core.errors import BodyCalError
from .coords import check_positions
from .model import DEVICE_KINDS, ROLES, Device, Recording, Segment

MARKER_RE = re.compile(rf"(?:^|[._:|\- ])((?:{'|'.join(FINGERS)})_tip_[lr]|hand_led[123]_[lr])$", re.IGNORECASE)
# Words of a name that say what the device is (any case; CamelCase and separators split words).
KIND_WORDS = (
    ("hmd", ("hmd", "head", "headset", "helmet", "visor")),
    ("rigid_body", ("glove", "gloves", "rigidbody")),
    ("controller", ("controller", "ctrl", "hand", "wand", "knuckles", "grip")),
)
ORTHONORMAL_TOL = 1e-4  # largest |R^T R - I| entry accepted without the polar decomposition


@dataclass
class SampledObject:
    """One sampled object: its name, and what it was given (a kind and a role of its own)."""

    name: str
    kind: str | None = None
    role: str | None = None


def name_words(name: str) -> list[str]:
    """Lower-case words of an object name: split at separators, digits and CamelCase."""
    spaced = re.sub(r"(?<=[a-z])(?=[A-Z])", " ", name)
    return [w for w in re.split(r"[^A-Za-z]+", spaced.lower()) if w]


def guess_kind(name: str) -> str:
    """`hmd`, `rigid_body`, `controller` or `tracker` from the words of a device's name."""
    words = set(name_words(name))
    for kind, hints in KIND_WORDS:
        if words & set(hints):
            return kind
    return "tracker"


def marker_name(name: str) -> str | None:
    """The marker an object shows, when its name ends with a marker name (lower case), else None."""
    m = MARKER_RE.search(name.strip())
    return m.group(1).lower() if m else None


def device_rotations(m: np.ndarray, names: list[str], source: str) -> np.ndarray:
    """Unit quaternions (..., N, 4) of the rotation parts (..., N, 3, 3), scale removed; refuses a
    mirrored one. Columns are normalised; frames a sheared parent left not orthonormal get the
    nearest rotation (polar decomposition by SVD) instead."""
    cols = np.linalg.norm(m, axis=-2, keepdims=True)
    if not np.all(cols > 1e-12):
        i = int(np.argwhere(~np.all(cols[..., 0, :] > 1e-12, axis=-1))[0][-1])
        raise BodyCalError("has a zero scale: no device frame", source=source, field=names[i],
                           hint="give the object a non-zero scale")
    r = m / cols
    det = np.linalg.det(r)
    if np.any(det < 0):
        i = int(np.argwhere(det < 0)[0][-1])
        raise BodyCalError("is mirrored (a negative scale): its frame is not a device's rotation", source=source,
                           field=names[i], hint="give the object and its parents positive scales")
    err = np.abs(np.swapaxes(r, -1, -2) @ r - np.eye(3)).max(axis=(-1, -2))
    sheared = err > ORTHONORMAL_TOL
    if sheared.any():
        u, _s, vt = np.linalg.svd(m[sheared])
        r[sheared] = u @ vt
    return tf.matrix_to_quat(r)


def _check_given(objects: list[SampledObject], source: str) -> None:
    """Given kinds and roles must be ones FORMATS.md §2.1 knows, each role on one object."""
    seen: dict[str, str] = {}
    for o in objects:
        if o.kind is not None and o.kind not in DEVICE_KINDS:
            raise BodyCalError(f"{o.kind!r} is not a device kind", source=source, field=o.name,
                               hint=f"use one of {', '.join(DEVICE_KINDS)}")
        if o.role is None:
            continue
        if o.role not in ROLES:
            raise BodyCalError(f"{o.role!r} is not a device role", source=source, field=o.name,
                               hint=f"use one of {', '.join(ROLES)}")
        if seen.setdefault(o.role, o.name) != o.name:
            raise BodyCalError(f"'{seen[o.role]}' and '{o.name}' both have the role '{o.role}'", source=source,
                               hint="give each role to one object")


def recording_from_matrices(name: str, frames: np.ndarray, rate: float, matrices: np.ndarray,
                            objects: list[SampledObject], *, segments: list[Segment] | None = None,
                            source: str = "scene objects", notes: list[str] | None = None) -> Recording:
    """The Recording of `objects` whose world matrices (F, N, 4, 4) were sampled at scene `frames`
    (F,) played at `rate` frames per second: sample k at time (frames[k] - frames[0]) / rate.
    Markers and devices as the module docstring says; every sample is tracked."""
    frames = np.asarray(frames, float)
    matrices = np.asarray(matrices, float)
    f, n = len(frames), len(objects)
    if f == 0 or n == 0:
        raise BodyCalError("nothing to read: no frames or no objects", source=source)
    if matrices.shape != (f, n, 4, 4):
        raise BodyCalError(f"matrices of shape {matrices.shape}, expected {(f, n, 4, 4)}", source=source)
    if not (np.isfinite(rate) and rate > 0):
        raise BodyCalError(f"frame rate {rate!r} is not a rate", source=source, hint="set the scene's frame rate")
    names = [o.name for o in objects]
    if not np.all(np.isfinite(matrices)):
        fr, i = (int(x) for x in np.argwhere(~np.isfinite(matrices).all(axis=(-1, -2)))[0])
        raise BodyCalError("has a non-finite transform", source=source, field=names[i],
                           where=f"frame {frames[fr]:g}", hint="fix the object's animation")
    check_positions(matrices[..., :3, 3], np.ones((f, n), bool), 1.0, source, names,
                    lambda fr, _i: f"frame {frames[fr]:g}")
    _check_given(objects, source)
    marker_of = [marker_name(o.name) for o in objects]
    taken: dict[str, str] = {}
    for o, mk in zip(objects, marker_of):
        if mk is not None and taken.setdefault(mk, o.name) != o.name:
            raise BodyCalError(f"'{taken[mk]}' and '{o.name}' are both the marker '{mk}'", source=source,
                               hint="rename one of them")
    dev = [i for i, mk in enumerate(marker_of) if mk is None]
    mks = [i for i, mk in enumerate(marker_of) if mk is not None]
    rot = device_rotations(matrices[:, dev][..., :3, :3], [names[i] for i in dev], source)
    devices = [Device(name=names[i], kind=objects[i].kind or guess_kind(names[i]), role=objects[i].role)
               for i in dev]
    return Recording(name=name, time=(frames - frames[0]) / rate, devices=devices,
                     positions=matrices[:, dev][..., :3, 3], rotations=tf.continuous_quaternions(rot),
                     valid=np.ones((f, len(dev)), bool), marker_names=[marker_of[i] for i in mks],
                     markers=matrices[:, mks][..., :3, 3], marker_valid=np.ones((f, len(mks)), bool),
                     segments=list(segments or []), source=source, notes=list(notes or []))
