"""Step 2 of the pipeline (DESIGN.md §1) and the conversion every method ends with: canonical bone
frames in the world -> the avatar's pose-bone rotations (Blender's `matrix_basis`) and back.

Canonical bone frames follow `surface_layout.bone_frame`: origin at the head joint, +Y along the
bone, +X the bone's right (`canonical_rest_frames` fixes the right of every bone with ONE rule used
for the user at the reference time and for the avatar at rest, so copying a frame copies the pose).

`AvatarRig` is the avatar's armature as the rest of BodyCal meets it: the frame-independent plan
(`rig/plan.py`, its fields: bones in armature space, the armature's `matrix_world`, what drives each
bone, where the canonical joints ride) with the entry points of forward kinematics (`rig/fk.py`) and
the basis solve (`rig/basis.py`), and the one state a pose leaves, the spine chain's memo
(`rig/chain.py` `ChainMemo`). Step 2's copy of the user's frames onto the avatar's (`copy_frames`)
and the root's scale (`root_scale`) are here too.
"""

from __future__ import annotations

import numpy as np

from ..body import skeleton as sk
from ..body.bodymodel import BodyModel
from ..body.rest_frames import complete_joints
from ..body.skeleton import BONE_INDEX as BI
from ..body.skeleton import JOINT_INDEX as JI
from ..body.skeleton import JOINTS, SPINE_BONES
from ..core.errors import BodyCalError
from ..core.transforms import matmul_stack
from .rig import basis as rig_basis
from .rig import fk as rig_fk
from .rig.chain import ChainMemo
from .rig.fk import RigPose
from .rig.plan import RigPlan


class AvatarRig(RigPlan):
    """The rig's plan (`RigPlan.from_model` builds it) posed: `solve` (canonical frames -> pose
    bones), `joint_positions` (a few joints of that pose), `fk` (pose bones -> joints and frames).

    Decision (layout): a thin face over `rig/` rather than callers moving to it: some thirty
    modules, benches and tests read the plan's fields and call these four methods; the work is in
    `rig/`'s modules, each one job."""

    def __post_init__(self):
        super().__post_init__()
        self.memo = ChainMemo()  # the spine chain's rotations of the last pose (`ChainMemo`)

    def solve(self, frames: np.ndarray, pelvis: np.ndarray, *, basis: bool = True, realised=True,
              float64: bool = False) -> RigPose:
        """Pose bones that realise canonical world frames (F, B, 3, 3) with the canonical pelvis
        joint at `pelvis` (F, 3, world). `basis=False` skips the pose-bone quaternions and root
        location, `realised=False` the realised canonical frames (RigPose fields left None); a list
        of canonical bone indices realises only those (the other frames are left NaN). One frame's
        spine chain is aimed in mathutils (float32, `rig_one_frame`) unless `float64` (a constant
        of the bake's, such as a method's T-pose, keeps numpy's values).

        Speed: the pose is built bone by bone in a bones-first layout, and every product is a
        stack of 3x3 matrices times ONE fixed matrix, which is one BLAS call on the stack seen as
        (3F, 3) rows (numpy's stacked matmul makes one call per 3x3 product, ~10x slower)."""
        P, H, turned, joints = rig_fk.posed(self, self.memo, np.asarray(frames, float), pelvis, float64=float64)
        if not basis:
            return rig_fk.finish(self, None, P, H, None, realised, turned, joints)
        turn = self.w_rot if turned else None
        return rig_fk.finish(self, rig_basis.solve(self.basis_plan, P, turn), P, H,
                             rig_basis.root_location(self.basis_plan, P, H, turn), realised, turned, joints)

    def joint_positions(self, frames: np.ndarray, pelvis: np.ndarray, joints: list[str]) -> np.ndarray:
        """(F, len(joints), 3) world positions of a few canonical joints for the pose `solve` would
        give, posing only the bones they hang from (the IK's limb roots need the trunk only)."""
        return rig_fk.joint_positions(self, self.memo, frames, pelvis, joints)

    def fk(self, basis: np.ndarray, root_location: np.ndarray, *, locations: np.ndarray | None = None,
           realised=True) -> RigPose:
        """Blender's pose evaluation from pose-bone quaternions (F, N, 4) and the root bone's
        location (F, 3); `locations` (F, N, 3), when given, are every bone's pose location (an
        animated character's: a bone above the pelvis may carry the motion), the root's included."""
        basis = np.asarray(basis, float)
        P, H = rig_fk.evaluate(self, basis, root_location, locations)
        return rig_fk.finish(self, basis, P, H, np.asarray(root_location, float), realised)

    def basis_of(self, bone_names: list[str], rotations: np.ndarray) -> np.ndarray:
        """(F, N, 4) pose-bone quaternions in this rig's bone order from `rotations` (F, B, 4) of
        the bones `bone_names` (an animation's keyed bones); the rig's other bones at rest."""
        basis = np.zeros((len(rotations), len(self.names), 4))
        basis[..., 0] = 1.0
        index = self.bone_index
        cols = [(index[n], k) for k, n in enumerate(bone_names) if n in index]
        basis[:, [c for c, _ in cols]] = np.asarray(rotations)[:, [k for _, k in cols]]
        return basis

    def leg_length(self) -> float:
        return _leg_length(self.joint_world)


