"""The per-frame retargeting pipeline (DESIGN.md §1 steps 1-4) for the three methods, in chunks
of frames, with progress and cancel callbacks for the modal bake operator.

- `egocentric` (Delahaye 2023, the default): animate the user (step 1), pose the avatar by copying the
  user's bone frames (step 2), map the targets (wrists, ankles, elbows, knees, fingertips, skull
  base) through the two posed surfaces (step 3, `egocentric.retarget_points`), then avatar IK
  (step 4): spine aimed at the skull base, two-bone limbs with the swivel blend, fingers.
- `offsets` (AvatarGo): exact tracker-to-joint offsets for root, feet, hands and head, spine bent
  by the root-to-head angle, limbs by IK, fingers closed on the controller (`offsets.py`).
- `rotations`: step 2 only, the baseline.

The result is an `AvatarAnimation` whose `rotations` / `root_location` are pose-bone values for
the armature (`avatar_pose.AvatarRig.solve`) and whose `joints_world` are the canonical joints
those values put in the world (Blender's FK, armature matrix_world included).
"""

from __future__ import annotations

import copy
from collections.abc import Callable

import numpy as np

from ..avatar.estimate import ESTIMATED
from ..body import naming
from ..body import skeleton as sk
from ..body.animation import AvatarAnimation
from ..body.bodymodel import BodyModel
from ..body.rest_frames import complete_joints, model_rest_frames
from ..body.skeleton import BONE_INDEX as BI
from ..body.skeleton import BONES, JOINTS, SPINE_BONES, SPINE_JOINTS
from ..body.skeleton import JOINT_INDEX as JI
from ..body.surface_layout import bone_frame
from ..core.errors import BodyCalError, Cancelled
from ..core.transforms import normalize, quat_to_matrix, stack_apply, stack_mul
from ..recording.model import Recording
from . import egocentric as ego
from . import feet, ik
from . import offsets as ofs
from .avatar_pose import AvatarRig, copy_frames, root_centre, root_positions, root_scale
from .methods import check_method, methods_for
from .placement import check_placement, play_area_to_world, transformed_avatar
from .pose_source import PoseSource, RecordingSource
from .user_animation import pose_finger_chain, read_trackers, sacrum_toward_hip_line

TARGETS = tuple(
    [f"{j}_{s}" for j in ("wrist", "elbow", "ankle", "knee") for s in sk.SIDES]
    + [f"tip_{f}_{s}" for s in sk.SIDES for f in sk.FINGERS] + ["skull_base"])
ARM_PASSES = 2  # arm mappings per chunk (the second sees the arms where the first put them)
# Decision: the mapping (step 3) runs in single precision, about twice as fast; its targets agree
# with double precision to micrometres, and the IK and the rig stay in double precision.
MAPPING_DTYPE = np.float32
LIMBS = {  # limb: (anchor, intermediate, effector, anchored bone, intermediate bone)
    "arm": ("shoulder", "elbow", "wrist", "upperarm", "forearm"),
    "leg": ("hip", "knee", "ankle", "thigh", "shin"),
}


def surface_correction(model: BodyModel, frames0: np.ndarray, pos: dict) -> np.ndarray:
    """(B, 3, 3) C0^-1 C_model0: the model's surface points are local to `bone_frame` with the
    model's own `right`; the engine's frames fix the right by one rule. Posing with C(t) corr
    places them as the model defined them."""
    out = np.broadcast_to(np.eye(3), (len(BONES), 3, 3)).copy()
    for i, b in enumerate(BONES):
        info = model.bones.get(b.name)
        if info is None or info.right is None:
            continue
        cm = bone_frame(pos[b.head], pos[b.tail], np.asarray(info.right, float))
        if np.isfinite(cm).all() and abs(np.linalg.det(cm) - 1) < 1e-3:
            out[i] = frames0[i].T @ cm
    return out


def _check_method(avatar: BodyModel, method: str) -> None:
    check_method(method, "recording")
    if avatar.kind != "avatar":
        raise BodyCalError(f"expected an avatar body model, got kind '{avatar.kind}'", source=avatar.name,
                           field="kind")


def _check_inputs(recording: Recording, user: BodyModel, avatar: BodyModel, method: str) -> None:
    _check_method(avatar, method)
    if user.kind != "user":
        raise BodyCalError(f"expected a user body model, got kind '{user.kind}'", source=user.name, field="kind")
    if recording.frame_count == 0:
        raise BodyCalError("the recording has no frames", source=recording.source or recording.name)


