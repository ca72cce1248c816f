"""Where the pipeline's performer pose comes from (DESIGN.md §1 step 1): the pipeline (`_Run`)
asks a pose source for the performer's body model, the canonical joints and bone frames of a chunk
of frames, and the ankles of the whole take (feet.py's stance detection).

- `RecordingSource`: a tracker recording of a calibrated user (`user_animation.animate_user`).
- `AnimationSource` (animation transfer, DESIGN.md §8): another character's animation: its
  avatar model (surface calibrated, or estimated from a bare skeleton) and its pose-bone values
  per frame, posed by the same FK as the avatar's (`AvatarRig.fk`), so the canonical joints and
  frames are exactly where Blender's pose puts them.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from ..body import skeleton as sk
from ..body.bodymodel import BodyModel
from ..body.skeleton import BONE_INDEX as BI
from ..body.skeleton import JOINT_INDEX as JI
from ..body.skeleton import SPINE_BONES, SPINE_JOINTS
from ..core.errors import BodyCalError
from ..core.transforms import frame_from_axes, normalize, quat_to_matrix
from ..recording.live.buffer import LiveRecording
from ..recording.model import Recording
from . import lower_body
from .avatar_pose import AvatarRig
from .rig import arc_param, curve_point
from .trackers import TrackerReader, joint_from_trackers
from .user_animation import UserAnimator, UserPose

ANKLE_CHUNK = 4000  # frames posed at once for the whole take's ankles


class PoseSource(Protocol):
    model: BodyModel  # the performer's body: a user model, or the source character's avatar model
    time: np.ndarray  # (F,) seconds
    name: str  # for messages
    recording: Recording | None  # the tracker recording (AvatarGo's offsets read its devices); None: none
    character: bool  # an animated character: its spine's shape and its limbs' twists are its own (_Run.solve_ik)
    notes: list[str]  # what making the pose source said (a lower body estimated), for the solver's notes

    @property
    def frame_count(self) -> int: ...

    def pose(self, start: int, stop: int, rest: tuple[dict, np.ndarray], fingers: bool = True,
             trunk: bool = True, finger_joints: bool = True) -> UserPose:
        """Canonical joints and bone frames of frames [start, stop), in the play area. `fingers`,
        `trunk` False: the caller reads none of the fingers', the trunk's joints and frames (a
        source may then leave them unposed; `UserAnimator.animate`); `finger_joints` False: none
        of the fingers' joints (their frames, yes)."""

    def ankle(self, side: str, start: int = 0, stop: int | None = None) -> np.ndarray | None:
        """(F, 3) the performer's ankle over frames [start, stop) (default the whole take; None:
        not known)."""

    def foot_turn(self, side: str, start: int = 0, stop: int | None = None) -> np.ndarray | None:
        """(F, 3, 3) the performer's foot's rotation since its rest pose (world) over frames [start,
        stop): its canonical frame is this times its rest frame (None: not known)."""

    def trackers(self, start: int = 0, stop: int | None = None):
        """The trackers of frames [start, stop) (trackers.Trackers; default the whole take), None
        for an animation."""


