"""The avatar's rig posed (DESIGN.md §1, "The rig posed"), in small modules: `plan` (`RigPlan`: what posing
reads that does not depend on the frames, built once per rig), `pose_plan` (how a subset of its
bones is posed, depth by depth), `chain` (the spine chain aimed at the canonical spine curve, and
the memo of its last aim), `fk` (forward kinematics over frames: canonical frames -> pose, the
joints and frames a pose realises, Blender's pose evaluation) and `basis` (pose -> pose-bone
quaternions and the root's location). `retarget.avatar_pose.AvatarRig` is the face the rest of
BodyCal uses."""

from .fk import RigPose
from .plan import RigPlan, arc_param, curve_point

__all__ = ["RigPlan", "RigPose", "arc_param", "curve_point"]