class _Run:
    """Everything computed once per (performer, avatar, method). The performer is a pose source
    (pose_source.py): a tracker recording of a calibrated user, or another character's action."""

    def __init__(self, source: PoseSource, avatar: BodyModel, method: str, plant_feet: bool = True,
                 centre: np.ndarray | None = None):
        _check_method(avatar, method)
        user = source.model
        self.src, self.user, self.avatar, self.method = source, user, avatar, method
        self.rec = source.recording  # None: not a tracker recording
        # An animated character (pose_source.AnimationSource): its own spine shape and limb hinges.
        self.character = source.character
        self.rig = AvatarRig.from_model(avatar)
        self.k = root_scale(user, self.rig)
        # The floor point the performer's path is scaled about (placement.py): the play area's
        # origin, or the one under the performer's pelvis at the reference time.
        self.centre = root_centre(user) if centre is None else np.asarray(centre, float)
        self.user_pos = complete_joints(user)
        self.user_frames0 = model_rest_frames(user, self.user_pos)
        avatar_pos = complete_joints(avatar)
        # The avatar's vertebrae at rest in its sacrum's frame: the spine IK bends that shape.
        self.rest_spine = np.diff(np.stack([avatar_pos[j] for j in SPINE_JOINTS]), axis=0) @ \
            self.rig.frames0[BI["sacrum"]]
        self.notes: list[str] = []
        bm = naming.BoneMap.from_dict(avatar.extra["rig"].get("bone_map", {}))
        self.has_fingers = {s: all(f"{f}_{i}_{s}" in bm.bones for f in sk.FINGERS for i in (1, 2, 3))
                            for s in sk.SIDES}
        self.impl = METHOD_CLASSES[method](self, avatar_pos)
        self.feet = self._plan_feet(avatar, avatar_pos) if plant_feet else None

    def _plan_feet(self, avatar: BodyModel, avatar_pos: dict) -> dict:
        """The stances of the whole take from the performer's ankles (carried by the foot trackers,
        or the source character's) and, per stance, where the avatar's foot is planted (feet.py):
        {side: (weight (F,), planted xy (F, 2), the avatar's sole points (K, 3) in its canonical
        foot frame)}."""
        out = {}
        ref = self.user_pos
        tr = self.src.trackers()
        placed = self.impl.ankle_places(tr) if tr is not None else None
        corr = surface_correction(avatar, self.rig.frames0, avatar_pos)
        for s in sk.SIDES:
            user_ankle = self.src.ankle(s)
            if user_ankle is None:
                continue
            stance = feet.detect(user_ankle, self.src.time, float(ref[f"ankle_{s}"][2]))
            reference = (placed[f"ankle_{s}"] if placed is not None
                         else root_positions(user_ankle, self.k, self.centre))
            eid = f"mesh:sole_{s}"
            if eid in {e.id for e in avatar.surface}:
                sole = np.stack([corr[BI[f"foot_{s}"]] @ p.local for p in avatar.element(eid).points.values()])
            else:  # no sole measured: one point under the ankle, as deep as the ankle stands at rest
                sole = (np.array([0.0, 0.0, -avatar_pos[f"ankle_{s}"][2]]) @ self.rig.frames0[BI[f"foot_{s}"]])[None]
            out[s] = (stance.weight, feet.planted_xy(reference, stance), sole)
        return out

    def plant(self, targets: dict, frames: np.ndarray, pelvis: np.ndarray, start: int, stop: int,
             ankles: dict | None = None):
        """Feet planted (feet.py): the ankle targets (the method's, or `ankles` when it has none) eased
        onto the planted places and kept above the floor, and the pelvis lowered where a planted foot
        is out of reach. Returns (targets, pelvis, whether the feet have targets: a foot with a plan
        always has one, planted or not, so that a frame's result never depends on which frames are
        solved with it)."""
        if not self.feet:
            return targets, pelvis, False
        rig = self.rig
        targets = dict(targets)
        weights, aims, sides = [], [], []
        for s, (weight, planted, sole) in self.feet.items():
            w = weight[start:stop]
            name = f"ankle_{s}"
            base = targets[name] if name in targets else ankles[name]
            targets[name] = feet.lock(base, planted[start:stop], w, feet.sole_lift(frames[:, BI[f"foot_{s}"]], sole))
            weights.append(w)
            aims.append(targets[name])
            sides.append(s)
        if not sides:
            return targets, pelvis, False
        hips = rig.joint_positions(frames, pelvis, [f"hip_{s}" for s in sides])
        lengths = np.array([rig.lengths[BI[f"thigh_{s}"]] + rig.lengths[BI[f"shin_{s}"]] for s in sides])
        drop = feet.pelvis_drop(hips, np.stack(aims, axis=1), lengths, np.stack(weights, axis=1))
        if drop.any():
            down = drop[:, None] * np.array([0.0, 0.0, 1.0])
            pelvis = pelvis - down
            if "skull_base" in targets:  # the whole body comes down, the head with it
                targets["skull_base"] = targets["skull_base"] - down
        return targets, pelvis, True

    # --- one chunk of frames ------------------------------------------------------------------

    def chunk(self, start: int, stop: int):
        up = self.src.pose(start, stop, rest=(self.user_pos, self.user_frames0))
        for n in up.notes:
            if n not in self.notes:
                self.notes.append(n)
        pelvis = root_positions(up.joints[:, JI["pelvis"]], self.k, self.centre)
        # From here on the user's frames are the ones copied onto the avatar (step 2).
        user_frames = up.frames if up.surface_frames is None else up.surface_frames
        up = type(up)(up.time, up.joints, copy_frames(up.frames, self.user_frames0, self.rig.frames0), up.valid,
                      up.notes)
        fk = self.rig.solve(up.frames, pelvis, basis=self.impl.fk_basis, realised=self.impl.realised)
        return self.impl.chunk(up, fk, pelvis, user_frames, start, stop)

    def solve_ik(self, up, fk, pelvis, targets, hands=None, frames=None, trunk=None):
        """Avatar IK (appendix E, DESIGN.md §6) toward the targets present: the spine when there is
        a skull-base target, then each limb whose effector has a target, then the fingers.
        `frames` (default: the user's, copied) are updated; `trunk` is the rig pose the limbs
        start from (default: solved here after the spine)."""
        rig = self.rig
        frames = up.frames.copy() if frames is None else frames
        # Spine aimed at the skull base (appendix D: the same two-pass solver as the user's); the
        # clavicles keep their pose relative to vertebra 5.
        if "skull_base" in targets:
            spine_idx = [BI[b] for b in SPINE_BONES]
            top_right = normalize(up.joints[:, JI["shoulder_l"]] - up.joints[:, JI["shoulder_r"]])

            def solve_spine(aim):
                return ik.spine(pelvis, fk.frames[:, BI["sacrum"]], rig.lengths[BI["sacrum"]], None, aim,
                                top_right=top_right, two_pass=False, rest_segments=self.rest_spine)

            res = solve_spine(targets["skull_base"])
            frames[:, BI["sacrum"]] = res.sacrum_rot
            if self.character:
                # Decision (DESIGN.md §8): an animated character's spine has its own shape (an
                # animator's curve is no IK's), so the IK only corrects it: each vertebra turns by
                # what the IK changes between aiming at the copied skull base and at the target.
                # Where they agree (the same body) the source's spine comes back as it was.
                held = solve_spine(fk.joints[:, JI["skull_base"]])
                frames[:, spine_idx] = res.rotations @ np.swapaxes(held.rotations, -1, -2) @ up.frames[:, spine_idx]
            else:
                frames[:, spine_idx] = res.rotations
            v5 = BI[f"spine_{sk.CLAVICLE_VERTEBRA:02d}"]
            for s in sk.SIDES:
                c = BI[f"clavicle_{s}"]
                frames[:, c] = frames[:, v5] @ np.swapaxes(up.frames[:, v5], -1, -2) @ up.frames[:, c]
        # The limbs hang from the trunk as solved now (or as given).
        names = [f"{a}_{s}" for s in sk.SIDES for a, _, e, _, _ in LIMBS.values() if f"{e}_{s}" in targets]
        at = rig.joint_positions(frames, pelvis, names) if trunk is None else trunk.joints[:, [JI[j] for j in names]]
        roots = {j: at[:, k] for k, j in enumerate(names)}
        wrist_pos = {}
        for s in sk.SIDES:
            for limb, (a, m, e, ab, mb) in LIMBS.items():
                eff = targets.get(f"{e}_{s}")
                if eff is None:
                    continue
                root = roots[f"{a}_{s}"]
                l1, l2 = rig.lengths[BI[f"{ab}_{s}"]], rig.lengths[BI[f"{mb}_{s}"]]
                # Appendix E: swivel blended between the mapped intermediate target and the user's.
                # The hinge's axis: a character's upper bones twist on their own (a user's share
                # the hinge's right), so its hinge is the intermediate bone's +X.
                hinge = up.frames[:, BI[f"{mb if self.character else ab}_{s}"]][..., :, 0]
                tb = ik.two_bone(root, l1, l2, eff, targets.get(f"{m}_{s}"), self._user_swivel(up, a, m, e, s),
                                 hinge, size_ratio=self.k)
                frames[:, BI[f"{ab}_{s}"]] = tb.rot1
                frames[:, BI[f"{mb}_{s}"]] = tb.rot2
                reached = tb.end
                if limb == "arm":
                    wrist_pos[s] = reached
            if hands is not None and s in hands:
                for b, fr in hands[s].items():
                    frames[:, BI[b]] = frames[:, BI[f"hand_{s}"]] @ fr
            elif s in wrist_pos and self.has_fingers[s]:
                self._fingers(frames, s, wrist_pos[s], targets)
        return frames

    @staticmethod
    def _user_swivel(up, anchor: str, mid: str, effector: str, s: str) -> np.ndarray:
        """The user's swivel: the intermediate joint's offset from the user's own anchor-effector
        axis. Measured from the avatar's axis instead, the offset would also hold the angle
        between the two axes (the mapping moves the effector), whose direction turns with every
        millimetre of target noise when the limb is nearly straight: the upper arm's roll then
        jittered three times the user's."""
        root = up.joints[:, JI[f"{anchor}_{s}"]]
        axis = normalize(up.joints[:, JI[f"{effector}_{s}"]] - root)
        v = up.joints[:, JI[f"{mid}_{s}"]] - root
        return v - np.einsum("fi,fi->f", v, axis)[:, None] * axis

    def _fingers(self, frames, s, wrist, targets):
        rig = self.rig
        hand = frames[:, BI[f"hand_{s}"]]
        c0h = rig.frames0[BI[f"hand_{s}"]]
        w0 = rig.joint_world[JI[f"wrist_{s}"]]
        for f in sk.FINGERS:
            tip = targets.get(f"tip_{f}_{s}")
            if tip is None:
                continue
            names = [f"{j}_{f}_{s}" for j in sk.FINGER_JOINTS]
            p0 = [rig.joint_world[JI[n]] for n in names]
            lens = np.array([np.linalg.norm(p0[i + 1] - p0[i]) for i in range(3)])
            mcp = wrist + stack_apply(hand, c0h.T @ (p0[0] - w0))
            rest = [stack_mul(hand, c0h.T @ rig.frames0[BI[f"{f}_{i}_{s}"]]) for i in (1, 2, 3)]
            _, fr = pose_finger_chain(mcp, tip, lens, rest, thumb=f == "thumb")
            for i in (1, 2, 3):
                frames[:, BI[f"{f}_{i}_{s}"]] = fr[i - 1]


