"""A BVH reader with forward kinematics, in the outside tool's lab frame: Z up, metres.

BVH files are Y up; a clip is turned into the lab frame by (x, y, z) -> (x, -z, y) (a quarter turn
about X, so the CMU subject's rest forward +Z becomes -Y). Local rotations compose in the order
the CHANNELS list them (CMU: Z Y X, i.e. R = Rz Ry Rx); a joint's world rotation is its parent's
times its own, and its position is the parent's plus the parent's rotation applied to its OFFSET.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import rot

# The CMU skeleton's length unit (mocap.cs.cmu.edu FAQ: "inches * 1/0.45") in metres; files
# already in metres say so through `unit`.
CMU_UNIT_M = 0.0254 / 0.45
Y_UP_TO_Z_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])


@dataclass
class Clip:
    """A BVH clip: skeleton and per-frame local rotations, in the lab frame."""

    name: str
    joints: list[str]
    parents: np.ndarray  # (J,) -1 for the root
    offsets: np.ndarray  # (J, 3) metres, lab axes, in the parent's rest frame
    local: np.ndarray  # (F, J, 3, 3) local rotations (lab axes)
    root: np.ndarray  # (F, 3) root position, metres, lab frame
    fps: float

    @property
    def frame_count(self) -> int:
        return self.local.shape[0]

    def index(self, name: str) -> int:
        return self.joints.index(name)

    def fk(self, local=None, root=None, root_rot=None):
        """World rotations (F, J, 3, 3) and positions (F, J, 3) for local rotations `local`
        (default the clip's), root positions and an optional extra world rotation of the root."""
        local = self.local if local is None else local
        root = self.root if root is None else root
        n = local.shape[0]
        G = np.empty((n, len(self.joints), 3, 3))
        P = np.empty((n, len(self.joints), 3))
        for j, p in enumerate(self.parents):
            if p < 0:
                G[:, j] = local[:, j] if root_rot is None else root_rot @ local[:, j]
                P[:, j] = root + self.offsets[j]
            else:
                G[:, j] = G[:, p] @ local[:, j]
                P[:, j] = P[:, p] + G[:, p] @ self.offsets[j]
        return G, P

    def resampled(self, fps: float) -> Clip:
        """The clip at another frame rate (geodesic interpolation of every local rotation)."""
        t_old = np.arange(self.frame_count) / self.fps
        t_new = np.arange(0.0, t_old[-1] + 1e-9, 1.0 / fps)
        k = np.clip(np.searchsorted(t_old, t_new, side="right") - 1, 0, self.frame_count - 2)
        frac = (t_new - t_old[k]) / (t_old[k + 1] - t_old[k])
        local = rot.interpolate(self.local[k], self.local[k + 1], np.broadcast_to(frac[:, None], (len(k),
                                                                                                   len(self.joints))))
        root = self.root[k] + frac[:, None] * (self.root[k + 1] - self.root[k])
        return Clip(self.name, self.joints, self.parents, self.offsets, local, root, fps)


def read(path, unit: float | None = None) -> Clip:
    """Read a BVH file. `unit`: metres per file unit (default: CMU units, unless the name says
    the file is already scaled to metres)."""
    path = Path(path)
    toks = path.read_text().split()
    names, parents, offsets, channels = [], [], [], []
    stack: list[int] = []
    i = 0
    pending_end = False
    while toks[i] != "MOTION":
        t = toks[i]
        if t in ("ROOT", "JOINT"):
            names.append(toks[i + 1])
            parents.append(stack[-1] if stack else -1)
            i += 2
        elif t == "End":
            pending_end = True
            i += 2
        elif t == "{":
            stack.append(-2 if pending_end else len(names) - 1)
            i += 1
        elif t == "}":
            popped = stack.pop()
            pending_end = pending_end and popped != -2
            i += 1
        elif t == "OFFSET":
            if stack and stack[-1] == -2:
                pass  # an end site's offset: not a joint
            else:
                offsets.append([float(x) for x in toks[i + 1:i + 4]])
            i += 4
        elif t == "CHANNELS":
            n = int(toks[i + 1])
            channels.append(toks[i + 2:i + 2 + n])
            i += 2 + n
        else:
            i += 1
    # "MOTION Frames: N Frame Time: dt"
    nf = int(toks[i + 2])
    dt = float(toks[i + 5])
    data = np.array(toks[i + 6:i + 6 + nf * sum(len(c) for c in channels)], float).reshape(nf, -1)
    if unit is None:
        unit = 1.0 if "scaled" in path.name else CMU_UNIT_M
    A = Y_UP_TO_Z_UP
    off = np.array(offsets, float) * unit @ A.T
    local = np.empty((nf, len(names), 3, 3))
    root = np.zeros((nf, 3))
    col = 0
    for j, ch in enumerate(channels):
        m = np.broadcast_to(np.eye(3), (nf, 3, 3)).copy()
        for c in ch:
            if c.endswith("position"):
                root[:, "XYZ".index(c[0])] = data[:, col] * unit
            else:
                m = m @ rot.about(c[0], np.radians(data[:, col]))
            col += 1
        local[:, j] = A @ m @ A.T  # the same rotation seen in lab axes
    root = root @ A.T
    return Clip(path.stem, names, np.array(parents), off, local, root, 1.0 / dt)