class RecordingSource:
    """A tracker recording of a calibrated user. A whole recording from a kit below six devices
    gets its estimated devices here (lower_body.complete: `seat_height` for a seated performer); a
    live one has them added frame by frame (live.LiveSolver)."""

    character = False

    def __init__(self, recording: Recording, user: BodyModel, *, seat_height: float | None = None):
        self.notes = []
        if not isinstance(recording, LiveRecording):
            completed = lower_body.complete(recording, user, seat_height=seat_height)
            self.notes = completed.notes[len(recording.notes):]
            recording = completed
        self.recording, self.model = recording, user
        self.name = recording.source or recording.name
        self._reader = None
        self._animator = None
        self._tr = None

    @property
    def time(self) -> np.ndarray:
        return self.recording.time  # a live recording's grows

    @property
    def frame_count(self) -> int:
        return self.recording.frame_count

    @property
    def reader(self) -> TrackerReader:
        if self._reader is None:
            self._reader = TrackerReader(self.recording, self.model)
        return self._reader

    def pose(self, start, stop, rest, fingers=True, trunk=True, finger_joints=True):
        if self._animator is None:
            self._animator = UserAnimator(self.recording, self.model, rest, self.reader)
        return self._animator.animate(start, stop, self.trackers(start, stop), fingers=fingers, trunk=trunk,
                                      finger_joints=finger_joints)

    def trackers(self, start=0, stop=None):
        if start or stop is not None:
            # the user animation and then the feet's plan ask for the same frames' trackers, ankles
            # and feet in turn (a live stream: every frame): read once
            if getattr(self, "_block", (None,))[0] != (start, stop, self.frame_count):
                self._block = ((start, stop, self.frame_count), self.reader.read(start, stop))
            return self._block[1]
        if self._tr is None:
            self._tr = self.reader.read()
        return self._tr

    def ankle(self, side, start=0, stop=None):
        return joint_from_trackers(self.model, self.trackers(start, stop), f"ankle_{side}", [f"foot_{side}"])

    def foot_turn(self, side, start=0, stop=None):
        # the foot's frame rides on its tracker (user_animation: R_T(t) R_T0^-1 C0)
        tr, role = self.trackers(start, stop), f"foot_{side}"
        if tr is None or role not in tr.rot or role not in tr.ref_rot:
            return None
        return tr.rot[role] @ tr.ref_rot[role].T