# --- the methods: one class each, the same stages -------------------------------------------------

class Method:
    """A retargeting method: what it computes once (`__init__`, on the run's shared state) and per
    chunk of frames (`chunk`: the avatar pose and the targets it aimed at). `fk_basis` and
    `realised` say how the run's rotation copy (step 2) is solved for it; `ankle_places` gives
    the ankles the feet plan holds (None: the user's, scaled about the root)."""

    name = ""
    fk_basis = False
    realised: bool | list[int] = False

    def __init__(self, run: _Run, avatar_pos: dict):
        self.run = run

    def ankle_places(self, trackers) -> dict | None:
        return None

    def chunk(self, up, fk, pelvis, user_frames, start: int, stop: int):
        raise NotImplementedError


class RotationCopy(Method):
    """Step 2 only, the baseline every other tool does; the legs reach their planted feet."""

    name = "rotations"
    fk_basis = True

    def chunk(self, up, fk, pelvis, user_frames, start, stop):
        run = self.run
        ankles = {f"ankle_{s}": fk.joints[:, JI[f"ankle_{s}"]] for s in sk.SIDES}
        targets, pelvis, planted = run.plant({}, up.frames, pelvis, start, stop, ankles)
        if not planted:
            return fk, {}
        # The legs reach their planted feet (and only the legs: the rest stays a rotation copy).
        legs = {n: v for n, v in targets.items() if n.startswith("ankle_")}
        frames = run.solve_ik(up, fk, pelvis, legs)
        return run.rig.solve(frames, pelvis, realised=False), legs


