"""One frame in Blender's own `mathutils` (DESIGN.md "Prepared solver", BLENDER_NOTES.md).

A live frame or a preview's is a few dozen 3x3 products, cross products and normalisations on
single items, where numpy's per-call cost (several thousand instructions) is the whole cost: a
3x3 product takes 0.2 us in mathutils against 2.6 us in numpy. So each kernel has two
implementations, chosen by one dispatcher: numpy over a leading frame axis (the bake), and
mathutils for one frame. mathutils ships inside every Blender (a built-in module: importable in
Blender, and after `import bpy` in the bpy module); the engine lane and a plain interpreter use
PyPI's build of the same code (`mathutils`, requirements-dev.txt). Where it cannot be imported (a
worker process started from Blender's own Python, which has no mathutils of its own), one frame
takes the numpy path: the same values to float32's rounding (below).

Decision (precision): mathutils stores float32 (Blender's and PyPI's alike, BLENDER_NOTES.md), so
a one-frame solve agrees with the bake's float64 values to float32's rounding, not to the bit:
measured on the pinned takes, within the tolerances the pin tests state (DESIGN.md "Prepared
solver"). Python floats read out of mathutils are float32 values; scalar arithmetic between them
(lengths, angles) runs in Python's float64.

This is the only engine module that imports mathutils (tests/engine/test_module_layout.py)."""

from __future__ import annotations

import struct
from functools import lru_cache

import numpy as np

try:
    import mathutils
    from mathutils import Matrix, Quaternion, Vector
except ImportError:  # Blender's own Python outside Blender (a worker process), or no PyPI build
    mathutils = None
    Matrix = Quaternion = Vector = None

# Whether one frame takes the mathutils path (tests switch it off to compare with the numpy path).
ENABLED = mathutils is not None


def matrices(a: np.ndarray) -> list:
    """mathutils Matrices of a stack of 3x3 matrices (K, 3, 3) (rows, as numpy's)."""
    return [Matrix(m) for m in a.tolist()]


def vectors(a: np.ndarray) -> list:
    """mathutils Vectors of (K, 3) rows."""
    return [Vector(v) for v in a.tolist()]


def matrix_rows(ms: list) -> list:
    """The entries of mathutils 3x3 matrices as row-major lists of nine floats (np.array's input)."""
    return [m[0][:] + m[1][:] + m[2][:] for m in ms]


def matrix_array(ms: list) -> np.ndarray:
    """(K, 3, 3) float64 of mathutils 3x3 matrices."""
    return np.array(matrix_rows(ms), float).reshape(len(ms), 3, 3)


def vector_array(vs: list) -> np.ndarray:
    """(K, 3) float64 of mathutils Vectors (or 3-sequences)."""
    return np.array([v[:] for v in vs], float).reshape(len(vs), 3)


def float_array(values) -> np.ndarray:
    """(len(values),) float64 of a sequence of Python floats (a one-frame kernel's results), by
    struct's packing: ~100 instructions a value, where np.array of a list costs ~360 and
    np.fromiter ~250 (callgrind; a frame's kernels hand back hundreds). A read-only array."""
    return np.frombuffer(_packer(len(values)).pack(*values))


@lru_cache(maxsize=32)
def _packer(count: int) -> struct.Struct:
    """A `struct.Struct` of `count` float64s, once per count."""
    return struct.Struct(f"{count}d")