class AnimationSource:
    """A character's action: `basis` (F, N, 4) pose-bone quaternions (w, x, y, z) in the order of
    `AvatarRig.from_model(model).names`, `locations` (F, N, 3) pose-bone locations (or (F, 3) for
    the pelvis bone only), `time` (F,) seconds."""

    character = True
    recording = None
    notes: list[str] = []

    def __init__(self, model: BodyModel, basis: np.ndarray, locations: np.ndarray, time: np.ndarray,
                 name: str | None = None):
        self.model, self.name = model, name or model.name
        if model.kind != "avatar":
            raise BodyCalError(f"expected the source character's avatar model, got kind '{model.kind}'",
                               source=self.name, field="kind")
        self.rig = AvatarRig.from_model(model)
        n = len(self.rig.names)
        basis = np.asarray(basis, float)
        locations = np.asarray(locations, float)
        time = np.asarray(time, float)
        nf = len(time)
        if nf == 0:
            raise BodyCalError("the source animation has no frames", source=self.name)
        if basis.shape != (nf, n, 4) or locations.shape not in ((nf, n, 3), (nf, 3)):
            raise BodyCalError(f"the source animation's arrays do not match its rig ({n} bones, {nf} frames)",
                               source=self.name)
        if not (np.isfinite(basis).all() and np.isfinite(locations).all() and np.isfinite(time).all()):
            raise BodyCalError("the source animation has non-finite values", source=self.name,
                               hint="check the action's F-Curves")
        norm = np.linalg.norm(basis, axis=-1, keepdims=True)
        if (norm < 1e-9).any():
            raise BodyCalError("the source animation has a zero rotation quaternion", source=self.name)
        self.basis = basis / norm
        if locations.ndim == 2:
            full = np.zeros((nf, n, 3))
            full[:, self.rig.root] = locations
            locations = full
        self.locations = locations
        self.time = time
        self._ankles = self._foot_turns = None
        self._chain = None

    @property
    def frame_count(self) -> int:
        return len(self.time)

    def _fk(self, start, stop, realised=True):
        return self.rig.fk(self.basis[start:stop], self.locations[start:stop, self.rig.root],
                           locations=self.locations[start:stop], realised=realised)

    def pose(self, start, stop, rest=None, fingers=True, trunk=True, finger_joints=True):  # (its animation's)
        fk = self._fk(start, stop)
        frames = fk.frames.copy()
        idx = [BI[b] for b in SPINE_BONES]
        frames[:, idx] = frame_from_axes(self._vertebrae(fk), frames[:, idx][..., :, 0])
        return UserPose(self.time[start:stop], fk.joints, frames, np.ones(stop - start, bool), [], fk.frames)

    def trackers(self, start=0, stop=None):
        return None

    def _vertebrae(self, fk) -> np.ndarray:
        """(F, 12, 3) world vertebra directions whose curve (the avatar's vertebra lengths, from
        the spine root: `rig.chain.spine_curve`) passes through the points the posed chain bones
        are aimed at (each at its arc position, `AvatarRig.chain_s`), so a rig posed from them
        (`AvatarRig.solve`) aims its chain where this one's chain is: the round trip is exact for
        the same rig. A vertebra spanning two chain bones' arcs gets the direction that reaches the
        lower bone's aim point at its fraction of the vertebra; the others aim at their top joint
        carried rigidly by the chain bone whose arc holds it. No chain: the carriers' frames."""
        rig = self.rig
        if self._chain is None:
            chain = [i for i, d in enumerate(rig.driver) if d == "chain"]
            rest = rig.to_armature(np.stack([rig.joint_world[JI[j]] for j in SPINE_JOINTS]))
            starts = sorted((arc_param(rest, rig.head[i]), i) for i in chain)
            self._chain = (rest, starts, sorted((float(rig.chain_s[i]), i) for i in chain))
        rest, starts, ends = self._chain
        ys = fk.frames[:, [BI[b] for b in SPINE_BONES]][..., :, 1]
        if not starts:
            return ys
        P, H = fk.rotations, fk.heads

        def image(i, x):  # the rest point x (armature) carried by chain bone i, world
            return rig.to_world(H[:, i] + (P[:, i] @ (rig.rest[i].T @ (x - rig.head[i]))))

        def bone_at(a):
            return next((i for s0, i in reversed(starts) if s0 <= a + 1e-9), starts[0][1])

        lengths = rig.lengths[[BI[b] for b in SPINE_BONES]]
        c = fk.joints[:, JI["spine_root"]]
        out = np.empty_like(ys)
        for k in range(len(SPINE_BONES)):
            end = next(((s1, i) for s1, i in ends if k + 1e-9 < s1 <= k + 1 + 1e-9), None)
            if end is not None and end[0] < k + 1 - 1e-6:
                aim = image(end[1], curve_point(rest[None], end[0])[0])
            else:
                aim = image(bone_at(k + 1), rest[k + 1])
            out[:, k] = normalize(aim - c)
            c = c + lengths[k] * out[:, k]
        return out

    def ankle(self, side, start=0, stop=None):
        if self._ankles is None:
            # Blender's pose rule (AvatarRig.fk) on the ankles' bones and their ancestors only.
            rig = self.rig
            carry = {s: int(rig.joint_bone[JI[f"ankle_{s}"]]) for s in sk.SIDES}
            need = set()
            for b in carry.values():
                while b >= 0 and b not in need:
                    need.add(b)
                    b = int(rig.parent[b])
            out = {s: np.empty((self.frame_count, 3)) for s in sk.SIDES}
            turns = {s: np.empty((self.frame_count, 3, 3)) for s in sk.SIDES}  # the feet's, since rest
            turn_world = np.asarray(rig.w_rot, float)  # armature to world, without its scale
            for a in range(0, self.frame_count, ANKLE_CHUNK):
                z = min(a + ANKLE_CHUNK, self.frame_count)
                B = quat_to_matrix(self.basis[a:z])
                P, H = {}, {}
                for i in sorted(need):
                    p, loc = int(rig.parent[i]), self.locations[a:z, i]
                    if p < 0:
                        P[i] = rig.rest[i] @ B[:, i]
                        H[i] = rig.head[i] + loc @ rig.rest[i].T
                    else:
                        pr = P[p] @ (rig.rest[p].T @ rig.rest[i])
                        P[i] = pr @ B[:, i]
                        H[i] = H[p] + P[p] @ (rig.rest[p].T @ (rig.head[i] - rig.head[p])) \
                            + (pr @ loc[..., None])[..., 0]
                for s, b in carry.items():
                    out[s][a:z] = rig.to_world(H[b] + P[b] @ rig.joint_local[JI[f"ankle_{s}"]])
                    turns[s][a:z] = turn_world @ (P[b] @ rig.rest[b].T) @ turn_world.T
            self._ankles, self._foot_turns = out, turns
        return self._ankles[side][start:stop]

    def foot_turn(self, side, start=0, stop=None):
        self.ankle(side)
        return self._foot_turns[side][start:stop]