class Egocentric(Method):
    """Delahaye 2023: the targets mapped through the user's and the avatar's posed surfaces, then IK."""

    name = "egocentric"

    def __init__(self, run: _Run, avatar_pos: dict):
        super().__init__(run, avatar_pos)
        # Both surfaces re-expressed in the engine's canonical bone frames: the mapping's surface
        # coordinates (capsule angles, sphere directions) must mean the same side of the body
        # on the user and on the avatar, whatever `right` each model's producer chose.
        self.user_s = canonical_surface(_surface_bones(run.user), run.user_frames0, run.user_pos)
        self.avatar_s = canonical_surface(_surface_bones(run.avatar), run.rig.frames0, avatar_pos)
        self.ids = ego.common_elements(run.user, run.avatar)
        # Decision: the skull base (the trunk's target, solved before the limbs) is mapped
        # against the body without the arms: arm, hand and finger elements are moved by the IK
        # afterwards, and a hand resting on the head would otherwise drag the head toward where
        # the FK copy happened to put the avatar's hand.
        arm_parts = ("capsule:upperarm_", "capsule:forearm_", "mesh:palm_") + tuple(
            f"capsule:{f}_" for f in sk.FINGERS)
        self.trunk_ids = [i for i in self.ids if not i.startswith(arm_parts)]
        if not self.ids:
            raise BodyCalError("the user and the avatar share no surface elements", source=run.avatar.name,
                               field="surface", hint="calibrate the avatar's surface")
        self.graph_bones = list(ego.GRAPH_BONES)
        self.bone_heads = [JI[sk.BONE_BY_NAME[b].head] for b in self.graph_bones]
        self.bone_tails = [JI[sk.BONE_BY_NAME[b].tail] for b in self.graph_bones]
        self.user_lengths = np.array([np.linalg.norm(run.user_pos[sk.BONE_BY_NAME[b].tail] -
                                                     run.user_pos[sk.BONE_BY_NAME[b].head])
                                      for b in self.graph_bones])
        self.sbones = surface_bone_indices(self.user_s, self.avatar_s)
        # The frames the avatar's posed surface and the IK read (the rest stay unrealised).
        self.realised = sorted(set(self.sbones) | {BI["sacrum"]} | {BI[f"hand_{s}"] for s in sk.SIDES})
        have = {e.id for e in run.user.surface}
        self.palm_local = {}  # side -> (user, avatar) palm centre in the canonical hand frame
        for s in sk.SIDES:
            eid = f"mesh:palm_{s}"
            if eid in self.ids:
                self.palm_local[s] = tuple(
                    np.mean([p.local for p in m.element(eid).points.values()], axis=0)
                    for m in (self.user_s, self.avatar_s))
        # A fingertip is a target when the user has that finger and the avatar finger bones to reach it
        # (a skeleton with lumped hands, such as CMU's, has none: its tips would be reached by nothing).
        self.targets = [t for t in TARGETS if not t.startswith("tip_") or
                        (run.has_fingers[t[-1]] and any(i.startswith(f"capsule:{t.split('_')[1]}_") for i in have))]

    def chunk(self, up, fk, pelvis, user_frames, start, stop):
        """Steps 3-4 in two stages (Decision): the trunk and legs first, mapped against the body
        without the arms and solved; then the arms and fingers, mapped against the body with the
        trunk and legs already where the IK put them. Targets are mapped relative to the posed
        avatar, so a hand resting on a thigh must be mapped against the thigh where it ends up,
        not where the rotation copy had put it; and arm elements, which the IK moves last, must not
        pull the head or the feet."""
        run = self.run
        uj, uf = _jd(up.joints), _fd(user_frames, self.sbones)
        heads = np.take(up.joints, self.bone_heads, axis=1)
        tails = np.take(up.joints, self.bone_tails, axis=1)
        # A user's bones keep their calibrated lengths (tracked joints wobble); a character's are
        # taken as posed, like the avatar's own (a vertebra spanning two spine bones stretches).
        vec = tails - heads if run.character else normalize(tails - heads) * self.user_lengths[:, None]
        ub = {b: vec[:, i] for i, b in enumerate(self.graph_bones)}
        lower = [n for n in self.targets if n.startswith(("skull_base", "ankle_", "knee_"))]
        upper = [n for n in self.targets if n not in lower]
        targets = {}
        if self.trunk_ids:
            ust = ego.pose_surface(self.user_s, uj, uf, self.trunk_ids)
            avt = ego.pose_surface(self.avatar_s, _jd(fk.joints), _fd(fk.frames, self.sbones), self.trunk_ids)
            tg = ego.retarget_points(np.take(up.joints, [JI[n] for n in lower], axis=1), lower, ust, avt,
                                     user_bones=ub, dtype=MAPPING_DTYPE)
            targets.update({n: tg[:, i] for i, n in enumerate(lower)})
        ankles = {f"ankle_{s}": fk.joints[:, JI[f"ankle_{s}"]] for s in sk.SIDES}
        targets, pelvis, _ = run.plant(targets, up.frames, pelvis, start, stop, ankles)
        frames = run.solve_ik(up, fk, pelvis, targets)
        mid = run.rig.solve(frames, pelvis, basis=False, realised=self.realised)
        us = ego.pose_surface(self.user_s, uj, uf, self.ids)
        pts = np.take(up.joints, [JI[n] for n in upper], axis=1)
        # Decision: the hand is mapped through the centre of its palm, the part that touches, and
        # the wrist target is that point minus the avatar's own palm offset (the hand's orientation
        # is copied): wrist and palm are a hand's size apart, and hands differ.
        for s, (u_loc, _) in self.palm_local.items():
            pts[:, upper.index(f"wrist_{s}")] += stack_apply(user_frames[:, BI[f"hand_{s}"]], u_loc)
        # Pass 1 maps every arm target against the avatar with its trunk and legs solved. Later
        # passes re-map the wrists, against the arms where the previous pass put them, so a
        # hand touching the other hand (or arm) meets it where that one ends up; both hands move
        # toward each other at once, so those passes go half way (no overshoot).
        # The fingertips are re-mapped in full: their nearest elements are mostly their own hand's
        # palm and fingers, which pass 1 saw where the rotation copy had put the hand.
        wrists = [i for i, n in enumerate(upper) if n.startswith("wrist_")]
        tips = [i for i, n in enumerate(upper) if n.startswith("tip_")]
        user_side = ego.prepare_targets(pts, upper, us, user_bones=ub, dtype=MAPPING_DTYPE)  # the same for every pass
        pose, tg = mid, None
        for k in range(ARM_PASSES):
            av = ego.pose_surface(self.avatar_s, _jd(pose.joints), _fd(pose.frames, self.sbones), self.ids)
            ta = user_side.map(av)
            if tg is None:
                tg = ta
            else:
                tg[:, wrists] = 0.5 * (tg[:, wrists] + ta[:, wrists])
                tg[:, tips] = ta[:, tips]
            arm_targets = {n: tg[:, i] for i, n in enumerate(upper)}
            for s, (_, a_loc) in self.palm_local.items():
                arm_targets[f"wrist_{s}"] = arm_targets[f"wrist_{s}"] - stack_apply(mid.frames[:, BI[f"hand_{s}"]],
                                                                                    a_loc)
            arm_frames = run.solve_ik(up, fk, pelvis, arm_targets, frames=frames.copy(), trunk=mid)
            if k + 1 < ARM_PASSES:
                pose = run.rig.solve(arm_frames, pelvis, basis=False, realised=self.realised)
        frames = arm_frames
        targets.update(arm_targets)
        return run.rig.solve(frames, pelvis, realised=False), targets


