"""`AvatarAnimation`: what the retargeting engine hands to the bake (DESIGN.md step 5).

Values are exactly what Blender stores on pose bones, so the bake only copies arrays:
- `rotations[f, b]` = `pose.bones[bone_names[b]].rotation_quaternion` at frame f (w, x, y, z),
  the bone's rotation relative to its rest pose in its own rest frame (Blender's matrix_basis).
- `root_location[f]` = `pose.bones[root_bone].location` at frame f (rest-local frame of the root
  bone, armature units).
- `bone_locations[bone][f]` = `pose.bones[bone].location` of other bones keyed with a location
  (the root bone carrying root motion, `retarget/root_motion.py`; Rigify's `torso` control).
- `constant_keys[data_path]` = a value keyed once at the first frame (Rigify's IK_FK switches).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.transforms import slerp


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
    targets: dict[str, np.ndarray] = field(default_factory=dict)  # retargeted effector targets, (F, 3) world; NaN: none
    notes: list[str] = field(default_factory=list)
    bone_locations: dict[str, np.ndarray] = field(default_factory=dict)  # other location-keyed bones, (F, 3)
    constant_keys: dict[str, float] = field(default_factory=dict)  # data path -> value, one key

    def __post_init__(self):
        f, b = len(self.time), len(self.bone_names)
        if self.rotations.shape != (f, b, 4):
            raise ValueError(f"rotations must be ({f}, {b}, 4), got {self.rotations.shape}")
        if self.root_location.shape != (f, 3):
            raise ValueError(f"root_location must be ({f}, 3), got {self.root_location.shape}")
        for name, loc in self.bone_locations.items():
            if np.shape(loc) != (f, 3):
                raise ValueError(f"bone_locations[{name!r}] must be ({f}, 3), got {np.shape(loc)}")

    @property
    def frame_count(self) -> int:
        return len(self.time)


def resample(anim: AvatarAnimation, fps: float) -> AvatarAnimation:
    """`anim` sampled every 1/fps s from its first sample to its last (the duration is kept: a
    90 Hz take resampled at 30 fps lasts as long). Rotations are slerped, the root location and
    the measured joints and targets interpolated linearly."""
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps must be positive, got {fps}")
    time = np.asarray(anim.time, float)
    if len(time) < 2:
        return anim
    n = int(np.floor((time[-1] - time[0]) * fps + 1e-6)) + 1
    t_out = time[0] + np.arange(n) / fps
    i = np.clip(np.searchsorted(time, t_out, side="right") - 1, 0, len(time) - 2)
    u = np.clip((t_out - time[i]) / np.maximum(time[i + 1] - time[i], 1e-12), 0.0, 1.0)

    def lerp(a):
        a = np.asarray(a, float)
        w = u.reshape((-1,) + (1,) * (a.ndim - 1))
        return a[i] * (1.0 - w) + a[i + 1] * w

    rotations = slerp(anim.rotations[i], anim.rotations[i + 1], u[:, None])
    return AvatarAnimation(anim.armature, list(anim.bone_names), rotations, anim.root_bone,
                           lerp(anim.root_location), t_out, anim.method,
                           {k: lerp(v) for k, v in anim.joints_world.items()},
                           {k: lerp(v) for k, v in anim.targets.items()},
                           [*anim.notes, f"resampled to {fps:g} fps from {len(time)} samples"],
                           {k: lerp(v) for k, v in anim.bone_locations.items()}, dict(anim.constant_keys))
