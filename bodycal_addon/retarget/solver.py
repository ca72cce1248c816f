"""The prepared solver (DESIGN.md §1 steps 1-4, "Prepared solver"): everything that depends only on
the performer's body model, the avatar and the method (rest frames, surface layouts, correction
matrices, the method's constants, the feet plan) is computed once, when the solver is built; then
`solve(start, stop)` gives the pose-bone values, the joints and the targets of any frames
[start, stop) of the take. The bake (`pipeline.run_source`) runs it over chunks of frames, a
timeline preview over the frame being scrubbed, the live loop (`live.LiveSolver`) over each new
frame: the same code, vectorised over a leading frame axis, whatever the block's length.

The performer is a pose source (pose_source.py): a tracker recording of a calibrated user (a
whole file, or a live buffer that grows as frames arrive), or another character's action.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..body import naming
from ..body import skeleton as sk
from ..body.bodymodel import BodyModel
from ..body.rest_frames import complete_joints, model_rest_frames
from ..body.skeleton import BONE_INDEX as BI
from ..body.skeleton import JOINT_INDEX as JI
from ..body.skeleton import SPINE_BONES, SPINE_JOINTS
from ..core import one_frame
from ..core.errors import BodyCalError
from ..core.transforms import EPS, matmul_stack, normalize, stacks_apply, stacks_mul
from ..recording.model import Recording
from . import feet, ik
from .avatar_pose import AvatarRig, copy_factor, copy_frames, copy_frames_by, root_centre, root_positions, root_scale
from .lower_body.estimate import KIND as ESTIMATED
from .methods import check_method
from .placement import check_placement, play_area_to_world, transformed_avatar
from .pose_source import PoseSource
from .solver_methods import METHOD_CLASSES, surface_correction
from .user_animation import finger_set

STANCES = ("whole", "causal")  # the feet plan: from the whole take (a bake), or frame by frame (live)


_SPINE_ROWS = np.array([BI[b] for b in SPINE_BONES], int)
_CLAVICLE_ROWS = np.array([BI[f"clavicle_{s}"] for s in sk.SIDES], int)
LIMBS = {  # limb: (anchor, intermediate, effector, anchored bone, intermediate bone)
    "arm": ("shoulder", "elbow", "wrist", "upperarm", "forearm"),
    "leg": ("hip", "knee", "ankle", "thigh", "shin"),
}


def _check_method(avatar: BodyModel, method: str) -> None:
    check_method(method, "recording")
    if avatar.kind != "avatar":
        raise BodyCalError(f"expected an avatar body model, got kind '{avatar.kind}'", source=avatar.name,
                           field="kind")


def check_inputs(recording: Recording, user: BodyModel, avatar: BodyModel, method: str) -> None:
    _check_method(avatar, method)
    if user.kind != "user":
        raise BodyCalError(f"expected a user body model, got kind '{user.kind}'", source=user.name, field="kind")
    if recording.frame_count == 0:
        raise BodyCalError("the recording has no frames", source=recording.source or recording.name)


@dataclass
class SolvedFrames:
    """What the solver gives for frames [start, stop) of a take (F = stop - start): exactly the
    bake's values for those frames."""

    basis: np.ndarray  # (F, N, 4) pose-bone rotation_quaternion (w, x, y, z), the rig's bone order
    root_location: np.ndarray  # (F, 3) the root bone's pose location (its rest frame)
    joints: np.ndarray  # (F, J, 3) canonical joints in the world (skeleton.JOINTS order)
    targets: dict[str, np.ndarray]  # name -> (F, 3) what the IK aimed at, world; NaN where none