class ExactOffsets(Method):
    """AvatarGo: exact tracker-to-joint offsets from the T-pose, the spine bent by the root-to-head
    vector, limbs by IK, fingers closed on the controller (offsets.py)."""

    name = "offsets"

    def __init__(self, run: _Run, avatar_pos: dict):
        super().__init__(run, avatar_pos)
        if run.rec is None:
            raise BodyCalError("the offsets method needs a tracker recording (AvatarGo's offsets are from "
                               "trackers)", source=run.user.name, field="method", hint="use egocentric or rotations")
        tpose = {}
        raw = run.user.extra.get("tpose") or {}
        tr0 = None
        for role in ("pelvis", "head", "hand_l", "hand_r", "foot_l", "foot_r"):
            if role in raw:
                v = np.asarray(raw[role], float)
                tpose[role] = (v[:3], quat_to_matrix(v[3:7] / np.linalg.norm(v[3:7])))
            else:
                if tr0 is None and run.user.reference_time is not None:
                    f0 = int(np.clip(np.searchsorted(run.rec.time, run.user.reference_time), 0,
                                     run.rec.frame_count - 1))
                    tr0 = read_trackers(run.rec, run.user, f0, f0 + 1)
                if tr0 is not None and role in tr0.pos:
                    tpose[role] = (tr0.pos[role][0], tr0.rot[role][0])
        # The user's sacrum at the T-pose as the other methods see it (halfway to the hip line),
        # so that eq. 3 turns the avatar's pelvis the way theirs turns.
        ref = run.user_frames0.copy()
        ref[BI["sacrum"]] = sacrum_toward_hip_line(ref[BI["sacrum"]], run.user_pos["hip_l"], run.user_pos["hip_r"])
        self.ofs = ofs.setup(run.user, run.rig, ref, tpose, run.centre)
        self.grip = {s: ofs.grip_fingers(run.rig, s) for s in sk.SIDES if run.has_fingers[s]}

    def ankle_places(self, trackers) -> dict:
        placed, _ = ofs.effector_targets(self.ofs, trackers.pos, trackers.rot)
        return placed

    def chunk(self, up, fk, pelvis, user_frames, start, stop):
        run = self.run
        st = self.ofs
        tr = read_trackers(run.rec, run.user, start, stop)
        p, r = ofs.effector_targets(st, tr.pos, tr.rot)
        frames = up.frames.copy()
        for bone, fr in r.items():
            frames[:, BI[bone]] = fr
        sf = ofs.spine_frames(st, tr.pos, r["sacrum"])
        frames[:, [BI[b] for b in SPINE_BONES]] = sf
        v5 = sk.CLAVICLE_VERTEBRA - 1
        for s in sk.SIDES:
            c = BI[f"clavicle_{s}"]
            frames[:, c] = stack_mul(sf[:, v5], st.spine0[v5].T @ st.ref_frames[c])
        targets = {f"{j}_{s}": p[f"{j}_{s}"] for j in ("wrist", "ankle") for s in sk.SIDES}
        # AvatarGo stands its avatar on the floor: planted feet on it, the pelvis lowered to reach.
        targets, pelvis, _ = run.plant(targets, frames, p["pelvis"], start, stop)
        up2 = type(up)(up.time, up.joints, frames, up.valid, up.notes)
        frames = run.solve_ik(up2, fk, pelvis, targets, hands=self.grip)
        targets["skull_base"] = p["skull_base"]
        return run.rig.solve(frames, pelvis, realised=False), targets


