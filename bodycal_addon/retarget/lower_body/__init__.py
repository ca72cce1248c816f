"""A lower body from head and hands (DESIGN.md §6): the estimated pelvis and feet of a kit without
their trackers, made for a whole recording (`complete`) or a stream (`LiveLowerBody`).

Its modules: `estimate` (the devices made, the face re-exported here) from `shape` (what it reads
of the body model), `body_path` (the path under the head), `stepping` (planted feet that step),
`heel`, `kneel`, `chest` and `touch` (a hand resting on the trunk holds the pelvis)."""

from .estimate import KIND, LiveLowerBody, complete, device_poses, estimated_roles, filled_pose, with_devices
from .shape import LowerBodyShape

__all__ = ["KIND", "LiveLowerBody", "LowerBodyShape", "complete", "device_poses", "estimated_roles", "filled_pose",
           "with_devices"]
