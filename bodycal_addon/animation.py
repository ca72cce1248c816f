"""`AvatarAnimation`: what the retargeting engine hands to the bake (DESIGN.md step 5).

Values are exactly what Blender stores on pose bones, so the bake only copies arrays:
- `rotations[f, b]` = `pose.bones[bone_names[b]].rotation_quaternion` at frame f (w, x, y, z),
  the bone's rotation relative to its rest pose in its own rest frame (Blender's matrix_basis).
- `root_location[f]` = `pose.bones[root_bone].location` at frame f (rest-local frame of the root
  bone, armature units).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class AvatarAnimation:
    armature: str  # armature object name
    bone_names: list[str]  # avatar pose bones to key, in the order of `rotations`' second axis
    rotations: np.ndarray  # (F, B, 4) unit quaternions w, x, y, z
    root_bone: str
    root_location: np.ndarray  # (F, 3)
    time: np.ndarray  # (F,) seconds
    method: str = "egocentric"
    joints_world: dict[str, np.ndarray] = field(default_factory=dict)  # canonical joint -> (F, 3) after IK
    targets: dict[str, np.ndarray] = field(default_factory=dict)  # retargeted effector targets, (F, 3) world
    notes: list[str] = field(default_factory=list)

    def __post_init__(self):
        f, b = len(self.time), len(self.bone_names)
        if self.rotations.shape != (f, b, 4):
            raise ValueError(f"rotations must be ({f}, {b}, 4), got {self.rotations.shape}")
        if self.root_location.shape != (f, 3):
            raise ValueError(f"root_location must be ({f}, 3), got {self.root_location.shape}")

    @property
    def frame_count(self) -> int:
        return len(self.time)