METHOD_CLASSES: dict[str, type[Method]] = {m.name: m for m in (Egocentric, ExactOffsets, RotationCopy)}
METHODS = methods_for("recording")  # every method (a recording takes them all), the default first


def _surface_bones(model: BodyModel) -> BodyModel:
    """The model with every mesh element's `bone` a canonical bone (FORMATS.md allows a pattern such
    as "spine_*" for the torso, whose points each name their own vertebra)."""
    fixed = []
    changed = False
    for e in model.surface:
        if e.type == "mesh" and e.bone not in sk.BONE_BY_NAME and e.points:
            e = copy.copy(e)
            e.bone = next(iter(e.points.values())).bone
            changed = True
        fixed.append(e)
    if not changed:
        return model
    out = copy.copy(model)
    out.surface = fixed
    return out


def _jd(joints: np.ndarray) -> dict[str, np.ndarray]:
    return {j: joints[:, i] for i, j in enumerate(JOINTS)}


def _fd(frames: np.ndarray, bones: list[int]) -> dict[str, np.ndarray]:
    """The frames of the bones a surface rides on."""
    return {BONES[b].name: frames[:, b] for b in bones}


def canonical_surface(model: BodyModel, frames0: np.ndarray, pos: dict) -> BodyModel:
    """A copy of `model` whose sphere centres, capsule axis offsets and mesh points are local to the
    engine's canonical rest frames `frames0` (and whose bones' `right` are those frames' +X)."""
    corr = surface_correction(model, frames0, pos)
    out = copy.copy(model)
    out.bones = {k: copy.copy(v) for k, v in model.bones.items()}
    for name, b in out.bones.items():
        if name in BI:
            b.right = frames0[BI[name]][:, 0].copy()
    out.surface = []
    for e in model.surface:
        e = copy.deepcopy(e)
        if e.center is not None and e.bone in BI:
            e.center = corr[BI[e.bone]] @ e.center
        if e.type == "capsule" and e.bone in BI and ("axis_head" in e.extra or "axis_tail" in e.extra):
            e.set_axis_offsets(*(corr[BI[e.bone]] @ e.axis_offsets().T).T)
        for p in e.points.values():
            if p.bone in BI:
                p.local = corr[BI[p.bone]] @ p.local
        out.surface.append(e)
    return out