def _leg_length(joints: np.ndarray) -> float:
    """Hip to knee to ankle plus the ankle's height, mean of both sides (joints (J, 3) world)."""
    out = []
    for s in sk.SIDES:
        h, k, a = joints[JI[f"hip_{s}"]], joints[JI[f"knee_{s}"]], joints[JI[f"ankle_{s}"]]
        out.append(np.linalg.norm(k - h) + np.linalg.norm(a - k) + a[2])
    return float(np.mean(out))


def root_scale(user_model: BodyModel, rig: AvatarRig) -> float:
    pos = complete_joints(user_model)
    user = np.stack([pos[j] for j in JOINTS])
    lu = _leg_length(user)
    if lu <= 1e-6:
        raise BodyCalError("the user's legs have no length", source=user_model.name, field="joints")
    return rig.leg_length() / lu


def root_centre(user_model: BodyModel) -> np.ndarray:
    """(3,) the floor point under the user's pelvis at the reference time: the avatar's root
    motion is the user's scaled about it (steps scale with the legs), so the avatar starts where
    the performer stood and the whole result moves with the recording (no world origin involved)."""
    pel = complete_joints(user_model)["pelvis"]
    return np.array([pel[0], pel[1], 0.0])


def root_positions(user_pelvis: np.ndarray, k: float, centre: np.ndarray) -> np.ndarray:
    """(F, 3) the avatar's pelvis: the user's, scaled by `k` about `centre` (`root_centre`)."""
    return centre + (np.asarray(user_pelvis, float) - centre) * k


# Bones whose canonical frame depends on where each calibration put the trunk's joints (spine root
# behind the sacrum, resampled vertebrae, clavicle root): the avatar takes the user's rotation
# since the reference pose, not the user's orientation, so both stand as they were calibrated.
DELTA_COPY = tuple(BI[b] for b in ["sacrum", "head", *SPINE_BONES, "clavicle_l", "clavicle_r", "foot_l", "foot_r"])


def facing_turn(user_frames0: np.ndarray, avatar_frames0: np.ndarray) -> np.ndarray:
    """(3, 3) the turn about the vertical that carries the avatar's rest facing (its hip line)
    onto the user's facing at the reference time. Step 2 compares the two bodies in this frame of
    reference: a performer may face any way in the room, the avatar's rest faces wherever its rig
    was built to face."""
    a = avatar_frames0[BI["sacrum"]][:, 0]
    u = user_frames0[BI["sacrum"]][:, 0]
    ang = np.arctan2(u[1], u[0]) - np.arctan2(a[1], a[0])
    c, s = np.cos(ang), np.sin(ang)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def copy_frames(user_frames: np.ndarray, user_frames0: np.ndarray, avatar_frames0: np.ndarray) -> np.ndarray:
    """Step 2's copy: limb, hand, foot and finger frames are copied as they are (anatomical axes,
    whatever the avatar's rest pose); trunk frames (DELTA_COPY) as the rotation since the user's
    reference pose applied to the avatar's rest turned to face as the user did (`facing_turn` Y):
    C_u(t) C_u0^-1 Y C_a0. Without Y a performer who faced anywhere but the avatar's rest facing
    got a trunk turned against the limbs (legs crossed; DESIGN.md §1, "Frame of reference")."""
    return copy_frames_by(user_frames, copy_factor(user_frames0, avatar_frames0))


def copy_factor(user_frames0: np.ndarray, avatar_frames0: np.ndarray) -> np.ndarray:
    """(len(DELTA_COPY), 3, 3) `copy_frames`' right factor C_u0^-1 Y C_a0 of the trunk bones, which
    depends on the rest frames only (the prepared solver computes it once)."""
    idx = list(DELTA_COPY)
    turn = facing_turn(user_frames0, avatar_frames0)
    return user_frames0[idx].swapaxes(-1, -2) @ (turn @ avatar_frames0[idx])


def copy_frames_by(user_frames: np.ndarray, factor: np.ndarray) -> np.ndarray:
    """`copy_frames` with its right factor given (`copy_factor`)."""
    out = np.array(user_frames, float, copy=True)
    out[:, _DELTA_COPY_ROWS] = matmul_stack(out[:, _DELTA_COPY_ROWS], factor)
    return out


_DELTA_COPY_ROWS = np.array(DELTA_COPY, int)
