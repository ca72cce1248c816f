"""Step 1 of the pipeline (DESIGN.md §1, §6; Delahaye 2023, appendix D): the user's canonical skeleton
animated from the trackers, vectorised over frames.

- Limbs: every joint from its calibrated locals in each tracker it is known in
  (`Joint.frames`); the intermediate joint (elbow, knee) is the mean of its positions from both
  adjacent trackers; the effector (wrist, ankle) only from its own frame; the anchored and
  intermediate bones then simply join these points (they are "scaled to meet") and keep the hinge's
  local right (`bones[hinge].extra["right_local"]` in `right_frame`), so they never twist.
- Fingers: from the fingertip markers (`<finger>_tip_<s>`) with the flexion equation and the
  yaw/pitch realignment (`fingers.pose_finger`); without markers the fingers stay as calibrated.
- Trunk: sacrum rigid on the pelvis tracker, its lateral direction and origin averaged with the hip
  line (appendix D "Trunk animation"); spine aimed at the skull base carried by the HMD
  (`ik.spine`); clavicles from vertebra 5 to the shoulders; head rigid on the HMD.
- Dropouts: the reader bridges, rides or holds a lost device (trackers.py, DESIGN.md §6 "Lost
  devices"); a joint known in several trackers is the mean of those tracking it that frame, and
  `UserPose.valid` says which frames had every device.

`UserAnimator` is prepared once per (recording, user model): which tracker carries each joint and
every constant product of the rest pose; then `animate(start, stop)` costs a few stacked products
per pass, whatever the number of frames (the prepared solver's step 1, solver.py).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..body import skeleton as sk
from ..body.bodymodel import BodyModel
from ..body.rest_frames import complete_joints, model_rest_frames
from ..body.skeleton import BONE_INDEX as BI
from ..body.skeleton import BONES, JOINTS, SPINE_BONES, SPINE_JOINTS
from ..body.skeleton import JOINT_INDEX as JI
from ..calibration.coverage import ANIMATED_ROLES
from ..core import one_frame
from ..core.errors import BodyCalError
from ..core.geometry import two_bone_mid
from ..core.transforms import (
    EPS,
    all_true,
    cross,
    frame_from_axes,
    matmul_stack,
    normalize,
    quat_between,
    quat_to_matrix,
    stack_apply,
    stacks_apply,
    stacks_mul,
)
from ..recording.model import ROLES_LIST, Recording
from . import fingers, ik
from .trackers import TrackerReader, Trackers

ARM_REACH = 0.98  # x the arm: the wrist within this of its shoulder keeps the elbow off straight
# The most a shoulder turns toward its hand about the shoulders' middle: the girdle's elevation
# (about 45°) and protraction (25-30°), and down, where the girdle drops 5-10°, the trunk's side
# bend, which the estimated trunk does not make (a Beat Saber player's low swings: with 8° down,
# 21 % of the frames stayed out of reach, p95 45 mm).
SHOULDER_REACH = math.radians(25.0)
# The elbow's flexion at most (its range of motion: active 146 degrees on average, passive 3-5
# more, Zwerus 2017): a hand nearer its shoulder than the arm folds that far turns the shoulder
# away from it (`_reach_shoulders`, within SHOULDER_REACH), as a hand beyond reach turns it toward
# it. Without it a Beat Saber player's hands held beside the head (a third of simsaber's frames,
# 5-10 cm from the estimated shoulders) folded the two-bone elbow shut (180 degrees) onto the
# shoulder-wrist line, which whirls as the hand moves by centimetres: the rotation copy's wrist
# 1.39x the controllers', 1.30x with the limit.
ELBOW_FLEX_MAX = math.radians(150.0)
# The estimated elbow's swivel (`estimated_elbow_right`; Parger 2018), vectors (out, up,
# forward) in the shoulders' frame: the hand's rest direction from its shoulder (forward and
# down; its opposite, behind and above the shoulder, the one direction where the swivel is not
# defined), the elbow's direction there (Parger's fixed elbow direction, VRArmIK's localElbowPos
# (0.3, -1, -2), seen square to it), and the share of the hand device's roll. Measured on CMU
# clips recorded with three devices (evaluation/), the swivel's median error against the clip's
# own elbow: 8-26 degrees with a share of 0.3, 6-30 with none, 10-48 turning with the roll (before);
# the hand's rest (0.4, -0.6, 0.7) against (0.2, -0.5, 0.85): the same or better on every clip
# (its p95 17-106 against 19-99 degrees), the real `tracked` take's wrist 1.38x against 1.50x.
ELBOW_HAND_REST = (0.4, -0.6, 0.7)
ELBOW_POLE = (0.3, -1.0, -2.0)
ELBOW_HAND_ROLL = 0.3
# Where that undefined direction goes instead: a hand behind and above its shoulder,
# opposite ELBOW_HAND_REST, is where the real takes' hands went (within 30 degrees of it: 10 % of
# the `tracked` take's frames, 8 % of simsaber's, 4 % of grabLeft's; a Beat Saber player's hand near
# the shoulder), and each pass flipped the elbow: simsaber's rotation copy's wrist 1.50x the
# controllers'. Straight behind the shoulder, toward the back and a little down (within 30 degrees:
# no frame of four takes, 0.01-0.06 % of the other two and the CMU clips) a hand hardly goes. Near
# the arc between the two the swivel is the pole swung from the opposite of ELBOW_UNDEFINED
# (defined there), turned into the one swung from ELBOW_HAND_REST by the shorter way between
# ELBOW_BLEND (angles from the arc's middle; the two never point opposite there, 123 degrees apart
# at most): everywhere else the swivel is what it was.
ELBOW_UNDEFINED = (-0.5, -0.1, -0.85)
ELBOW_BLEND = (math.radians(35.0), math.radians(55.0))


def _elbow_frame(rest, pole) -> tuple[np.ndarray, np.ndarray]:
    """(rest, pole) as unit vectors, the pole square to the rest direction."""
    rest = np.asarray(rest, float) / np.linalg.norm(rest)
    pole = np.asarray(pole, float)
    pole = pole - (pole @ rest) * rest
    return rest, pole / np.linalg.norm(pole)


def _swung(pole, rest, axis):
    """`pole` (square to `rest`) turned by the shortest turn from `rest` to `axis` (Rodrigues, with
    the turn's axis k = rest x axis unnormalised: v cos + k x v + k (k.v) / (1 + cos)); undefined
    where `axis` is opposite `rest`."""
    c = np.einsum("fi,fi->f", rest, axis)
    k = cross(rest, axis)
    return pole * c[:, None] + cross(k, pole) + k * (np.einsum("fi,fi->f", k, pole)
                                                     / np.maximum(1.0 + c, 1e-9))[:, None]


def _moved_frame(rest, pole, undefined) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(anchor, its pole, the arc's middle): the hand direction opposite `undefined`, the pole
    carried there by the shortest turn from `rest` (swinging it back gives `pole` again: the turns
    from u to v and from v to u are one turn's two senses), and the middle of the arc from
    -`rest` to `undefined`."""
    anchor = -np.asarray(undefined, float) / np.linalg.norm(undefined)
    middle = undefined / np.linalg.norm(undefined) - rest
    return anchor, _swung(pole[None], rest[None], anchor[None])[0], middle / np.linalg.norm(middle)


_ELBOW_FRAME = _elbow_frame(ELBOW_HAND_REST, ELBOW_POLE)
_ELBOW_MOVED = _moved_frame(*_ELBOW_FRAME, ELBOW_UNDEFINED)
LIMB_SEGMENTS = {  # side-less limb: (anchor, intermediate, effector, anchored bone, intermediate bone)
    "arm": ("shoulder", "elbow", "wrist", "upperarm", "forearm"),
    "leg": ("hip", "knee", "ankle", "thigh", "shin"),
}


@dataclass
class UserPose:
    time: np.ndarray  # (F,)
    joints: np.ndarray  # (F, J, 3) canonical joints (skeleton.JOINTS order), world
    frames: np.ndarray  # (F, B, 3, 3) canonical bone frames (skeleton.BONES order), world
    valid: np.ndarray  # (F,) every device used was tracked this frame
    notes: list[str] = field(default_factory=list)
    # (F, B, 3, 3) the frames the body's surface rides on, when not `frames` (an animated
    # character's vertebrae: rigid on its spine bones, pose_source.AnimationSource)
    surface_frames: np.ndarray | None = None

    def joint(self, name: str) -> np.ndarray:
        return self.joints[:, JI[name]]

    def take(self, start: int, stop: int) -> UserPose:
        s = slice(start, stop)
        return UserPose(self.time[s], self.joints[s], self.frames[s], self.valid[s], self.notes)


def animate_user(recording: Recording, user_model: BodyModel, start: int = 0, stop: int | None = None, *,
                 rest: tuple[dict, np.ndarray] | None = None) -> UserPose:
    """Animate the user's canonical skeleton over frames [start, stop) of `recording`. `rest`: the
    model's (complete_joints, model_rest_frames), when the caller has them."""
    return UserAnimator(recording, user_model, rest).animate(start, stop)


def _check_trackers(tr: Trackers, src: str, user_model: BodyModel) -> None:
    """Refuses a recording without the six devices every method needs, or a model without their
    reference poses."""
    for role in ANIMATED_ROLES:
        if role not in tr.pos:
            raise BodyCalError(f"no tracked device with role '{role}'", source=src, field="devices",
                               hint=f"assign device roles ({ROLES_LIST}) or record with the HMD, both hands, "
                                    "pelvis and both feet")
        if role not in tr.ref_rot:
            raise BodyCalError(f"no reference pose for '{role}' (body model extra.tpose)", source=user_model.name,
                               field="extra.tpose", hint="calibrate the user from this recording")


@dataclass
class _Plan:
    """What `UserAnimator` computes per block of frames, as index tables into the trackers
    (roles first): rotation x vector products, joint estimates (a tracker's position plus a
    product; a joint is the mean of its estimates), frames rigid on a tracker (rotation x the
    fixed R_T0^-1 C0), and the limbs, hands and fingers built on them."""

    vec_role: list = field(default_factory=list)  # products R_T(t) v: the tracker
    vec: list = field(default_factory=list)  # and v
    est_role: list = field(default_factory=list)  # estimates: the tracker
    est_vec: list = field(default_factory=list)  # and the product
    joints: dict = field(default_factory=dict)  # joint -> its estimates
    rigid_role: list = field(default_factory=list)  # rigid frames: the tracker
    rigid_fixed: list = field(default_factory=list)  # and R_T0^-1 C0
    rigid: dict = field(default_factory=dict)  # (role, what) -> rigid frame index
    limbs: list = field(default_factory=list)  # (side, limb names, right: ("vec", i) | ("rigid", i))
    toes: dict = field(default_factory=dict)  # side -> ("joint",) | ("rigid", rigid index, vector)
    hands: dict = field(default_factory=dict)  # side -> (joint names, vectors, bone indices, fixed matrices)
    tips: list = field(default_factory=list)  # fingers posed from a marker: (side, finger, marker column)
    reaching: list = field(default_factory=list)  # sides whose shoulder no arm tracker carries (`_reach_shoulders`)

    def product(self, role: str, v) -> int:
        self.vec_role.append(role)
        self.vec.append(np.asarray(v, float))
        return len(self.vec) - 1

    def estimates(self, model: BodyModel, roles: tuple, joint: str, only=None) -> list[int] | None:
        """`joint_from_trackers`'s estimates of `joint` (in the trackers `only`), None: none."""
        j = model.joints.get(joint)
        if j is None:
            return None
        out = []
        for r, loc in j.frames.items():
            if r in roles and (only is None or r in only):
                self.est_role.append(r)
                self.est_vec.append(self.product(r, np.asarray(loc, float)))
                out.append(len(self.est_role) - 1)
        return out or None

    def rigid_frame(self, role: str, what: str, fixed: np.ndarray) -> int:
        key = (role, what)
        if key not in self.rigid:
            self.rigid_role.append(role)
            self.rigid_fixed.append(fixed)
            self.rigid[key] = len(self.rigid_role) - 1
        return self.rigid[key]


class UserAnimator:
    """The user's canonical skeleton animated from the trackers of `recording` (a whole take, or a
    live buffer that grows), prepared once: `animate(start, stop)` for any block of frames. The
    plan is rebuilt when a device is tracked for the first time (its role then joins)."""

    def __init__(self, recording: Recording, user_model: BodyModel, rest: tuple[dict, np.ndarray] | None = None,
                 reader: TrackerReader | None = None):
        if user_model.kind != "user":
            raise BodyCalError(f"expected a user body model, got kind '{user_model.kind}'", source=user_model.name)
        self.recording, self.model = recording, user_model
        self.reader = reader or TrackerReader(recording, user_model)
        if rest is None:
            rest_pos = complete_joints(user_model)
            rest = rest_pos, model_rest_frames(user_model, rest_pos)
        self.rest_pos, self.C0 = rest
        self._version = None
        self._trunk_constants()

    def _trunk_constants(self) -> None:
        rest_pos, C0 = self.rest_pos, self.C0
        hipmid0 = 0.5 * (rest_pos["hip_l"] + rest_pos["hip_r"])
        self.hip_offset = C0[BI["sacrum"]].T @ (rest_pos["pelvis"] - hipmid0)
        self.sac_len = float(np.linalg.norm(rest_pos["spine_root"] - rest_pos["pelvis"]))
        rest_spine = np.stack([rest_pos[j] for j in SPINE_JOINTS])
        self.rest_segments = np.diff(rest_spine, axis=0) @ C0[BI["sacrum"]]
        self._hip_offset_floats = self.hip_offset.tolist()  # (`_trunk_one`)

    @property
    def plan(self) -> _Plan:
        if self._version != self.reader.version:
            self.reader.read(0, 0)  # the roles as far as the recording goes
            self._plan = self._make_plan()
            self._tables = self._make_tables(self._plan)
            self._one = {}  # the one-frame tables (`_one_frame_tables`) by what the tips pose, made on first use
            self._version = self.reader.version
        return self._plan

    def _make_tables(self, plan: _Plan) -> dict:
        """The plan as the index arrays `animate` gathers with, once per plan: the products' and
        rigid frames' trackers (rows of `Trackers.rotations`, roles in the reader's order), the
        joints with one estimate, and those with k estimates, by k (each the mean of its own)."""
        index = {r: k for k, r in enumerate(self.reader.roles)}
        by_count: dict[int, list] = {}
        for j, e in plan.joints.items():
            by_count.setdefault(len(e), []).append((j, e))
        which = [(s, f) for s, f, _ in plan.tips]
        axes = [(f"{b}_{s}", f"{j0}_{s}", f"{j1}_{s}") for s, _, names, _, _ in plan.limbs
                for b, j0, j1 in ((names[3], names[0], names[1]), (names[4], names[1], names[2]))]
        clavicles_root = sk.spine_joint(sk.CLAVICLE_VERTEBRA)
        axes += [(f"clavicle_{s}", clavicles_root, f"shoulder_{s}") for s in sk.SIDES]
        axes += [(b.name, b.head, b.tail) for b in _SHORTCUTS]
        self._check_placed(plan)
        return {"vec": np.array(plan.vec), "vec_rows": [index[r] for r in plan.vec_role],
                "est_rows": np.array([index[r] for r in plan.est_role], int), "est_vec": np.array(plan.est_vec, int),
                "rigid": np.array(plan.rigid_fixed), "rigid_rows": [index[r] for r in plan.rigid_role],
                "joints": [(k, np.array([JI[j] for j, _ in g], int), np.array([e for _, e in g], int))
                           for k, g in sorted(by_count.items())],
                "tips": which, "tip_columns": np.array([c for _, _, c in plan.tips], np.intp),
                "fingers": finger_constants(which, self.rest_pos, self.model.bones) if which else None,
                # the bones built from their axes at the end, in one pass (the limbs', the
                # clavicles', the shortcuts'): the bones, their heads' and tails' joints
                "axes_rows": np.array([BI[b] for b, _, _ in axes], int),
                "axes_heads": np.array([JI[h] for _, h, _ in axes], int),
                "axes_tails": np.array([JI[t] for _, _, t in axes], int),
                # frames rigid on a device as they are: the head, the feet, the hands
                "rigid_bones": np.array([BI[b] for b in _RIGID_BONES], int),
                "rigid_frames": np.array([plan.rigid[_RIGID_KEYS[b]] for b in _RIGID_BONES], int),
                # both hands' finger joints and frames (rigid on the hand as calibrated) at once
                "hand_joints": np.array([JI[n] for s in sk.SIDES for n in plan.hands[s][0]], int),
                "hand_vecs": np.concatenate([plan.hands[s][1] for s in sk.SIDES]),
                "hand_bones": np.concatenate([plan.hands[s][2] for s in sk.SIDES]),
                "hand_fixed": np.concatenate([plan.hands[s][3] for s in sk.SIDES]),
                "hand_rows": (np.repeat(np.arange(2), [len(plan.hands[s][1]) for s in sk.SIDES]),
                              np.repeat(np.arange(2), [len(plan.hands[s][3]) for s in sk.SIDES])),
                "hand_frames": np.array([plan.rigid[f"hand_{s}", "hand"] for s in sk.SIDES], int)}

    @staticmethod
    def _check_placed(plan: _Plan) -> None:
        """Every joint is written by one of `animate`'s stages (its block of joints is allocated,
        not filled): those with estimates, the limbs' two-bone joints, the toes rigid on the foot,
        the spine and clavicles, the hands'."""
        placed = set(plan.joints) | set(SPINE_JOINTS) | {f"clavicle_{s}" for s in sk.SIDES}
        placed |= {f"{names[1]}_{s}" for s, _, names, _, tracked in plan.limbs if not tracked}
        placed |= {f"toe_{s}" for s, toe in plan.toes.items() if toe[0] == "rigid"}
        placed |= {n for s in sk.SIDES for n in plan.hands[s][0]}
        missing = [j for j in JOINTS if j not in placed]
        if missing:
            raise BodyCalError(f"the user animation would not place the joints {missing}",
                               hint="report this: the animation plan misses them")

    def _need(self, joint: str, value):
        """`value`, or one error when no tracked device knows `joint`."""
        if value is None:
            raise BodyCalError(f"joint '{joint}' is not known in any tracked device", source=self.model.name,
                               field=f"joints.{joint}.frames", hint="calibrate the user with these trackers")
        return value

    def _make_plan(self) -> _Plan:
        rd, model, C0 = self.reader, self.model, self.C0
        _check_trackers(rd.read(0, 0), self.recording.source or self.recording.name, model)
        roles, plan = rd.roles, _Plan()
        for j in ("skull_base", "head", "pelvis"):
            plan.joints[j] = self._need(j, plan.estimates(model, roles, j, ["pelvis" if j == "pelvis" else "head"]))
        plan.rigid_frame("head", "head", rd.ref_rot["head"].T @ C0[BI["head"]])
        plan.rigid_frame("pelvis", "sacrum", rd.ref_rot["pelvis"].T @ C0[BI["sacrum"]])
        for s in sk.SIDES:
            for limb, names in LIMB_SEGMENTS.items():
                self._plan_limb(plan, s, limb, names)
            toe = self._own_frame(plan, f"toe_{s}")
            if toe is not None:
                plan.joints[f"toe_{s}"] = toe
                plan.toes[s] = ("joint",)
            else:
                k = plan.rigid_frame(f"foot_{s}", "eye", rd.ref_rot[f"foot_{s}"].T @ np.eye(3))
                plan.toes[s] = ("rigid", k, self.rest_pos[f"toe_{s}"] - self.rest_pos[f"ankle_{s}"])
            for part in ("foot", "hand"):
                plan.rigid_frame(f"{part}_{s}", part, rd.ref_rot[f"{part}_{s}"].T @ C0[BI[f"{part}_{s}"]])
            self._plan_hand(plan, s)
        return plan

    def _own_frame(self, plan: _Plan, joint: str):
        """An effector's estimate from its own (first) tracker only."""
        j = self.model.joints.get(joint)
        for r in (j.frames if j is not None else ()):
            if r in self.reader.roles:
                return plan.estimates(self.model, self.reader.roles, joint, [r])
        return None

    def _plan_limb(self, plan: _Plan, s: str, limb: str, names: tuple) -> None:
        """Anchor, intermediate and effector joints of a limb, and the hinge's right (`_hinge_right`)."""
        a, m, e, ab, mb = names
        model, roles = self.model, self.reader.roles
        # The anchor rides on its limb's tracker (the root tracker's estimate ignores the
        # clavicle / pelvis-side motion); the root tracker only when the limb has none.
        anchor = plan.estimates(model, roles, f"{a}_{s}", [f"{ab}_{s}"])
        plan.joints[f"{a}_{s}"] = self._need(f"{a}_{s}", anchor or plan.estimates(model, roles, f"{a}_{s}"))
        plan.joints[f"{e}_{s}"] = self._need(f"{e}_{s}", self._own_frame(plan, f"{e}_{s}"))
        mid = plan.estimates(model, roles, f"{m}_{s}")
        if mid is not None:
            plan.joints[f"{m}_{s}"] = mid
        if limb == "arm" and anchor is None and mid is None:
            plan.reaching.append(s)
        eff_role = f"{'hand' if limb == 'arm' else 'foot'}_{s}"
        plan.limbs.append((s, limb, names, self._hinge_right(plan, f"{mb}_{s}", eff_role), mid is not None))

    def _hinge_right(self, plan: _Plan, bone: str, eff_role: str) -> tuple:
        """The hinge's right: its calibrated local right in its tracker, else the rest right carried
        by the limb's intermediate tracker or its end device (never another limb's: a knee carried
        by a hand turned with the wrist), else the effector tracker's rigid frame's +X."""
        rd, model = self.reader, self.model
        info = model.bones.get(bone)
        ex = info.extra if info is not None else {}
        role = ex.get("right_frame")
        if role in rd.roles and ex.get("right_local") is not None:
            return ("vec", plan.product(role, normalize(np.asarray(ex["right_local"], float))))
        carriers = ("forearm", "hand") if bone.startswith("forearm_") else ("shin", "foot")
        for r in carriers:  # the rest right carried by the limb's intermediate tracker, else its end device
            role = f"{r}_{bone.rsplit('_', 1)[-1]}"
            if role in rd.roles and role in rd.ref_rot and info is not None and info.right is not None:
                return ("vec", plan.product(role, rd.ref_rot[role].T @ info.right))
        return ("rigid", plan.rigid_frame(eff_role, bone, rd.ref_rot[eff_role].T @ self.C0[BI[bone]]))

    def _plan_hand(self, plan: _Plan, s: str) -> None:
        """Finger joints and frames rigid on the hand as calibrated, and the fingers with a tip marker."""
        rest_pos, C0 = self.rest_pos, self.C0
        c0h = C0[BI[f"hand_{s}"]]
        names, vecs, bones, fixed = [], [], [], []
        for f in sk.FINGERS:
            for jn in sk.FINGER_JOINTS:
                names.append(f"{jn}_{f}_{s}")
                vecs.append(c0h.T @ (rest_pos[names[-1]] - rest_pos[f"wrist_{s}"]))
            for b in [f"metacarpal_{f}_{s}"] + [f"{f}_{i}_{s}" for i in (1, 2, 3)]:
                bones.append(BI[b])
                fixed.append(c0h.T @ C0[BI[b]])
            tip = f"{f}_tip_{s}"
            if tip in self.recording.marker_names:
                col = self.recording.marker_names.index(tip)
                if self.reader.marker_seen(col):
                    plan.tips.append((s, f, col))
        plan.hands[s] = (names, np.array(vecs), np.array(bones), np.array(fixed))

    def _one_frame_tables(self, plan: _Plan, posed: tuple = (False, False)) -> dict:
        """The plan for ONE frame (`_animate_one`), once per plan. Every product of a tracker's
        rotation with a constant (the products, the rigid frames' columns, and those of the hands'
        finger joints and frames and of the toes rigid on the foot, their two constants multiplied
        together) is one row of `V` (C, 3), `roles` (C,) its tracker: one product of the rotations
        gathered by `roles` with them (einsum: one call, where a stacked matmul makes a BLAS call
        per product) gives them all. Every joint of the trackers alone (the mean of
        its estimates; the hands' and toes' joints their wrist's or ankle's plus a product) is a
        weighted sum of at most `TERMS` of the trackers' positions and those products.
        `posed` (frames, joints): whether `pose_user_fingers` then overwrites the tipped fingers'
        second and third phalanges' frames, and their joints after the MCP: those are not computed
        (their rows are left unset; the first phalanx's frame and the MCP, which it reads, are)."""
        tab, nr = self._tables, len(self.reader.roles)
        tipped = {(s, f) for s, f, _ in plan.tips}
        skip_bones = {BI[f"{f}_{i}_{s}"] for s, f in tipped for i in (2, 3)} if posed[0] else set()
        skip_joints = ({f"{j}_{f}_{s}" for s, f in tipped for j in sk.FINGER_JOINTS[1:]} if posed[1] else set())
        roles, vecs = [], []

        def column(row: int, v) -> int:
            roles.append(row)
            vecs.append(np.asarray(v, float))
            return nr + len(vecs) - 1  # its row in (the positions, the products)

        vec_at = [column(r, v) for r, v in zip(tab["vec_rows"], plan.vec)]
        rigid_at = [[column(r, m[:, i]) for i in range(3)] for r, m in zip(tab["rigid_rows"], plan.rigid_fixed)]
        terms: dict[str, list] = {}  # joint -> [(row in (positions, products), weight)]
        for j, ests in plan.joints.items():
            k = len(ests)
            terms[j] = [(t, 1.0 / k) for e in ests for t in (int(tab["est_rows"][e]), vec_at[int(tab["est_vec"][e])])]
        frame_bones, frame_cols = [], []
        for b, key in zip(_RIGID_BONES, _RIGID_KEYS.values()):
            frame_bones.append(BI[b])
            frame_cols.append(rigid_at[plan.rigid[key]])
        for s in sk.SIDES:
            names, hand_vecs, bones, fixed = plan.hands[s]
            h = plan.rigid[f"hand_{s}", "hand"]
            row, carry = tab["rigid_rows"][h], plan.rigid_fixed[h]
            for n, v in zip(names, hand_vecs):
                if n not in skip_joints:
                    terms[n] = terms[f"wrist_{s}"] + [(column(row, carry @ v), 1.0)]
            for b, m in zip(bones, fixed):
                if int(b) in skip_bones:
                    continue
                frame_bones.append(int(b))
                frame_cols.append([column(row, (carry @ m)[:, i]) for i in range(3)])
            toe = plan.toes[s]
            if toe[0] == "rigid":
                terms[f"toe_{s}"] = terms[f"ankle_{s}"] + [
                    (column(tab["rigid_rows"][toe[1]], plan.rigid_fixed[toe[1]] @ toe[2]), 1.0)]
        frame_cols.append(rigid_at[plan.rigid["pelvis", "sacrum"]])  # the sacrum's rigid frame, last
        width = max(len(t) for t in terms.values())
        rows, weights = np.zeros((len(terms), width), int), np.zeros((len(terms), width))
        for i, ts in enumerate(terms.values()):  # padded with weight 0 on the first position
            rows[i, :len(ts)] = [t for t, _ in ts]
            weights[i, :len(ts)] = [w for _, w in ts]
        rights = [vec_at[k] if kind == "vec" else rigid_at[k][0] for _, _, _, (kind, k), _ in plan.limbs]
        multi = sorted({int(tab["est_rows"][e]) for ests in plan.joints.values() if len(ests) > 1 for e in ests})
        return {"V": np.array(vecs), "roles": np.array(roles, int), "terms": rows, "weights": weights,
                "rows": np.array([JI[j] for j in terms], int), "frame_bones": np.array(frame_bones, int),
                "frame_cols": np.array(frame_cols, int), "rights": np.array(rights, int),
                "hint_rows": np.repeat(np.arange(len(rights)), 2), "multi": np.array(multi, int) if multi else None}

    def _animate_one(self, plan: _Plan, start: int, tr: Trackers, fingers: bool = True,
                     trunk: bool = True, finger_joints: bool = True) -> UserPose | None:
        """`animate` of ONE frame with few numpy calls (`_one_frame_tables`: the products in one
        stacked product, the trackers' joints in one weighted sum, the frames rigid on a device in
        one gather), then the same passes as a block's (the limbs without a tracker, the trunk, the
        fingers, the bones built from their axes): the block's values to float64's rounding. None
        (the block's path then) where a joint's estimates are not all tracked this frame (their
        mean is then over those tracked, `_mean_estimates`)."""
        posed = (bool(plan.tips) and fingers, bool(plan.tips) and fingers and finger_joints)
        one = self._one.get(posed)
        if one is None:
            one = self._one[posed] = self._one_frame_tables(plan, posed)
        if one["multi"] is not None and tr.tracked is not None and not all_true(tr.tracked.take(one["multi"], 0)):
            return None
        tab = self._tables
        # (the positions, the products R_T(t) v) (R + C, 3)
        X = np.concatenate((tr.positions[:, 0], np.einsum("cij,cj->ci", tr.rotations[:, 0].take(one["roles"], axis=0),
                                                          one["V"])))
        pos = np.empty((1, len(JOINTS), 3))
        pos[0, one["rows"]] = np.einsum("jt,jti->ji", one["weights"], X.take(one["terms"], axis=0))
        Fr = np.empty((1, len(BONES), 3, 3))
        rigid = X.take(one["frame_cols"], axis=0).swapaxes(1, 2)  # (n, 3, 3): columns laid out
        Fr[0, one["frame_bones"]] = rigid[:-1]
        P = _Joints(pos)
        self._reach_shoulders(plan, P)
        rights = X.take(one["rights"], axis=0)  # (limbs, 3) the hinges' rights
        limb_hints = rights.take(one["hint_rows"], axis=0)  # (2 limbs, 3) both bones' x hints
        for i, (s, limb, (a, m, e, _, _), _, tracked) in enumerate(plan.limbs):
            if not tracked:  # no tracker carries it: two-bone from the user's lengths (`_limbs`)
                right = limb_hints[2 * i] = self._hinge(P, s, limb, rights[i:i + 1])[0]
                P[f"{m}_{s}"] = _two_bone_mid(P[f"{a}_{s}"], P[f"{e}_{s}"], self.rest_pos, a, m, e, s,
                                              right[None])
        hinted: list = []
        (self._trunk if trunk else _rigid_trunk)(P, Fr, rigid[-1:], hinted)
        if plan.tips and fingers:
            tips = self.reader.markers(tab["tip_columns"], start, start + 1)
            pose_user_fingers(P, Fr, tab["tips"], tips, self.rest_pos, self.model.bones, tab["fingers"], finger_joints)
        sacrum_x = Fr[:, BI["sacrum"], :, 0]
        hints = np.concatenate([limb_hints] + hinted + [sacrum_x] * len(_SHORTCUTS))
        ys = pos[0].take(tab["axes_tails"], axis=0) - pos[0].take(tab["axes_heads"], axis=0)
        Fr[0, tab["axes_rows"]] = frame_from_axes(ys, hints)
        if not math.isfinite(pos.sum() + Fr.sum()):  # (a sum of finite values overflows only beyond 1e300)
            raise BodyCalError("the user animation has non-finite values",
                               source=self.recording.source or self.recording.name,
                               hint="check the recording for broken device poses")
        return UserPose(self.recording.time[start:start + 1], pos, Fr, tr.valid, tr.notes)

    # --- per block of frames ------------------------------------------------------------------

    def animate(self, start: int = 0, stop: int | None = None, trackers: Trackers | None = None,
                fingers: bool = True, trunk: bool = True, finger_joints: bool = True) -> UserPose:
        """The canonical joints and bone frames of frames [start, stop); `trackers`: those frames'
        as `self.reader` reads them, when the caller has them already. For a caller that reads
        none of them (`Method.user_fingers`, `Method.user_trunk`): `fingers` False, the fingers
        stay rigid on the hand as calibrated (not posed from their tip markers); `trunk` False,
        the trunk pass is not run (`_rigid_trunk`: the pelvis tracker's estimate, the sacrum rigid
        on its tracker, the vertebrae and clavicles placeholders at the pelvis); `finger_joints`
        False, the fingers' frames are posed from their tip markers but their joints after the MCP
        stay rigid on the hand as calibrated (the rotation copy reads the frames only)."""
        plan = self.plan
        tab = self._tables
        stop = self.recording.frame_count if stop is None else stop
        tr = self.reader.read(start, stop) if trackers is None else trackers
        if stop - start == 1 and one_frame.ENABLED:
            pose = self._animate_one(plan, start, tr, fingers, trunk, finger_joints)
            if pose is not None:
                return pose
        prod = stacks_apply(tr.rotations, tab["vec"], tab["vec_rows"])
        est = tr.positions.take(tab["est_rows"], axis=0) + prod.take(tab["est_vec"], axis=0)
        rigid = stacks_mul(tr.rotations, tab["rigid"], tab["rigid_rows"])
        # Every joint is written where it goes, a stage's joints at once, and read as views
        # (`_Joints`; a dict of each joint's array joined at the end cost a tenth of a one-frame
        # animation); every joint is written (`_check_placed`).
        pos = np.empty((stop - start, len(JOINTS), 3))
        P = _Joints(pos)
        for k, rows, ests in tab["joints"]:  # a joint is the mean of its estimates (np.mean's sum / k)
            value = est.take(ests[:, 0], axis=0) if k == 1 else self._mean_estimates(est, ests, tab["est_rows"], tr)
            P.put(rows, value)
        Fr = np.empty((stop - start, len(BONES), 3, 3))
        Fr[:, tab["rigid_bones"]] = rigid.take(tab["rigid_frames"], axis=0).swapaxes(0, 1)  # head, feet, hands
        # The bones built from their axes (the limbs', the clavicles', the shortcuts'), in one pass
        # at the end: a frame from its axes is its own item's arithmetic, and no limb or clavicle
        # joint is written after its stage, so the values are each stage's. `hints`: their x hints.
        hints: list = []
        self._limbs(plan, P, prod, rigid, hints)
        (self._trunk if trunk else _rigid_trunk)(P, Fr, rigid[plan.rigid["pelvis", "sacrum"]], hints)
        self._hands(plan, P, Fr, rigid, start, stop, fingers, finger_joints)
        # shortcut bones (and hips): rigid in the sacrum's lateral, for the mapping's paths
        hints += [Fr[:, BI["sacrum"]][..., :, 0]] * len(_SHORTCUTS)
        ys = pos.take(tab["axes_tails"], axis=1) - pos.take(tab["axes_heads"], axis=1)  # (F, bones, 3)
        Fr[:, tab["axes_rows"]] = frame_from_axes(ys, np.stack(hints, axis=1))
        if not np.isfinite(pos).all() or not np.isfinite(Fr).all():
            raise BodyCalError("the user animation has non-finite values",
                               source=self.recording.source or self.recording.name,
                               hint="check the recording for broken device poses")
        return UserPose(self.recording.time[start:stop], pos, Fr, tr.valid, tr.notes)

    @staticmethod
    def _mean_estimates(est: np.ndarray, rows: np.ndarray, est_rows: np.ndarray, tr: Trackers) -> np.ndarray:
        """The mean of each joint's estimates (`rows`, (J, k) into `est`) over the trackers tracking
        it each frame (a lost one rides on its carrier, DESIGN.md §6 "Lost devices": the knee follows
        the shin while the thigh is lost), over all of them where none is."""
        k = rows.shape[1]
        if tr.tracked is None:
            return est[rows].sum(axis=1) / k
        w = tr.tracked[est_rows[rows]]  # (J, k, F)
        if w.all():
            return est[rows].sum(axis=1) / k
        w = np.where(w.any(axis=1, keepdims=True), w, True).astype(float)
        return np.einsum("jkf,jkfi->jfi", w, est[rows]) / w.sum(axis=1)[..., None]

    def _limbs(self, plan: _Plan, P: _Joints, prod: np.ndarray, rigid: np.ndarray, hints: list) -> None:
        """Limbs pass: the intermediate joints without a tracker (two-bone from the user's lengths),
        the toes, and the hinge's right, the x hint of both limb bones (they join the joints and keep
        it: built by `animate`)."""
        self._reach_shoulders(plan, P)
        rights = {}
        for s, limb, _, (kind, k), _ in plan.limbs:
            rights[s, limb] = prod[k] if kind == "vec" else rigid[k][..., :, 0]
        bent = {}  # the hinges of the limbs bent here, where not their device's right
        for s, limb, (a, m, e, _, _), _, tracked in plan.limbs:
            if not tracked:  # no tracker carries it (minimal profile): two-bone from the user's lengths
                right = bent[s, limb] = self._hinge(P, s, limb, rights[s, limb])
                P[f"{m}_{s}"] = _two_bone_mid(P[f"{a}_{s}"], P[f"{e}_{s}"], self.rest_pos, a, m, e, s, right)
        for s, limb, _, _, _ in plan.limbs:
            # the anchored bone's x hint is the hinge it bends about; the intermediate bone's
            # keeps its device's right (a forearm turns with the hand's pronation)
            hints += [bent.get((s, limb), rights[s, limb]), rights[s, limb]]
        for s in sk.SIDES:
            toe = plan.toes[s]
            if toe[0] == "rigid":
                P[f"toe_{s}"] = P[f"ankle_{s}"] + stack_apply(rigid[toe[1]], toe[2])

    @staticmethod
    def _hinge(P: _Joints, s: str, limb: str, right: np.ndarray) -> np.ndarray:
        """The hinge an untracked intermediate joint bends about: an arm's from the hand's place
        (`estimated_elbow_right`), a leg's its foot device's `right` (a foot does not roll apart
        from its shin the way a controller rolls with the wrist)."""
        if limb != "arm":
            return right
        return estimated_elbow_right(P[f"shoulder_{s}"], P[f"wrist_{s}"], P["shoulder_l"] - P["shoulder_r"],
                                     1.0 if s == sk.SIDES[0] else -1.0, P["skull_base"], P["pelvis"], right)

    def _reach_shoulders(self, plan: _Plan, P: _Joints) -> None:
        """Shoulder pass, for shoulders no arm tracker carries: a wrist beyond `ARM_REACH` of its
        arm turns its shoulder toward it about the shoulders' middle (the shoulder girdle's
        protraction and elevation, and a side bend), at most `SHOULDER_REACH`; a wrist nearer than
        the arm folds (`ELBOW_FLEX_MAX`) turns it away as far; the frames between keep their
        shoulder to the bit. A Beat Saber player's controllers are beyond the arms of a rigid
        trunk on 36 % of the frames (p95 74 mm); the shoulder's turn leaves 1.5 % (DESIGN.md §6
        "A lower body from head and hands")."""
        if not plan.reaching:
            return
        mid = 0.5 * (P["shoulder_l"] + P["shoulder_r"])
        moved = {}
        for s in plan.reaching:
            sh, wr = P[f"shoulder_{s}"], P[f"wrist_{s}"]
            reach, fold = ARM_REACH * self._arm_length(s), self._fold_distance(s)
            d2 = np.einsum("fi,fi->f", wr - sh, wr - sh)
            far = d2 > reach * reach
            out = far | (d2 < fold * fold)
            if out.any():
                moved[s] = (out, _shoulder_toward(mid[out], sh[out], wr[out], np.where(far[out], reach, fold)))
        for s, (out, value) in moved.items():
            P.pos[out, JI[f"shoulder_{s}"]] = value

    def _fold_distance(self, s: str) -> float:
        """The wrist's distance from its shoulder with the elbow flexed ELBOW_FLEX_MAX (the law of
        cosines over the user's two arm bones)."""
        l1, l2 = self._arm_bones(s)
        return math.sqrt(l1 * l1 + l2 * l2 + 2.0 * l1 * l2 * math.cos(ELBOW_FLEX_MAX))

    def _arm_length(self, s: str) -> float:
        upper, fore = self._arm_bones(s)
        return upper + fore

    def _arm_bones(self, s: str) -> tuple[float, float]:
        """The user's upper arm and forearm lengths at rest, once a side (a three-point frame's
        shoulder pass reads them for each reaching side)."""
        cache = self.__dict__.setdefault("_arm_bone_lengths", {})
        if s not in cache:
            r = self.rest_pos
            cache[s] = tuple(float(np.linalg.norm(r[b] - r[a]))
                             for a, b in ((f"shoulder_{s}", f"elbow_{s}"), (f"elbow_{s}", f"wrist_{s}")))
        return cache[s]

    def _trunk(self, P: _Joints, Fr: np.ndarray, sac: np.ndarray, hints: list) -> None:
        """Trunk pass (appendix D "Trunk animation"): the sacrum's lateral and origin averaged with the
        hip line, the spine aimed at the skull base with its twist shared hips -> shoulders -> head
        (`ik.spine`), and the clavicles (their x hint: built by `animate`). Needs the limbs and head."""
        if len(sac) == 1 and one_frame.ENABLED:
            return self._trunk_one(P, Fr, sac, hints)
        hip_l, hip_r = P["hip_l"], P["hip_r"]
        sac = sacrum_toward_hip_line(sac, hip_l, hip_r)
        from_hips = 0.5 * (hip_l + hip_r) + stack_apply(sac, self.hip_offset)
        pelvis = 0.5 * (P["pelvis"] + from_hips)  # the pelvis tracker's estimate and the hips'
        P["pelvis"] = pelvis
        res = ik.spine(pelvis, sac, self.sac_len, None, np.ascontiguousarray(P["skull_base"]),
                       top_right=normalize(P["shoulder_l"] - P["shoulder_r"]), two_pass=False,
                       rest_segments=self.rest_segments)
        _spine_written(P, Fr, res, hints)

    def _trunk_one(self, P: _Joints, Fr: np.ndarray, sac: np.ndarray, hints: list) -> None:
        """`_trunk` of ONE frame: its few vectors (the sacrum turned toward the hip line, the hips'
        and the tracker's pelvis, the shoulders' line) in Python floats, float64, read out in one
        call and handed to the spine IK in one array (each numpy call on a single vector costs
        5,000-10,000 instructions, a float operation about 130), the spine IK (`ik.spine`) as the
        block's; the sums in numpy's order."""
        pos = P.pos[0]
        hl, hr, pe, sl, sr = pos.take(_TRUNK_ROWS, axis=0).tolist()
        rows = _sacrum_turned(sac[0].tolist(), hl, hr)
        if rows is None:  # a vanishing hip line: numpy's fallbacks
            rows = sacrum_toward_hip_line(sac, P["hip_l"], P["hip_r"])[0].tolist()
        (a0, a1, a2), (b0, b1, b2), (c0, c1, c2) = rows
        o0, o1, o2 = self._hip_offset_floats
        # the hips' pelvis, 0.5 (hip_l + hip_r) + sacrum offset, and the tracker's, averaged
        pelvis = [0.5 * (pe[0] + (0.5 * (hl[0] + hr[0]) + ((a0 * o0 + a1 * o1) + a2 * o2))),
                  0.5 * (pe[1] + (0.5 * (hl[1] + hr[1]) + ((b0 * o0 + b1 * o1) + b2 * o2))),
                  0.5 * (pe[2] + (0.5 * (hl[2] + hr[2]) + ((c0 * o0 + c1 * o1) + c2 * o2)))]
        t0, t1, t2 = sl[0] - sr[0], sl[1] - sr[1], sl[2] - sr[2]  # the shoulders' line, normalised
        size = math.sqrt((t0 * t0 + t1 * t1) + t2 * t2)
        top = [t0 / size, t1 / size, t2 / size] if size > EPS else [0.0, 0.0, 0.0]
        arr = np.array([pelvis, top, *rows])  # (5, 3): pelvis, the top's right, the sacrum's rows
        pos[JI["pelvis"]] = arr[0]
        res = ik.spine(arr[0:1], arr[None, 2:], self.sac_len, None, pos[None, JI["skull_base"]],
                       top_right=arr[1:2], two_pass=False, rest_segments=self.rest_segments)
        _spine_written(P, Fr, res, hints)

    def _hands(self, plan: _Plan, P: _Joints, Fr: np.ndarray, rigid: np.ndarray, start: int, stop: int,
               fingers: bool = True, finger_joints: bool = True) -> None:
        """Hands pass: finger joints and frames rigid on the hand as calibrated, both hands at once,
        then the fingers with a tip marker posed from it, all at once (`pose_user_fingers`;
        forward-filled over its dropouts)."""
        tab = self._tables
        hands = rigid.take(tab["hand_frames"], axis=0)  # (2, F, 3, 3)
        vec_rows, fixed_rows = tab["hand_rows"]  # each product's hand
        rel = stacks_apply(hands, tab["hand_vecs"], vec_rows)
        wrists = P.pos.take(_WRIST_JOINT_ROWS, axis=1).swapaxes(0, 1)  # (2, F, 3)
        P.put(tab["hand_joints"], wrists.take(vec_rows, axis=0) + rel)
        Fr[:, tab["hand_bones"]] = stacks_mul(hands, tab["hand_fixed"], fixed_rows).swapaxes(0, 1)
        if plan.tips and fingers:
            tips = self.reader.markers(tab["tip_columns"], start, stop)
            pose_user_fingers(P, Fr, tab["tips"], tips, self.rest_pos, self.model.bones, tab["fingers"],
                              finger_joints)


def _rigid_trunk(P: _Joints, Fr: np.ndarray, sac: np.ndarray, hints: list) -> None:
    """`UserAnimator._trunk`'s outputs where a caller reads none of them (`animate`'s `trunk`
    False): the sacrum rigid on the pelvis tracker (`sac`), the vertebrae turned with it, their
    joints and the clavicles' at the pelvis, the clavicles' x hint the sacrum's lateral (finite
    values, so the checks and the frames built from axes stand; nothing of the trunk's IK)."""
    Fr[:, BI["sacrum"]] = sac
    Fr[:, _SPINE_ROWS] = sac[:, None]
    at = P["pelvis"][:, None]
    P.pos[:, _SPINE_JOINT_ROWS] = at
    P.pos[:, _CLAVICLE_JOINT_ROWS] = at
    hints += [sac[..., :, 0]] * len(sk.SIDES)


class _Joints:
    """A block's joints (F, J, 3) (`skeleton.JOINTS` order) by name: a joint read is a view, a
    joint written goes where it belongs; `put` writes a stage's joints (n, F, 3) at once."""

    __slots__ = ("pos",)

    def __init__(self, pos: np.ndarray):
        self.pos = pos

    def __getitem__(self, joint: str) -> np.ndarray:
        return self.pos[:, JI[joint]]

    def __setitem__(self, joint: str, value: np.ndarray) -> None:
        self.pos[:, JI[joint]] = value

    def put(self, rows: np.ndarray, values: np.ndarray) -> None:
        self.pos[:, rows] = values.swapaxes(0, 1)


_SHORTCUTS = [b for b in BONES if b.shortcut]
_SPINE_ROWS = np.array([BI[b] for b in SPINE_BONES], int)
_SPINE_JOINT_ROWS = np.array([JI[j] for j in SPINE_JOINTS], int)
_CLAVICLE_JOINT_ROWS = np.array([JI[f"clavicle_{s}"] for s in sk.SIDES], int)
_TRUNK_ROWS = np.array([JI[j] for j in ("hip_l", "hip_r", "pelvis", "shoulder_l", "shoulder_r")], int)
_WRIST_JOINT_ROWS = np.array([JI[f"wrist_{s}"] for s in sk.SIDES], int)
_CLAVICLE_SPINE_ROW = SPINE_BONES.index(f"spine_{sk.CLAVICLE_VERTEBRA:02d}")  # the vertebra the clavicles hang from
# the frames rigid on a device (R_T(t) R_T0^-1 C0), as they are: bone -> its rigid frame's key in _Plan.rigid
_RIGID_KEYS = {"head": ("head", "head"), **{f"{part}_{s}": (f"{part}_{s}", part) for s in sk.SIDES
                                            for part in ("foot", "hand")}}
_RIGID_BONES = list(_RIGID_KEYS)


def _spine_written(P: _Joints, Fr: np.ndarray, res, hints: list) -> None:
    """The trunk pass's spine IK result (`ik.spine`, one pass: its sacrum the one it was given)
    written into the joints and frames, and the clavicles' x hint."""
    Fr[:, BI["sacrum"]] = res.sacrum_rot
    P.pos[:, _SPINE_JOINT_ROWS] = res.joints
    Fr[:, _SPINE_ROWS] = res.rotations
    P.pos[:, _CLAVICLE_JOINT_ROWS] = res.joints[:, sk.CLAVICLE_VERTEBRA, None]
    hints += [res.rotations[:, _CLAVICLE_SPINE_ROW][..., :, 2]] * len(sk.SIDES)


def sacrum_toward_hip_line(sacrum: np.ndarray, hip_l: np.ndarray, hip_r: np.ndarray) -> np.ndarray:
    """The sacrum frame (..., 3, 3) turned so its lateral axis lies half way to the hip line
    (Delahaye 2023, appendix D "Trunk animation"): the pelvis tracker's mounting and the fitted
    hip centres each carry their own error, and their average is never worse than the worse of them.
    One frame: the same turn in Python floats (`_sacrum_turned`), where neither vector vanishes."""
    if sacrum.shape[:-2] == (1,) and one_frame.ENABLED:
        rows = _sacrum_turned(sacrum[0].tolist(), hip_l[0].tolist(), hip_r[0].tolist())
        if rows is not None:
            return np.array(rows)[None]
    x_rigid = sacrum[..., :, 0]
    toward = normalize(x_rigid + normalize(hip_l - hip_r))
    return matmul_stack(quat_to_matrix(quat_between(x_rigid, toward)), sacrum)


def _sacrum_turned(rows: list, hip_l: list, hip_r: list) -> list | None:
    """`sacrum_toward_hip_line` of one frame in Python floats (float64): the sacrum's rows (3
    lists) turned by the shortest turn from its lateral x to t = x + the hip line's unit vector,
    normalised (R = c I + [k]x + k k^T / (1 + c), k = x̂ x t̂, c = x̂ . t̂; t̂ bisects x̂ and the
    line, so c >= 0). None where the line or t vanishes (numpy's fallbacks then)."""
    (s00, s01, s02), (s10, s11, s12), (s20, s21, s22) = rows
    sqrt = math.sqrt
    n = sqrt((s00 * s00 + s10 * s10) + s20 * s20)
    l0, l1, l2 = hip_l[0] - hip_r[0], hip_l[1] - hip_r[1], hip_l[2] - hip_r[2]
    m = sqrt((l0 * l0 + l1 * l1) + l2 * l2)
    if m <= EPS or n <= EPS:
        return None
    x0, x1, x2 = s00 / n, s10 / n, s20 / n
    t0, t1, t2 = x0 + l0 / m, x1 + l1 / m, x2 + l2 / m
    m = sqrt((t0 * t0 + t1 * t1) + t2 * t2)
    if m <= EPS:
        return None
    t0, t1, t2 = t0 / m, t1 / m, t2 / m
    k0, k1, k2 = x1 * t2 - x2 * t1, x2 * t0 - x0 * t2, x0 * t1 - x1 * t0
    c = (x0 * t0 + x1 * t1) + x2 * t2
    e = 1.0 / (1.0 + c)
    r00, r01, r02 = c + k0 * k0 * e, k0 * k1 * e - k2, k0 * k2 * e + k1
    r10, r11, r12 = k1 * k0 * e + k2, c + k1 * k1 * e, k1 * k2 * e - k0
    r20, r21, r22 = k2 * k0 * e - k1, k2 * k1 * e + k0, c + k2 * k2 * e
    return [[r00 * s00 + r01 * s10 + r02 * s20, r00 * s01 + r01 * s11 + r02 * s21, r00 * s02 + r01 * s12 + r02 * s22],
            [r10 * s00 + r11 * s10 + r12 * s20, r10 * s01 + r11 * s11 + r12 * s21, r10 * s02 + r11 * s12 + r12 * s22],
            [r20 * s00 + r21 * s10 + r22 * s20, r20 * s01 + r21 * s11 + r22 * s21, r20 * s02 + r21 * s12 + r22 * s22]]


def _shoulder_toward(mid: np.ndarray, sh: np.ndarray, wr: np.ndarray, reach) -> np.ndarray:
    """(F, 3) the shoulders `sh` turned about `mid` in the plane of `mid`, `sh` and the wrists
    `wr` as far as brings them `reach` (a float or (F,)) from the wrists (the law of cosines):
    toward wrists further, away from nearer ones, at most `SHOULDER_REACH`."""
    a, b = sh - mid, wr - mid
    na, nb = np.linalg.norm(a, axis=1), np.linalg.norm(b, axis=1)
    ua = a / np.maximum(na, 1e-9)[:, None]
    cos_ab = np.clip(np.einsum("fi,fi->f", ua, b) / np.maximum(nb, 1e-9), -1.0, 1.0)
    kappa = np.clip((na * na + nb * nb - reach * reach) / np.maximum(2.0 * na * nb, 1e-12), -1.0, 1.0)
    e = b / np.maximum(nb, 1e-9)[:, None] - cos_ab[:, None] * ua  # toward the wrist, square to the shoulder
    ne = np.linalg.norm(e, axis=1)
    e = e / np.maximum(ne, 1e-9)[:, None]
    cap = np.where(ne > 1e-9, SHOULDER_REACH, 0.0)
    theta = np.clip(np.arccos(cos_ab) - np.arccos(kappa), -cap, cap)
    return mid + na[:, None] * (np.cos(theta)[:, None] * ua + np.sin(theta)[:, None] * e)


def estimated_elbow_right(shoulder, wrist, left, side_sign, neck, pelvis, hand_right):
    """(F, 3) the hinge's right for an elbow no tracker carries (`_two_bone_mid`'s `right`): the
    elbow's swivel from the hand's place relative to its shoulder (Parger 2018's elbow heuristics),
    not from the controller's roll, which a real elbow does not follow (pronation turns the forearm).
    In the shoulders' frame (`left` the shoulders' line toward the left, `side_sign` +1 left
    arm, -1 right; up from the pelvis to the neck; each vector (out, up, forward)): with the hand
    along ELBOW_HAND_REST the elbow points along ELBOW_POLE; elsewhere that pole swung by the
    shortest turn from ELBOW_HAND_REST to the shoulder-wrist axis, so the swivel is smooth
    everywhere but straight behind the shoulder (ELBOW_UNDEFINED, where no hand goes) (a fixed pole seen square to
    the axis flips where the axis passes it, or its opposite: a hand raised forward). Plus
    ELBOW_HAND_ROLL of the swivel the hand device's `hand_right` gives. Of the current frame
    only: a live frame and a bake agree."""
    axis = normalize(wrist - shoulder)
    left = normalize(left)
    up = neck - pelvis
    up = normalize(up - np.einsum("fi,fi->f", up, left)[:, None] * left)
    forward = cross(left, up)
    rest, pole = (_in_shoulders(v, side_sign, left, up, forward) for v in _ELBOW_FRAME)
    anchor, anchor_pole, middle = (_in_shoulders(v, side_sign, left, up, forward) for v in _ELBOW_MOVED)
    swivel = _swung(pole, rest, axis)
    # near the undefined direction the pole swung from the anchor, turned back toward `swivel` by
    # the share `w` of the shorter angle between them (about the axis both are square to)
    moved = _swung(anchor_pole, anchor, axis)
    apart = np.arccos(np.clip(np.einsum("fi,fi->f", axis, middle), -1.0, 1.0))
    w = np.clip((apart - ELBOW_BLEND[0]) / (ELBOW_BLEND[1] - ELBOW_BLEND[0]), 0.0, 1.0)
    turn = (w * w * (3.0 - 2.0 * w)) * np.arctan2(np.einsum("fi,fi->f", axis, cross(moved, swivel)),
                                                  np.einsum("fi,fi->f", moved, swivel))
    swivel = moved * np.cos(turn)[:, None] + cross(axis, moved) * np.sin(turn)[:, None]
    if ELBOW_HAND_ROLL:
        hand = cross(axis, hand_right)  # the swivel the hand's right gives (`_two_bone_mid`)
        swivel = normalize(swivel) + ELBOW_HAND_ROLL * normalize(
            hand - np.einsum("fi,fi->f", hand, axis)[:, None] * axis)
    return cross(swivel, axis)


def _in_shoulders(v, side_sign, left, up, forward):
    return (side_sign * v[0]) * left + v[1] * up + v[2] * forward


def _two_bone_mid(root, eff, rest_pos, a, m, e, s, right):
    """The intermediate joint from the user's two bone lengths, bent about the hinge axis `right`
    the effector's device carries (six devices: no tracker on the limb)."""
    l1 = np.linalg.norm(rest_pos[f"{m}_{s}"] - rest_pos[f"{a}_{s}"])
    l2 = np.linalg.norm(rest_pos[f"{e}_{s}"] - rest_pos[f"{m}_{s}"])
    # A positive turn about the hinge's +X flexes the distal bone toward +Z = X x Y, so the joint
    # itself lies on the other side of the root-effector line: along (effector - root) x right.
    return two_bone_mid(root, eff, l1, l2, cross(eff - root, right))


def finger_constants(which: list[tuple[str, str]], rest_pos: dict, model_bones: dict) -> tuple:
    """What `pose_user_fingers` reads of the model for the fingers `which`, computed once: their
    joints' names, their phalanges' canonical bones, the phalanx lengths (K, 3), the fingertip
    radii (K,) (the LED's offset from the tip joint), and a dict that keeps the fingers'
    `fingers.FingerSet` per frame count."""
    names = [[f"{j}_{f}_{s}" for j in sk.FINGER_JOINTS] for s, f in which]
    bones = [[BI[f"{f}_{i}_{s}"] for i in (1, 2, 3)] for s, f in which]
    lens = np.array([[np.linalg.norm(rest_pos[n[i + 1]] - rest_pos[n[i]]) for i in range(3)] for n in names])
    radius = []
    for s, f in which:
        info = model_bones.get(f"{f}_3_{s}")
        radius.append(info.radius_tail if info is not None and info.radius_tail else 0.0)
    return names, bones, lens, radius, {}


def pose_user_fingers(P: _Joints, Fr: np.ndarray, which: list[tuple[str, str]], tips: np.ndarray, rest_pos: dict,
                      model_bones: dict, constants: tuple | None = None, joints: bool = True) -> None:
    """Finger joints and phalanx frames from fingertip markers (appendix D, eq. 3-4 and the yaw/pitch
    realignment, `fingers.pose_finger`), every finger of `which` [(side, finger)] at once: `tips`
    (K, F, 3) their markers; P (the block's joints) and Fr hold the fingers rigid on the hand (their
    MCPs and rest phalanx frames) and are updated. `constants`: `finger_constants(which, ...)`, when the caller
    keeps them. `joints` False: the phalanx frames only (the joints after the MCP left as they were)."""
    K, F = tips.shape[:2]
    names, bones, lens, radius, sets = constants or finger_constants(which, rest_pos, model_bones)
    if F not in sets:
        sets[F] = finger_set(np.repeat(lens, F, axis=0).T, np.repeat([f == "thumb" for _, f in which], F))
        sets[F, "radius"] = np.repeat(radius, F)[:, None]
    phalanges = sets.get("phalanges")
    if phalanges is None:  # (K, 3) the fingers' phalanges; their joints, (K,) the MCP, (K, 3) the rest
        phalanges = sets["phalanges"] = np.array(bones, int).reshape(K, -1)
        sets["joints"] = np.array([[JI[j] for j in n] for n in names], int)
    rows = sets["joints"]
    mcp = P.pos.take(rows[:, 0], axis=1).swapaxes(0, 1).reshape(-1, 3)  # (K F, 3)
    ref = Fr.take(phalanges[:, 0], axis=1).swapaxes(0, 1).reshape(-1, 3, 3)  # (K F, 3, 3) the first phalanges
    # The fingertip LED sits on the nail, one finger radius off the tip joint on the back of the
    # distal phalanx (-Z of its frame): once its orientation is known, aim at the joint instead
    # (of the first pose only that +Z is read).
    aim = tips.reshape(-1, 3)
    if F == 1:  # one frame (a live solve's): both passes item by item in Python floats
        points, rotations = sets[F].pose_floats(mcp, ref, aim, joints, sets[F, "radius"] if any(radius) else None)
    else:
        if any(radius):
            aim = aim + sets[F, "radius"] * sets[F].distal_z(mcp, ref, aim)
        fp = sets[F].pose(mcp, ref, aim, joints=joints)
        points, rotations = fp.joints, fp.rotations
    # every finger's joints after the MCP and its phalanges, one assignment each
    if joints:
        P.pos[:, rows[:, 1:]] = points.reshape(K, F, 4, 3)[:, :, 1:].swapaxes(0, 1)
    Fr[:, phalanges] = rotations.reshape(K, F, 3, 3, 3).swapaxes(0, 1)


def finger_set(lens, thumb) -> fingers.FingerSet:
    """`pose_finger_chain`'s constants (`fingers.FingerSet`) for phalanx lengths `lens` (3, n) and
    `thumb` (n,) bool, for a caller that poses the same fingers again."""
    thumb = np.asarray(thumb, bool)
    return fingers.FingerSet(lens[0], lens[1], lens[2], thumb=thumb, roll=0.0 if thumb.ndim or thumb else None)


def pose_finger_chain(mcp, tip, lens, rest_frames, thumb: bool = False, finger_set: fingers.FingerSet | None = None,
                      joints: bool = True):
    """`fingers.pose_finger` with the first phalanx's rest frame (moved with the hand) as the
    reference: a finger at rest has zero yaw and pitch, so the anatomical limits bound the motion
    away from the calibrated pose. The thumb's own frame already carries its roll (roll 0).
    `finger_set`: `finger_set(lens, thumb)` kept by the caller (then `lens` and `thumb` are not read).
    Returns (points (F, 4, 3), [3 frames (F, 3, 3)]); `joints` False with a `finger_set`: (None,
    the frames), a caller reading the frames only (the avatar's finger IK) skips the points."""
    if finger_set is None:
        thumb = np.asarray(thumb, bool)
        fp = fingers.pose_finger(mcp, rest_frames[0], lens[0], lens[1], lens[2], tip, thumb=thumb,
                                 roll=0.0 if thumb.ndim or thumb else None)
    else:
        fp = finger_set.pose(mcp, rest_frames[0], tip, joints=joints)
    return fp.joints, [fp.rotations[:, i] for i in range(3)]


def axis_angle_matrix(axis, angle):
    """(..., 3, 3) rotation matrices of `angle` (rad) about `axis` (normalised here)."""
    axis = normalize(axis)
    x, y, z = np.moveaxis(axis, -1, 0)
    c, s_ = np.cos(angle), np.sin(angle)
    C = 1 - c
    return np.stack([
        np.stack([c + x * x * C, x * y * C - z * s_, x * z * C + y * s_], -1),
        np.stack([y * x * C + z * s_, c + y * y * C, y * z * C - x * s_], -1),
        np.stack([z * x * C - y * s_, z * y * C + x * s_, c + z * z * C], -1),
    ], -2)