def surface_bone_indices(*models: BodyModel) -> list[int]:
    names = set()
    for m in models:
        for e in m.surface:
            names.add(e.bone)
            names |= {p.bone for p in e.points.values()}
    return sorted(BI[n] for n in names if n in BI)


def retarget(recording: Recording, user_model: BodyModel, avatar_model: BodyModel, method: str = "egocentric", *,
             chunk_frames: int = 2000, progress: Callable[[float], None] | None = None,
             cancel: Callable[[], bool] | None = None, plant_feet: bool = True,
             placement: str = "object") -> AvatarAnimation:
    """Retarget `recording` of the user (`user_model`) onto the avatar (`avatar_model`, kind
    "avatar" with `extra["rig"]`). Frames are processed `chunk_frames` at a time; `progress(f)` is
    called with the fraction done after each chunk and `cancel()` before each one (True raises
    `errors.Cancelled`). `plant_feet` holds the feet still and on the floor while the performer
    stands on them (feet.py), in every method. `placement` ("object" or "performer", placement.py)
    says where the performance plays: relative to the armature object's placement, or where the
    performer was in the room. Bad inputs raise one `BodyCalError`."""
    _check_inputs(recording, user_model, avatar_model, method)
    return run_source(RecordingSource(recording, user_model), avatar_model, method, chunk_frames=chunk_frames,
                      progress=progress, cancel=cancel, plant_feet=plant_feet, placement=placement)