class PreparedSolver:
    """The retargeting of one performer (a pose source) onto one avatar by one method, prepared
    once: `solve(start, stop)` then costs only the frames asked for.

    `avatar_model` is the avatar where its armature object stands (kind "avatar" with
    `extra["rig"]`); `placement` ("object" or "performer", placement.py) says where the
    performance plays. `plant_feet` holds the feet still and on the floor while the performer
    stands on them (feet.py); `stance` says how the stances are found: "whole" from the whole take
    (a bake: the easing starts before a stance and the planted place is the stance's mean),
    "causal" frame by frame from the frames so far (a live stream, `feet.CausalStance`). Bad inputs
    raise one `BodyCalError`."""

    def __init__(self, source: PoseSource, avatar_model: BodyModel, method: str = "egocentric", *,
                 plant_feet: bool = True, placement: str = "object", stance: str = "whole"):
        _check_method(avatar_model, method)
        if stance not in STANCES:
            raise BodyCalError(f"unknown stance detection '{stance}'", field="stance",
                               hint=f"use one of {', '.join(STANCES)}")
        # Everything is computed in the performer's play area, with the avatar brought into it; the
        # pose-bone values are in armature space either way, the world joints and targets go back.
        to_world = play_area_to_world(avatar_model, check_placement(placement))
        avatar = transformed_avatar(avatar_model, np.linalg.inv(to_world))
        self.rot_t, self.shift = to_world[:3, :3].T, to_world[:3, 3]
        self.placement, self.stance = placement, stance
        self._prepare(source, avatar, method, np.zeros(3) if placement == "object" else None)
        self.feet = self._plan_feet(avatar, complete_joints(avatar)) if plant_feet else None

    def _prepare(self, source: PoseSource, avatar: BodyModel, method: str, centre: np.ndarray | None) -> None:
        """What every frame shares: the rig, the root scale, the rest frames and the method's constants."""
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
        self._copy_factor = copy_factor(self.user_frames0, self.rig.frames0)  # step 2's trunk copy
        avatar_pos = complete_joints(avatar)
        # The avatar's vertebrae at rest in its sacrum's frame: the spine IK bends that shape.
        self.rest_spine = np.diff(np.stack([avatar_pos[j] for j in SPINE_JOINTS]), axis=0) @ \
            self.rig.frames0[BI["sacrum"]]
        self.notes: list[str] = list(source.notes)
        bm = naming.BoneMap.from_dict(avatar.extra["rig"].get("bone_map", {}))
        self.has_fingers = {s: all(f"{f}_{i}_{s}" in bm.bones for f in sk.FINGERS for i in (1, 2, 3))
                            for s in sk.SIDES}
        self.finger_bones = {s: any(f"{f}_{i}_{s}" in bm.bones for f in sk.FINGERS for i in (1, 2, 3))
                             for s in sk.SIDES}  # any finger bone of that hand
        self.impl = METHOD_CLASSES[method](self, avatar_pos)

    @property
    def frame_count(self) -> int:
        """The take's frames so far (a live buffer grows)."""
        return self.src.frame_count

    @property
    def bone_names(self) -> list[str]:
        """The rig's bones in the order of `SolvedFrames.basis`."""
        return list(self.rig.names)

    def solve(self, start: int, stop: int) -> SolvedFrames:
        """The pose-bone values, world joints and targets of frames [start, stop) (0 <= start <
        stop <= frame_count): the bake's values for those frames, for any block of frames."""
        if not 0 <= start < stop <= self.frame_count:
            raise BodyCalError(f"frames {start}-{stop} are not within the take's 0-{self.frame_count}",
                               source=self.src.name, field="frames")
        pose, tg = self.chunk(start, stop)
        names = list(tg)
        world = (np.stack([tg[n] for n in names]) @ self.rot_t + self.shift) if names else ()
        return SolvedFrames(pose.basis, pose.root_location, pose.joints @ self.rot_t + self.shift,
                            {n: world[k] for k, n in enumerate(names)})

    def _plan_feet(self, avatar: BodyModel, avatar_pos: dict) -> FeetPlan:
        """Where the avatar's feet are planted (feet.py): per side the avatar's contact points
        (feet.Contact) in its canonical foot frame, and the stances of the performer's heels and
        balls (carried by the foot trackers, or the source character's feet), found over the whole
        take or frame by frame."""
        corr = surface_correction(avatar, self.rig.frames0, avatar_pos)
        contacts = {}
        for s in sk.SIDES:
            c = corr[BI[f"foot_{s}"]]
            eid = f"mesh:sole_{s}"
            if eid not in {e.id for e in avatar.surface}:
                # no sole measured: one point under the ankle, as deep as the ankle stands at rest
                depth = (np.array([0.0, 0.0, -avatar_pos[f"ankle_{s}"][2]]) @ self.rig.frames0[BI[f"foot_{s}"]])
                contacts[s] = feet.Contact(depth, depth, depth[None])
                continue
            el = avatar.element(eid)
            measured = el.extra.get("contact")
            if isinstance(measured, dict) and {"heel", "ball", "support"} <= set(measured):
                heel, ball, support = (np.asarray(measured[k], float) for k in ("heel", "ball", "support"))
                contacts[s] = feet.Contact(c @ heel, c @ ball, support @ c.T)
                continue
            # An avatar calibrated before the skin's contact points were measured: its sole's outline
            # (rays.py: sole_1 the heel, sole_3 / sole_5 either side of the toe joint) stands in.
            pts = {k: c @ p.local for k, p in el.points.items()}
            outline = np.stack(list(pts.values()))
            heel, ball = pts.get(f"sole_1_{s}"), [pts[k] for k in (f"sole_3_{s}", f"sole_5_{s}") if k in pts]
            contacts[s] = feet.Contact(outline.mean(0) if heel is None else heel,
                                       np.mean(ball, axis=0) if len(ball) == 2 else outline.mean(0), outline)
            cal = avatar.calibration
            estimated = cal.get("method") == "estimated" or eid in cal.get("defaulted", {})  # said at calibration
            if not estimated and not self._old_soles_said:
                self._old_soles_said = True
                self.notes.append(f"{avatar.name}: the soles' contact points were not measured on its skin (an "
                                  "avatar file from before they were): the sole's outline stands in; calibrate "
                                  "the avatar again to plant its skin on the floor")
        return FeetPlan(self, contacts, causal=self.stance == "causal")

    _old_soles_said = False

    def plant(self, targets: dict, frames: np.ndarray, pelvis: np.ndarray, start: int, stop: int,
              ankles: dict | None = None):
        """Feet planted (feet.py): the ankle targets (the method's, or `ankles` when it has none)
        eased onto where a rolling foot stands (its heel's, then its ball's contact point on the
        floor where the performer's are down) and kept above the floor, and the pelvis lowered where
        a planted foot is out of reach. Returns (targets, pelvis, whether the feet are planned at all).

        Decision: every frame of a planned foot is locked (`feet.roll` also keeps an unplanted sole
        above the floor), whether or not the foot is planted anywhere in the frames asked for: once
        a block without a stance was left alone, so a frame's result depended on the block it was
        solved in (the bake's chunks, a preview's single frame)."""
        if not self.feet:
            return targets, pelvis, False
        rig = self.rig
        targets = dict(targets)
        weights, aims, sides = [], [], []
        for s, (w, share, heel_at, ball_at, contact) in self.feet.rows(start, stop).items():
            name = f"ankle_{s}"
            base = targets[name] if name in targets else ankles[name]
            targets[name] = feet.roll(base, heel_at, ball_at, w, share, frames[:, BI[f"foot_{s}"]], contact)
            # a foot on its ball lets its heel rise rather than pull the pelvis down (a walker's
            # pelvis does not dip at toe-off; the drop bobbed it, and the hands with it)
            weights.append(w * (1.0 - share))
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
        up = self.src.pose(start, stop, rest=(self.user_pos, self.user_frames0), fingers=self.impl.user_fingers,
                           trunk=self.impl.user_trunk, finger_joints=self.impl.user_finger_joints)
        for n in up.notes:
            if n not in self.notes:
                self.notes.append(n)
        pelvis = root_positions(up.joints[:, JI["pelvis"]], self.k, self.centre)
        # From here on the user's frames are the ones copied onto the avatar (step 2).
        user_frames = up.frames if up.surface_frames is None else up.surface_frames
        if self.impl.trunk_copied:
            up = type(up)(up.time, up.joints, copy_frames_by(up.frames, self._copy_factor), up.valid,
                          up.notes)
        fk = self.rig.solve(up.frames, pelvis, basis=self.impl.fk_basis, realised=self.impl.realised) \
            if self.impl.uses_fk else None
        return self.impl.chunk(up, fk, pelvis, user_frames, start, stop)

    def solve_ik(self, up, fk, pelvis, targets, hands=None, frames=None, trunk=None, user_side=None):
        """Avatar IK (appendix E, DESIGN.md §6) toward the targets present: the spine when there is
        a skull-base target, then each limb whose effector has a target, then the fingers.
        `frames` (default: the user's, copied) are updated; `trunk` is the rig pose the limbs
        start from (default: solved here after the spine). `user_side`: a dict kept by a caller
        that solves the same limbs of the same `up` again (the egocentric arm passes): what the
        limbs' IK reads of the user (lengths, hinges, swivels) is computed once into it."""
        rig = self.rig
        frames = up.frames.copy() if frames is None else frames
        # Spine aimed at the skull base (appendix D: the same two-pass solver as the user's); the
        # clavicles keep their pose relative to vertebra 5.
        if "skull_base" in targets:
            spine_idx = _SPINE_ROWS
            top_right = _top_right(up.joints)

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
                frames[:, spine_idx] = matmul_stack(matmul_stack(res.rotations, held.rotations.swapaxes(-1, -2)),
                                                    up.frames[:, spine_idx])
            else:
                frames[:, spine_idx] = res.rotations
            v5 = BI[f"spine_{sk.CLAVICLE_VERTEBRA:02d}"]
            if len(frames) == 1:  # one frame: the same products, without the stacks' bookkeeping
                turn = frames[0, v5] @ up.frames[0, v5].T
                frames[0, _CLAVICLE_ROWS] = turn @ up.frames[0].take(_CLAVICLE_ROWS, axis=0)
            else:
                turn = matmul_stack(frames[:, v5], up.frames[:, v5].swapaxes(-1, -2))  # the vertebra's, both sides'
                frames[:, _CLAVICLE_ROWS] = matmul_stack(turn[:, None], up.frames[:, _CLAVICLE_ROWS])
        # The limbs hang from the trunk as solved now (or as given).
        items, names, rows = self._limb_items(tuple(targets))
        at = rig.joint_positions(frames, pelvis, names) if trunk is None else trunk.joints.take(rows, axis=1)
        reached = self._limbs(up, frames, targets, items, at, {} if user_side is None else user_side)
        grip = [side for side in sk.SIDES if hands is not None and side in hands]
        if grip:
            hand_rows, fixed, rows, bones = self._grip_plan(hands, tuple(grip))
            rel = stacks_mul(frames.take(hand_rows, axis=1).swapaxes(0, 1), fixed, rows)
            frames[:, bones] = rel.swapaxes(0, 1)
        wrists = {side: reached[side, "arm"] for side in sk.SIDES
                  if side not in grip and (side, "arm") in reached and self.has_fingers[side]}
        if wrists:
            self._fingers(frames, wrists, targets)
        return frames

    def _limbs(self, up, frames, targets, items, at, user_side: dict) -> dict:
        """Two-bone IK of the limbs `items` [(side, limb)] from their roots `at` (F, K, 3) toward
        their effector targets, all at once (those with an intermediate target, then those
        without); `frames` updated. Returns {(side, limb): the effector reached (F, 3)}.
        `user_side` keeps what the IK reads of the user per limb set (see solve_ik)."""
        nf = frames.shape[0]
        if nf == 1 and len(items) <= ik.FEW_LIMBS and one_frame.ENABLED:
            return self._limbs_one(up, frames, targets, items, at, user_side)
        reached = {}
        for group, limbs, eff_names, pole_names in self._limb_groups(tuple(items), tuple(targets)):
            root = at.take(group, axis=1).swapaxes(0, 1).reshape(-1, 3)
            eff = np.concatenate([targets[n] for n in eff_names])
            pole = np.concatenate([targets[n] for n in pole_names]) if pole_names else None
            key = limbs
            if key not in user_side:
                # Appendix E: swivel blended between the mapped intermediate target and the user's.
                # The hinge's axis: a character's upper bones twist on their own (a user's share
                # the hinge's right), so its hinge is the intermediate bone's +X.
                lengths1, lengths2, hinge_rows, joint_rows, upper, lower = self._limb_constants(limbs)
                if nf > 1:
                    lengths1, lengths2 = np.repeat(lengths1, nf), np.repeat(lengths2, nf)
                hinge = up.frames.take(hinge_rows, axis=1)[..., 0].swapaxes(0, 1).reshape(-1, 3)
                user_side[key] = (lengths1, lengths2, self._user_swivel(up, joint_rows), hinge, upper, lower)
            l1, l2, swivel, hinge, upper, lower = user_side[key]
            tb = ik.two_bone(root, l1, l2, eff, pole, swivel, hinge, size_ratio=self.k)
            frames[:, upper] = tb.rot1.reshape(len(limbs), nf, 3, 3).swapaxes(0, 1)
            frames[:, lower] = tb.rot2.reshape(len(limbs), nf, 3, 3).swapaxes(0, 1)
            for i, k in enumerate(group.tolist()):
                reached[items[k]] = tb.end[i * nf:(i + 1) * nf]
        return reached

    def _limbs_one(self, up, frames, targets, items, at, user_side: dict) -> dict:
        """`_limbs` of one frame (a live frame's, up to `ik.FEW_LIMBS` limbs): the same steps in
        Python floats (`ik.two_bone_floats`, the user's swivel in `_user_swivel_one`), read out of
        the arrays once and the bone frames written back in one scatter per limb set, where numpy's
        calls on a few items (several thousand instructions each, whatever the count) were most of
        the cost. The same values as the numpy path's kernel to its sums' rounding."""
        reached = {}
        at0 = at[0].tolist()
        # the bone frames written into `frames` seen flat (a view: `solve_ik`'s own copy), or by index
        flat = frames.reshape(-1) if frames.flags.c_contiguous else None
        for group, limbs, eff_names, pole_names in self._limb_groups(tuple(items), tuple(targets)):
            l1, l2, hinge_rows, joint_rows, bones, entries, rows, names = self._limb_one_constants(
                limbs, group, eff_names + pole_names)
            key = ("one", limbs)
            if key not in user_side:
                user_side[key] = (self._user_swivel_one(up, joint_rows),
                                  up.frames[0].take(hinge_rows, axis=0)[:, :, 0].tolist())
            swivel, hinge = user_side[key]
            aims = [targets[n].tolist()[0] for n in names]  # the effectors', then the poles' (each (1, 3))
            K = len(rows)
            out = ik.two_bone_floats([at0[k] for k in rows], l1, l2, aims[:K], aims[K:] if pole_names else None,
                                     swivel, hinge, self.k)
            # the anchored bones' frames, then the intermediate ones' (`bones`' order), then the
            # effectors reached, into numpy at once
            values = []
            for r in out:
                values += r[6:15]
            for r in out:
                values += r[15:24]
            for r in out:
                values += r[3:6]
            values = one_frame.float_array(values)
            if flat is not None:
                flat[entries] = values[:18 * K]
            else:
                frames[0, bones] = values[:18 * K].reshape(-1, 3, 3)
            ends = values[18 * K:].reshape(K, 3)
            for i, k in enumerate(rows):
                reached[items[k]] = ends[i:i + 1]
        return reached

    def _limb_one_constants(self, limbs: tuple, group: np.ndarray, names: list) -> tuple:
        """What `_limbs_one` reads of the rig and the skeleton for the limbs `limbs` (the `_limb_groups`
        plan whose rows in `items` are `group`), once per plan:
        their lengths as floats, the hinges' and joints' rows (`_limb_constants`), the anchored then
        the intermediate bones and their frames' entries in one frame's flat (B, 3, 3) block, the
        limbs' rows in `items` and the effector then intermediate targets' names."""
        cache = self.__dict__.setdefault("_limb_one_cache", {})
        key = id(group)  # one of `_limb_groups`' plans (kept there, and here with its constants)
        if key not in cache:
            lengths1, lengths2, hinge_rows, joint_rows, upper, lower = self._limb_constants(limbs)
            bones = np.concatenate([upper, lower])
            cache[key] = (lengths1.tolist(), lengths2.tolist(), hinge_rows, joint_rows, bones,
                          (bones[:, None] * 9 + np.arange(9)).ravel(), group.tolist(), list(names), group)
        return cache[key][:8]

    @staticmethod
    def _user_swivel_one(up, rows: np.ndarray) -> list:
        """`_user_swivel` of one frame in Python floats, per limb a triple (`normalize`'s sums in
        their order, `einsum`'s dot product (0 + 2) + 1)."""
        pts = up.joints[0].take(rows.T.ravel(), axis=0).tolist()  # limb by limb: anchor, mid, effector
        out = []
        for i in range(0, len(pts), 3):
            (r0, r1, r2), (m0, m1, m2), (e0, e1, e2) = pts[i:i + 3]
            a0, a1, a2 = e0 - r0, e1 - r1, e2 - r2
            n = math.sqrt((a0 * a0 + a1 * a1) + a2 * a2)
            if n > EPS:
                a0, a1, a2 = a0 / n, a1 / n, a2 / n
            else:
                a0 = a1 = a2 = 0.0
            v0, v1, v2 = m0 - r0, m1 - r1, m2 - r2
            s = (v0 * a0 + v2 * a2) + v1 * a1
            out.append((v0 - s * a0, v1 - s * a1, v2 - s * a2))
        return out

    def _grip_plan(self, hands: dict, grip: tuple) -> tuple:
        """`solve_ik`'s held fingers of the hands `grip` ({side: {canonical bone: its frame in the
        hand's}} `hands`, a method's constants), once per such set: the hands' canonical bones,
        the fingers' frames in them stacked, each finger's hand (its row in `grip`), the fingers'
        canonical bones."""
        cache = self.__dict__.setdefault("_grip_plans", {})
        key = (id(hands), grip)
        if key not in cache:
            held = [(side, b, fr) for side in grip for b, fr in hands[side].items()]
            cache[key] = (np.array([BI[f"hand_{side}"] for side in grip], int), np.array([fr for _, _, fr in held]),
                          [grip.index(x) for x, _, _ in held], np.array([BI[b] for _, b, _ in held], int), hands)
        return cache[key][:4]

    def _limb_items(self, names: tuple) -> tuple:
        """(the limbs [(side, limb)] whose effector has a target among `names`, their roots' joints,
        the roots' rows in skeleton.JOINTS), once per target set."""
        cache = self.__dict__.setdefault("_limb_items_cache", {})
        if names not in cache:
            present = set(names)
            items = [(side, limb) for side in sk.SIDES for limb, (_, _, e, _, _) in LIMBS.items()
                     if f"{e}_{side}" in present]
            roots = [f"{LIMBS[limb][0]}_{side}" for side, limb in items]
            cache[names] = (items, roots, np.array([JI[j] for j in roots], int))
        return cache[names]

    def _limb_groups(self, items: tuple, names: tuple) -> list:
        """`_limbs`' groups of the limbs `items` for the targets `names`, once per such set: those
        with an intermediate target, then those without: [(their rows in `items`, the limbs
        (side, anchor, intermediate, effector, bones), the effector targets, the intermediate ones
        (empty: none))]."""
        cache = self.__dict__.setdefault("_limb_plans", {})
        if (items, names) not in cache:
            present, out = set(names), []
            for with_pole in (True, False):
                group = [k for k, (side, limb) in enumerate(items)
                         if (f"{LIMBS[limb][1]}_{side}" in present) == with_pole]
                if not group:
                    continue
                limbs = tuple((items[k][0], *LIMBS[items[k][1]]) for k in group)
                out.append((np.array(group, int), limbs, [f"{e}_{s}" for s, _, _, e, _, _ in limbs],
                            [f"{m}_{s}" for s, _, m, _, _, _ in limbs] if with_pole else []))
            cache[items, names] = out
        return cache[items, names]

    def _limb_constants(self, limbs: tuple) -> tuple:
        """What `_limbs` reads of the rig and the skeleton for the limbs `limbs`, once per set: the
        anchored and the intermediate bones' lengths (K,), the canonical bones whose +X is each
        limb's hinge, the (anchor, intermediate, effector) joints' rows (3, K), the anchored and the
        intermediate bones' rows."""
        cache = self.__dict__.setdefault("_limb_constant_cache", {})
        if limbs not in cache:
            rig = self.rig
            cache[limbs] = (np.array([rig.lengths[BI[f"{ab}_{s}"]] for s, _, _, _, ab, _ in limbs]),
                            np.array([rig.lengths[BI[f"{mb}_{s}"]] for s, _, _, _, _, mb in limbs]),
                            np.array([BI[f"{mb if self.character else ab}_{s}"] for s, _, _, _, ab, mb in limbs]),
                            np.array([[JI[f"{limb[k]}_{limb[0]}"] for limb in limbs] for k in (1, 2, 3)]),
                            np.array([BI[f"{ab}_{s}"] for s, _, _, _, ab, _ in limbs]),
                            np.array([BI[f"{mb}_{s}"] for s, _, _, _, _, mb in limbs]))
        return cache[limbs]

    @staticmethod
    def _user_swivel(up, rows: np.ndarray) -> np.ndarray:
        """The user's swivel of the limbs whose (anchor, intermediate, effector) joints are the
        rows `rows` (3, K), stacked (K F, 3): the intermediate joint's offset from the user's own
        anchor-effector axis. Measured from the avatar's axis instead, the offset would also hold
        the angle between the two axes (the mapping moves the effector), whose direction turns
        with every millimetre of target noise when the limb is nearly straight: the upper arm's
        roll then jittered three times the user's."""
        # (3, K F, 3): the anchors, intermediates and effectors, each limb's frames together
        root, mid, eff = up.joints.take(rows, axis=1).transpose(1, 2, 0, 3).reshape(3, -1, 3)
        axis = normalize(eff - root)
        v = mid - root
        return v - np.einsum("fi,fi->f", v, axis)[:, None] * axis

    def _fingers(self, frames, wrists: dict, targets: dict) -> None:
        """Every finger of the hands in `wrists` {side: the wrist reached (F, 3)} with a tip target,
        posed at once (`pose_finger_chain` from the hand's rest finger frames); `frames` updated."""
        nf, sides = frames.shape[0], tuple(wrists)
        plan = self._finger_plan(sides, tuple(targets), nf)
        if plan is None:
            return
        items, hand_bones, rows, mcp_local, base_rest, (bones, flat), chain = plan
        if nf == 1:  # one frame: each finger's hand gathered once; the MCPs never formed
            item_hands, mcp_in_ref, tip_names, at = self._finger_one(plan)
            ref = frames[0].take(item_hands, axis=0) @ base_rest  # (K, 3, 3) the reference frames
            # ref^T (tip - mcp) with mcp = wrist + hand @ offset, ref = hand @ rest: ref^T (tip - wrist)
            # less rest^T offset, a constant (the finger set rolls nothing: its thumbs' frames carry
            # it); tip - wrist taken out of place, in float64 as tip - mcp was (a float32 target's
            # difference in place moved a finger by 3e-7)
            # (an item's (1, 3) x (3, 3) product: the einsum's terms, 4 k fewer instructions a call)
            wrist = np.concatenate([wrists[s] for s in sides]).take(rows, axis=0)
            local = np.matmul((np.concatenate([targets[n] for n in tip_names]) - wrist)[:, None], ref)[:, 0]
            local -= mcp_in_ref
            np.put(frames, at, chain.frames_floats(ref, local))  # flat: the frames' entries in its order
            return
        hands = frames.take(hand_bones, axis=1).swapaxes(0, 1)  # (S, F, 3, 3)
        mcp = np.concatenate([wrists[s] for s, _ in items]) + stacks_apply(hands, mcp_local, rows).reshape(-1, 3)
        ref = stacks_mul(hands, base_rest, rows).reshape(-1, 3, 3)
        tip = np.concatenate([targets[f"tip_{f}_{s}"] for s, f in items])
        # `pose_finger_chain`'s frames (its rest frame the reference): one frame's in one scatter
        # (a view of them, finger by finger, phalanx by phalanx), a block's phalanx by phalanx (an
        # index over its frames too cost the bake 5 % of this function)
        rots = chain.pose(mcp, ref, tip, joints=False).rotations  # (K F, 3, 3, 3)
        if nf == 1:
            frames[0, flat] = rots.reshape(-1, 3, 3)
        else:
            for i in (0, 1, 2):
                frames[:, bones[i]] = rots[:, i].reshape(len(items), nf, 3, 3).swapaxes(0, 1)

    def _finger_plan(self, sides: tuple, names: tuple, nf: int) -> tuple | None:
        """What `_fingers` gathers for the fingers with a tip target (`names`: the targets') of the
        hands `sides`, once per such set and frame count: the fingers [(side, finger)], the hands'
        canonical bones, each finger's hand (its row in `sides`), its `_finger_rest` constants
        stacked (MCP offsets, first phalanx rest frames), the canonical bones of phalanges 1, 2, 3
        (three arrays, and finger by finger in one), and the fingers' `FingerSet`; None: no finger has a target."""
        cache = self.__dict__.setdefault("_finger_plans", {})
        key = (sides, names, nf)
        if key not in cache:
            present = set(names)
            items = tuple((s, f) for s in sides for f in sk.FINGERS if f"tip_{f}_{s}" in present)
            if not items:
                cache[key] = None
                return None
            rest = self._finger_rest
            mcp_local, base_rest, lens = (np.array([rest[i][k] for i in items]) for k in range(3))
            cache[key] = (items, np.array([BI[f"hand_{s}"] for s in sides], int),
                          np.array([sides.index(s) for s, _ in items], int), mcp_local, base_rest,
                          ([np.array([BI[f"{f}_{i}_{s}"] for s, f in items], int) for i in (1, 2, 3)],
                           np.array([BI[f"{f}_{i}_{s}"] for s, f in items for i in (1, 2, 3)], int)),
                          finger_set(np.repeat(lens, nf, axis=0).T, np.repeat([f == "thumb" for _, f in items], nf)))
        return cache[key]

    @staticmethod
    def _finger_scatter(phalanges: np.ndarray) -> np.ndarray:
        """The flat positions in a one-frame (1, bones, 3, 3) array of (K, 3, 9) [item, row,
        3 phalanx + column] entries, `phalanges` (K, 3) their canonical bones."""
        rows, cols = np.arange(3)[None, :, None, None], np.arange(3)[None, None, None, :]
        return (9 * phalanges[:, None, :, None] + 3 * rows + cols).ravel()

    def _finger_one(self, plan: tuple) -> tuple:
        """What `_fingers` of one frame reads of a finger plan, once per plan: each finger's hand
        bone, the MCP offsets in the reference frames (K, 3: rest^T offset, the hand's turn
        cancelled), the tip targets' names, and where `FingerSet.frames_floats`' (K, 3, 9) entries
        go in the frames (1, bones, 3, 3) flattened: phalanx p's (row, column) at 9 bone + 3 row + column."""
        cache = self.__dict__.setdefault("_finger_ones", {})
        if id(plan) not in cache:
            items, hand_bones, rows, mcp_local, base_rest = plan[:5]
            assert plan[6].roll is None  # frames_floats takes the reference frames as given
            cache[id(plan)] = (hand_bones[rows], np.einsum("fji,fj->fi", base_rest, mcp_local),
                               [f"tip_{f}_{s}" for s, f in items],
                               self._finger_scatter(plan[5][1].reshape(-1, 3)), plan)
        return cache[id(plan)][:4]

    @property
    def _finger_rest(self) -> dict:
        """Per (side, finger), once: the MCP from the wrist and the first phalanx's rest frame, both
        in the canonical hand frame, and the phalanx lengths."""
        if getattr(self, "_fingers_at_rest", None) is None:
            rig, out = self.rig, {}
            for s in sk.SIDES:
                c0h = rig.frames0[BI[f"hand_{s}"]]
                w0 = rig.joint_world[JI[f"wrist_{s}"]]
                for f in sk.FINGERS:
                    p0 = [rig.joint_world[JI[f"{j}_{f}_{s}"]] for j in sk.FINGER_JOINTS]
                    lens = np.array([np.linalg.norm(p0[i + 1] - p0[i]) for i in range(3)])
                    out[s, f] = (c0h.T @ (p0[0] - w0), c0h.T @ rig.frames0[BI[f"{f}_1_{s}"]], lens)
            self._fingers_at_rest = out
        return self._fingers_at_rest


