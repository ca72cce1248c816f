"""The retargeted avatar as VMC bones (FORMATS.md §6.4): `/VMC/Ext/Bone/Pos` with Unity's
HumanBodyBones names and `/VMC/Ext/Root/Pos`, as a VMC Performer sends a VRM humanoid, so that
VSeeFace, VMC4B or a Unity scene with EVMC4U shows the avatar BodyCal animated.

What a receiver expects: each bone's rotation relative to its parent's, with every bone at the
identity in a T-pose (the VRM-normalised humanoid), in Unity's axes (Y up, left-handed, metres,
the avatar facing +Z); each bone's position relative to its parent (the Hips' is the body's
place). BodyCal's avatar has its own rest pose (an A-pose, a relaxed hand) and faces where its
armature faces, so:

- The avatar's own frame: its armature object's origin on its floor, its rest heading forward
  (placement.play_area_to_world, "object"), then Unity's axes (recording/coords.py, `UNITY`).
- Its T-pose: every limb bone of the rest pose swung, without twist, onto its T-pose direction
  (arms, hands and the four fingers out sideways, legs straight down; the thumb stays as the hand
  holds it, the trunk, neck, head, clavicles and feet as they are at rest); `T_u = S_u C0_u`.
- A pose: each Unity bone turns with its canonical bone (DESIGN.md §2; the realised canonical frames,
  which carry every twist, the head's turn included): `W_u = C_u(t) T_u^-1`, then swung so its
  chord (its head to its child's head) lands where the pose has it, which makes a Unity bone
  spanning several canonical vertebrae reach the next one exactly. Local: `W_parent^-1 W_u`.

A receiver that rebuilds the skeleton from these (the local positions are the T-pose offsets)
puts every joint where BodyCal's pose has it; on its own avatar, the same turns.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..body import skeleton as sk
from ..body.animation import AvatarAnimation
from ..body.bodymodel import BodyModel
from ..body.rest_frames import complete_joints, model_rest_frames
from ..body.skeleton import BONE_INDEX as BI
from ..body.skeleton import JOINT_INDEX as JI
from ..core.transforms import matrix_to_quat, quat_between, quat_to_matrix
from ..recording.coords import from_internal, turns_from_internal
from ..recording.live.sender import VmcSender
from ..recording.live.vmc import AVAILABLE, BONE, ROOT, TIME, UNITY, bundles, message
from ..retarget.avatar_pose import AvatarRig
from ..retarget.placement import play_area_to_world

_FINGERS = {"thumb": "Thumb", "index": "Index", "middle": "Middle", "ring": "Ring", "pinky": "Little"}
_PHALANGES = ("Proximal", "Intermediate", "Distal")
_SIDE = {"l": "Left", "r": "Right"}


@dataclass(frozen=True)
class HumanoidBone:
    """A Unity humanoid bone: its parent, the canonical joint at its head, the canonical bone it
    turns with, the joint its chord aims at (its main child's head; None: no chord) and how its
    T-pose direction is found: "rest" (as at rest), "side" (out sideways), "down", "hand" (turned
    with the hand)."""

    name: str
    parent: str | None
    head: str
    bone: str
    aim: str | None
    tpose: str


def _humanoid() -> tuple[HumanoidBone, ...]:
    """Parents first. The canonical spine's 12 vertebrae are shared out as Spine 1-2, Chest 3-5,
    UpperChest 6-9 (the clavicles start at the top of the fifth, the UpperChest's head) and Neck
    10-12; each turns with its top vertebra but the Neck, which turns with its middle one."""
    bones = [HumanoidBone("Hips", None, "pelvis", "sacrum", "spine_root", "rest"),
             HumanoidBone("Spine", "Hips", "spine_root", "spine_02", "spine_02", "rest"),
             HumanoidBone("Chest", "Spine", "spine_02", "spine_05", "spine_05", "rest"),
             HumanoidBone("UpperChest", "Chest", "spine_05", "spine_09", "spine_09", "rest"),
             HumanoidBone("Neck", "UpperChest", "spine_09", "spine_11", "skull_base", "rest"),
             HumanoidBone("Head", "Neck", "skull_base", "head", "head", "rest")]
    for s, side in _SIDE.items():
        bones += [HumanoidBone(f"{side}UpperLeg", "Hips", f"hip_{s}", f"thigh_{s}", f"knee_{s}", "down"),
                  HumanoidBone(f"{side}LowerLeg", f"{side}UpperLeg", f"knee_{s}", f"shin_{s}", f"ankle_{s}", "down"),
                  HumanoidBone(f"{side}Foot", f"{side}LowerLeg", f"ankle_{s}", f"foot_{s}", f"toe_{s}", "rest"),
                  HumanoidBone(f"{side}Toes", f"{side}Foot", f"toe_{s}", f"foot_{s}", None, "rest"),
                  HumanoidBone(f"{side}Shoulder", "UpperChest", f"clavicle_{s}", f"clavicle_{s}", f"shoulder_{s}",
                               "rest"),
                  HumanoidBone(f"{side}UpperArm", f"{side}Shoulder", f"shoulder_{s}", f"upperarm_{s}", f"elbow_{s}",
                               "side"),
                  HumanoidBone(f"{side}LowerArm", f"{side}UpperArm", f"elbow_{s}", f"forearm_{s}", f"wrist_{s}",
                               "side"),
                  HumanoidBone(f"{side}Hand", f"{side}LowerArm", f"wrist_{s}", f"hand_{s}", f"mcp_middle_{s}", "side")]
        for f, fname in _FINGERS.items():
            parent = f"{side}Hand"
            for i, (ph, (head, aim)) in enumerate(zip(_PHALANGES, (("mcp", "pip"), ("pip", "dip"), ("dip", "tip")),
                                                      strict=True)):
                name = f"{side}{fname}{ph}"
                bones.append(HumanoidBone(name, parent, f"{head}_{f}_{s}", f"{f}_{i + 1}_{s}", f"{aim}_{f}_{s}",
                                          "hand" if f == "thumb" else "side"))
                parent = name
    return tuple(bones)


HUMANOID = _humanoid()
HUMANOID_INDEX = {b.name: i for i, b in enumerate(HUMANOID)}


class VmcHumanoid:
    """An avatar body model's mapping onto the Unity humanoid (module docstring), built once: its
    frame, its T-pose, the bones' T-pose offsets. `local_poses` turns poses into what VMC sends."""

    def __init__(self, avatar: BodyModel):
        to_world = play_area_to_world(avatar, "object")
        self.area_rot = to_world[:3, :3].T  # world -> the avatar's frame (rigid: a turn about Z)
        self.area_shift = -self.area_rot @ to_world[:3, 3]
        pos = complete_joints(avatar)
        j0 = self._area_points(np.stack([pos[j] for j in sk.JOINTS]))
        c0 = self.area_rot @ model_rest_frames(avatar, pos)
        self.parent = np.array([HUMANOID_INDEX[b.parent] if b.parent else -1 for b in HUMANOID])
        self.head = np.array([JI[b.head] for b in HUMANOID])
        self.aim = np.array([JI[b.aim] if b.aim else -1 for b in HUMANOID])
        self.bone = np.array([BI[b.bone] for b in HUMANOID])
        swing = self._tpose_swings(j0)
        self.chord_t = np.einsum("uij,uj->ui", swing, j0[np.maximum(self.aim, 0)] - j0[self.head])
        self.tpose_t = np.swapaxes(swing @ c0[self.bone], -1, -2)  # T_u^-1
        self.offsets = self._tpose_offsets(j0, swing)  # the avatar's frame
        self._unity_offsets = from_internal(self.offsets, None, *UNITY)[0]

    def _area_points(self, p: np.ndarray) -> np.ndarray:
        return p @ self.area_rot.T + self.area_shift

    def _tpose_swings(self, j0: np.ndarray) -> np.ndarray:
        """(U, 3, 3) S_u: each bone's turn from the rest pose to the T-pose (module docstring)."""
        swing = np.broadcast_to(np.eye(3), (len(HUMANOID), 3, 3)).copy()
        for u, b in enumerate(HUMANOID):
            side = -1.0 if b.head.endswith("_l") else 1.0  # the avatar's left is -X in its frame
            target = {"side": np.array([side, 0.0, 0.0]), "down": np.array([0.0, 0.0, -1.0])}.get(b.tpose)
            if target is not None:
                swing[u] = quat_to_matrix(quat_between(j0[self.aim[u]] - j0[self.head[u]], target))
        for u, b in enumerate(HUMANOID):
            if b.tpose == "hand":
                swing[u] = swing[HUMANOID_INDEX[f"{_SIDE[b.head[-1]]}Hand"]]
        return swing

    def _tpose_offsets(self, j0: np.ndarray, swing: np.ndarray) -> np.ndarray:
        """(U, 3) each bone's head from its parent's head in the T-pose, the avatar's frame: the rest
        offset turned with the parent (the Hips': from the floor under the origin)."""
        offsets = np.empty((len(HUMANOID), 3))
        for u, p in enumerate(self.parent):
            rest = j0[self.head[u]] - (j0[self.head[p]] if p >= 0 else 0.0)
            offsets[u] = swing[p] @ rest if p >= 0 else rest
        return offsets

    def local_poses(self, frames: np.ndarray, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(local rotations (F, U, 4) w, x, y, z and the Hips' positions (F, 3)), both in Unity's
        axes, of poses given as realised canonical frames (F, B, 3, 3) and joints (F, J, 3) in the
        world."""
        frames = self.area_rot @ np.asarray(frames, float)
        joints = self._area_points(np.asarray(joints, float))
        world = frames[:, self.bone] @ self.tpose_t  # (F, U, 3, 3) W_u before the chord's swing
        chord = joints[:, np.maximum(self.aim, 0)] - joints[:, self.head]
        reach = quat_to_matrix(quat_between(np.einsum("fuij,uj->fui", world, self.chord_t), chord))
        world = np.where((self.aim >= 0)[None, :, None, None], reach @ world, world)
        parent = np.where((self.parent >= 0)[None, :, None, None], world[:, np.maximum(self.parent, 0)], np.eye(3))
        local = np.swapaxes(parent, -1, -2) @ world
        hips, _ = from_internal(joints[:, JI["pelvis"]], None, *UNITY)
        return turns_from_internal(matrix_to_quat(local), *UNITY[:2]), hips

    def messages(self, local: np.ndarray, hips: np.ndarray) -> list:
        """One frame's `/VMC/Ext/Root/Pos` and `/VMC/Ext/Bone/Pos` messages from `local_poses`' (U, 4)
        and (3,) of that frame."""
        offsets = self._unity_offsets.copy()
        offsets[0] = hips
        out = [message(ROOT, "root", 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0)]
        for b, p, q in zip(HUMANOID, offsets.tolist(), np.asarray(local).tolist(), strict=True):
            out.append(message(BONE, b.name, p[0], p[1], p[2], q[1], q[2], q[3], q[0]))
        return out


def animation_pose(anim: AvatarAnimation, rig: AvatarRig, lo: int = 0, hi: int | None = None):
    """(realised canonical frames (F, B, 3, 3), joints (F, J, 3)), world, of frames lo..hi-1 of an
    engine animation of `rig`'s armature, by the rig's own FK (retarget/avatar_pose.py)."""
    hi = anim.frame_count if hi is None else hi
    index = rig.bone_index
    basis = rig.basis_of(anim.bone_names, anim.rotations[lo:hi])
    locations = np.zeros((hi - lo, len(rig.names), 3))
    locations[:, rig.root] = anim.root_location[lo:hi]
    for name, loc in anim.bone_locations.items():
        if name in index:
            locations[:, index[name]] = np.asarray(loc)[lo:hi]
    pose = rig.fk(basis, anim.root_location[lo:hi], locations=locations)
    return pose.frames, pose.joints


class AvatarMessages:
    """An engine animation as VMC bones, frame by frame (sender.FrameMessages), worked out a chunk
    of frames at a time so a long take never holds every frame's matrices at once."""

    def __init__(self, anim: AvatarAnimation, avatar: BodyModel, chunk: int = 512):
        self.name = anim.armature
        self.anim, self.time, self.chunk = anim, np.asarray(anim.time, float), max(1, int(chunk))
        self.rig = AvatarRig.from_model(avatar)
        self.humanoid = VmcHumanoid(avatar)
        self._cached: tuple[int, np.ndarray, np.ndarray] | None = None

    def announcements(self) -> list:
        return []

    def frame(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """(local rotations (U, 4), Hips position (3,)) of frame k, Unity's axes."""
        c = k // self.chunk
        if self._cached is None or self._cached[0] != c:
            lo = c * self.chunk
            frames, joints = animation_pose(self.anim, self.rig, lo, min(lo + self.chunk, len(self.time)))
            self._cached = (c, *self.humanoid.local_poses(frames, joints))
        _, local, hips = self._cached
        return local[k % self.chunk], hips[k % self.chunk]

    def messages(self, k: int, offset: float) -> list:
        return self.humanoid.messages(*self.frame(k))


class AvatarVmcOut:
    """The avatar's pose sent to a VMC receiver one frame at a time, for a live loop: `send_pose`
    with the realised canonical frames and joints a solve gives, or `send_animation_frame` with
    frame k of an engine animation."""

    def __init__(self, avatar: BodyModel, sender: VmcSender):
        self.humanoid, self.sender = VmcHumanoid(avatar), sender
        self._rig: AvatarRig | None = None
        self._avatar = avatar

    def send_pose(self, frames: np.ndarray, joints: np.ndarray, t: float) -> None:
        """One pose: frames (B, 3, 3) and joints (J, 3), world; `t` the sender's time (seconds)."""
        local, hips = self.humanoid.local_poses(np.asarray(frames)[None], np.asarray(joints)[None])
        msgs = self.humanoid.messages(local[0], hips[0])
        self.sender.send(bundles([*msgs, message(AVAILABLE, 1), message(TIME, float(t))]))

    def send_pose_values(self, basis: np.ndarray, root_location: np.ndarray, t: float) -> None:
        """One pose as a solve gives it: pose-bone quaternions (N, 4) in the avatar rig's bone order
        and the root bone's location (3,), posed by the rig's FK where the armature stands."""
        if self._rig is None:
            self._rig = AvatarRig.from_model(self._avatar)
        pose = self._rig.fk(np.asarray(basis, float)[None], np.asarray(root_location, float)[None])
        self.send_pose(pose.frames[0], pose.joints[0], t)

    def send_animation_frame(self, anim: AvatarAnimation, k: int) -> None:
        if self._rig is None:
            self._rig = AvatarRig.from_model(self._avatar)
        frames, joints = animation_pose(anim, self._rig, k, k + 1)
        self.send_pose(frames[0], joints[0], float(anim.time[k]))