class PreparedTake:
    """A pose source and an avatar prepared once for a whole take (the feet plan included):
    `solve(start, stop)` is the avatar's animation of frames [start, stop), the very values the bake
    of the take keys there (`run_source` runs the same steps over chunks). The timeline preview
    solves the frame the user scrubs to."""

    def __init__(self, source: PoseSource, avatar_model: BodyModel, method: str = "egocentric", *,
                 plant_feet: bool = True, placement: str = "object"):
        _check_method(avatar_model, method)
        self.source, self.avatar = source, avatar_model
        to_world = play_area_to_world(avatar_model, check_placement(placement))
        avatar_in_area = transformed_avatar(avatar_model, np.linalg.inv(to_world))
        self.run = _Run(source, avatar_in_area, method, plant_feet,
                        centre=np.zeros(3) if placement == "object" else None)
        self.rot_t, self.shift = to_world[:3, :3].T, to_world[:3, 3]

    @property
    def frame_count(self) -> int:
        return self.source.frame_count

    def solve(self, start: int, stop: int) -> AvatarAnimation:
        start, stop = max(0, int(start)), min(self.frame_count, int(stop))
        if stop <= start:
            raise BodyCalError(f"frames {start}-{stop} are outside the take (0-{self.frame_count - 1})",
                               source=self.source.name)
        run = self.run
        pose, tg = run.chunk(start, stop)
        rig = run.rig
        joints = {j: pose.joints[:, i] @ self.rot_t + self.shift for i, j in enumerate(JOINTS)}
        return AvatarAnimation(rig.armature, list(rig.names), pose.basis, rig.names[rig.root],
                               np.asarray(pose.root_location, float), np.asarray(self.source.time[start:stop], float),
                               run.method, joints, {n: v @ self.rot_t + self.shift for n, v in tg.items()},
                               list(run.notes))


def prepare_recording(recording: Recording, user_model: BodyModel, avatar_model: BodyModel,
                      method: str = "egocentric", *, plant_feet: bool = True, placement: str = "object"
                      ) -> PreparedTake:
    """`retarget`'s take prepared once, to be solved a few frames at a time (PreparedTake)."""
    _check_inputs(recording, user_model, avatar_model, method)
    return PreparedTake(RecordingSource(recording, user_model), avatar_model, method, plant_feet=plant_feet,
                        placement=placement)


def run_source(source: PoseSource, avatar_model: BodyModel, method: str = "egocentric", *, chunk_frames: int = 2000,
               progress: Callable[[float], None] | None = None, cancel: Callable[[], bool] | None = None,
               plant_feet: bool = True, placement: str = "object") -> AvatarAnimation:
    """`retarget` for any pose source (pose_source.py): a recording of a calibrated user, or an
    animated character (`transfer.transfer`). The source's poses are in its play area."""
    # Everything is computed in the performer's play area, with the avatar brought into it; the
    # pose-bone values are in armature space either way, the world joints and targets go back.
    _check_method(avatar_model, method)
    to_world = play_area_to_world(avatar_model, check_placement(placement))
    avatar_in_area = transformed_avatar(avatar_model, np.linalg.inv(to_world))
    run = _Run(source, avatar_in_area, method, plant_feet, centre=np.zeros(3) if placement == "object" else None)
    rot_t, shift = to_world[:3, :3].T, to_world[:3, 3]
    nf = source.frame_count
    rig = run.rig
    nb = len(rig.names)
    rotations = np.empty((nf, nb, 4))
    root_loc = np.empty((nf, 3))
    joints = np.empty((nf, len(JOINTS), 3), np.float32)
    targets: dict[str, np.ndarray] = {}
    chunk_frames = max(1, int(chunk_frames))
    for start in range(0, nf, chunk_frames):
        if cancel is not None and cancel():
            raise Cancelled(f"retargeting cancelled at frame {start} of {nf}")
        stop = min(nf, start + chunk_frames)
        pose, tg = run.chunk(start, stop)
        rotations[start:stop] = pose.basis
        root_loc[start:stop] = pose.root_location
        joints[start:stop] = pose.joints @ rot_t + shift
        for n, v in tg.items():
            # NaN where a chunk had no target of this name (rotations: an ankle only while planted)
            targets.setdefault(n, np.full((nf, 3), np.nan, np.float32))[start:stop] = v @ rot_t + shift
        if progress is not None:
            progress(stop / nf)
    if not (np.isfinite(rotations).all() and np.isfinite(root_loc).all()):
        raise BodyCalError("the retargeted animation has non-finite values", source=source.name,
                           hint="check the source for broken poses")
    if avatar_model.calibration.get("method") == ESTIMATED:
        run.notes.append(f"{avatar_model.name} (target): no mesh, body surface estimated from its bone lengths")
    return AvatarAnimation(rig.armature, list(rig.names), rotations, rig.names[rig.root], root_loc,
                           np.asarray(source.time, float), method,
                           {j: joints[:, i] for i, j in enumerate(JOINTS)}, targets, run.notes)