def _top_right(joints: np.ndarray) -> np.ndarray:
    """(F, 3) the unit direction from the right shoulder to the left (`normalize`'s; the spine's
    twist at the top); one frame's in Python floats (`normalize`'s sum in its order, the same bits)."""
    if len(joints) != 1:
        return normalize(joints[:, JI["shoulder_l"]] - joints[:, JI["shoulder_r"]])
    (l0, l1, l2), (r0, r1, r2) = joints[0].take(_SHOULDER_ROWS, axis=0).tolist()
    v0, v1, v2 = l0 - r0, l1 - r1, l2 - r2
    n = math.sqrt((v0 * v0 + v1 * v1) + v2 * v2)
    return np.array([[v0 / n, v1 / n, v2 / n] if n > EPS else [0.0, 0.0, 0.0]])


_SHOULDER_ROWS = np.array([JI["shoulder_l"], JI["shoulder_r"]], int)


class FeetPlan:
    """The stances of a take's heels and balls and where the avatar's feet are planted (feet.py),
    per side: `rows(start, stop)` {side: (weight (F,), the ball's share (F,), the heel's place (F, 2),
    the ball's place (F, 2), feet.Contact)}. Found over the whole take at once (`feet.detect`, a
    bake), or frame by frame as the frames are asked for, in order (`feet.CausalStance`, a live
    stream: each frame's from the frames before it only).

    The performer's heel (under the ankle, on the floor) and ball (the toe joint) ride on the foot
    (its tracker, or the source character's foot bone) from where they are at rest; each has its
    stance like the ankle once had. The places are the avatar's heel and ball contact points where
    the method puts the ankle, the foot turned as the performer's, averaged over their stance."""

    def __init__(self, solver: PreparedSolver, contacts: dict, causal: bool):
        self.solver, self.contacts, self.causal = solver, contacts, causal
        src = solver.src
        self.sides = [s for s in sk.SIDES if src.ankle(s, 0, 0) is not None and src.foot_turn(s, 0, 0) is not None]
        self.done = 0  # frames planned so far (causal)
        # per side: weight, share, heel's and ball's places of the frames planned so far, in buffers
        # that double when full (a live stream adds a frame at a time: never copied per frame)
        self._rows = {s: [np.zeros((0,) + shape) for shape in ((), (), (2,), (2,))] for s in self.sides}
        self.rest = {s: self._rest_points(s) for s in self.sides}
        if causal:
            rec = src.recording  # a live recording's nominal rate, else the take's
            fps = getattr(rec, "rate", None) or (rec.fps if rec is not None else (len(src.time) - 1) / max(
                float(src.time[-1] - src.time[0]), 1e-9))
            # an estimated foot's stances cut where its point has stepped, as the bake's (`feet.DRIFT`)
            self.stance = {(s, k): feet.CausalStance(float(self.rest[s][1][i, 2]), fps,
                                                     feet.DRIFT if self._estimated(s) else None)
                           for s in self.sides for i, k in enumerate(("heel", "ball"))}
        else:
            self._extend(src.frame_count)

    def _rest_points(self, s: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(the performer's ankle (3,), its heel and ball (2, 3) at the reference time, the avatar's
        heel and ball about its ankle as its foot lies when the performer stands so (2, 3))."""
        solver = self.solver
        ankle = np.asarray(solver.user_pos[f"ankle_{s}"], float)
        toe = solver.user_pos.get(f"toe_{s}")
        ball = np.asarray(toe, float) if toe is not None else ankle + solver.user_frames0[BI[f"foot_{s}"]][:, 1] * 0.1
        heel = ankle * [1.0, 1.0, 0.0]  # on the floor under the ankle
        c = self.contacts[s]
        # the avatar's foot frame when the performer stands as at the reference time (step 2's copy)
        rest = copy_frames(solver.user_frames0[None], solver.user_frames0, solver.rig.frames0)[0, BI[f"foot_{s}"]]
        return ankle, np.stack([heel, ball]), np.stack([c.heel, c.ball]) @ rest.T

    def _estimated(self, s: str) -> bool:
        """The recording's foot device on side `s` is the lower body's estimate (no foot tracker)."""
        rec = self.solver.src.recording
        devices = getattr(rec, "devices", None) or []
        return any(d.role == f"foot_{s}" and d.kind == ESTIMATED for d in devices)

    def _extend(self, stop: int) -> None:
        """Plan the frames [done, stop)."""
        solver, start = self.solver, self.done
        src = solver.src
        if stop <= start:
            return
        whole = not self.causal  # the whole take: its trackers read once for both feet
        a, b = (0, None) if whole else (start, stop)
        ankles = {s: src.ankle(s, a, b) for s in self.sides}
        tr = src.trackers(a, b)
        placed = solver.impl.ankle_places(tr) if tr is not None else None
        for s in self.sides:
            # where the method puts the ankle (AvatarGo's own target, or the user's ankle scaled about the root)
            reference = placed[f"ankle_{s}"] if placed is not None else root_positions(ankles[s], solver.k,
                                                                                        solver.centre)
            turn = src.foot_turn(s, a, b)
            rest_ankle, performer, avatar = self.rest[s]
            own = feet.foot_points(ankles[s], turn, rest_ankle, performer)  # (F, 2, 3) the performer's
            theirs = reference[:, None] + np.einsum("fij,pj->fpi", turn, avatar)  # the avatar's, there
            if whole:
                drift = feet.DRIFT if self._estimated(s) else None  # the stepper's foot: it moves only to step
                heel, ball = (feet.detect(own[:, i], src.time, float(performer[i, 2]), drift) for i in (0, 1))
                fps = (len(src.time) - 1) / max(float(src.time[-1] - src.time[0]), 1e-9)  # as `detect` takes it
                # a foot turning in place about its ankle stands on its heel (feet.with_pivots)
                heel = feet.with_pivots(heel, ball, feet.detect_pivot(ankles[s], src.time, float(rest_ankle[2])),
                                        feet.blend_frames(fps))
                heel_at, ball_at = feet.rolling_places(theirs[:, 0], theirs[:, 1], heel, ball)
                weight, share, heel_at, ball_at = feet.rolling(heel, ball, feet.blend_frames(fps), heel_at, ball_at,
                                                               theirs[:, 0], theirs[:, 1])
            else:  # live: no look-ahead, no inner weights; the ball placed from the heel's place
                t = src.time[start:stop]
                heel, ball = self.stance[s, "heel"], self.stance[s, "ball"]
                wh, heel_at = heel.update(own[:, 0], t, theirs[:, 0])
                chained = np.isfinite(heel_at[:, :1])
                ball_ref = np.where(chained, heel_at + theirs[:, 1, :2] - theirs[:, 0, :2], theirs[:, 1, :2])
                wb, ball_at = ball.update(own[:, 1], t, ball_ref)
                weight, share = np.maximum(wh, wb), feet.pivot_share(0.0 * wh, 0.0 * wb, heel.lead, ball.lead)
            self._store(s, start, stop, (weight, share, heel_at, ball_at))
        self.done = stop

    def _store(self, s: str, start: int, stop: int, rows: tuple) -> None:
        bufs = self._rows[s]
        if stop > len(bufs[0]):
            cap = max(stop, 2 * len(bufs[0]), 256) if start else stop  # a whole take: exactly its frames
            for k, old in enumerate(bufs):
                bigger = np.empty((cap,) + old.shape[1:])
                bigger[:start] = old[:start]
                bufs[k] = bigger
        for buf, new in zip(bufs, rows):
            buf[start:stop] = new

    @property
    def rows_so_far(self) -> dict:
        """{side: [weight (F,), share (F,), heel's place (F, 2), ball's place (F, 2)]} of the frames
        planned so far."""
        return {s: [b[:self.done] for b in bufs] for s, bufs in self._rows.items()}

    @property
    def weight(self) -> dict:
        """{side: (F,) the plant's weight of the frames planned so far}."""
        return {s: r[0] for s, r in self.rows_so_far.items()}

    def rows(self, start: int, stop: int) -> dict:
        if stop > self.done:
            self._extend(stop)
        return {s: (*(r[start:stop] for r in self._rows[s]), self.contacts[s]) for s in self.sides}

    def __bool__(self) -> bool:
        return bool(self.sides)
