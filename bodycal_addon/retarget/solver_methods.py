"""The retargeting methods of the prepared solver (solver.py; DESIGN.md §1 steps 3-4 and
"Prepared solver"), one class each with the same stages: what a method computes once for a
(performer, avatar) pair (`__init__`, on the solver's shared state) and per block of frames
(`chunk`: the avatar pose and the targets it aimed at).

- `Egocentric` (Delahaye 2023, the default): the targets (wrists, ankles, elbows, knees,
  fingertips, skull base) mapped through the two posed surfaces (`egocentric.retarget_points`),
  then avatar IK: spine aimed at the skull base, two-bone limbs with the swivel blend, fingers.
- `ExactOffsets` (AvatarGo): exact tracker-to-joint offsets for root, feet, hands and head, spine
  bent by the root-to-head angle, limbs by IK, fingers closed on the controller (`offsets.py`).
- `RotationCopy`: step 2 only, the baseline; the legs reach their planted feet.

Also the surface helpers they share with the solver and the metrics: the models' surfaces
re-expressed in the engine's canonical bone frames.
"""

from __future__ import annotations

import copy
import dataclasses

import numpy as np

from ..body import skeleton as sk
from ..body.bodymodel import BodyModel
from ..body.skeleton import BONE_INDEX as BI
from ..body.skeleton import BONES, SPINE_BONES
from ..body.skeleton import JOINT_INDEX as JI
from ..body.surface_layout import bone_frame
from ..core import one_frame
from ..core.errors import BodyCalError
from ..core.transforms import normalize, quat_to_matrix, stack_apply, stack_mul
from . import egocentric as ego
from . import offsets as ofs
from .egocentric.one_frame import OneFrameMapping
from .methods import methods_for
from .trackers import read_trackers
from .user_animation import sacrum_toward_hip_line

TARGETS = tuple(
    [f"{j}_{s}" for j in ("wrist", "elbow", "ankle", "knee") for s in sk.SIDES]
    + [f"tip_{f}_{s}" for s in sk.SIDES for f in sk.FINGERS] + ["skull_base"])
ARM_PASSES = 2  # arm mappings per chunk (the second sees the arms where the first put them)
# Decision: the mapping (step 3) runs in single precision, about twice as fast; its targets agree
# with double precision to micrometres, and the IK and the rig stay in double precision.
MAPPING_DTYPE = np.float32
# Decision (DESIGN.md §5 "The hand's point"): a hand is mapped through its palm's centre where the palm
# is within PALM_NEAR of the body it maps onto, through its wrist beyond PALM_FAR, and between
# them through a point between the two (a C1 ramp of that distance): a free hand's turn about its
# wrist does not move the avatar's wrist, a touching palm still lands on the avatar's body.
PALM_NEAR = 0.05  # m
PALM_FAR = 0.15  # m


def surface_correction(model: BodyModel, frames0: np.ndarray, pos: dict) -> np.ndarray:
    """(B, 3, 3) C0^-1 C_model0: the model's surface points are local to `bone_frame` with the
    model's own `right`; the engine's frames fix the right by one rule. Posing with C(t) corr
    places them as the model defined them."""
    out = np.broadcast_to(np.eye(3), (len(BONES), 3, 3)).copy()
    # Decision (speed): every bone's frame in one pass (element-wise, the same values as bone by
    # bone); the loop of numpy calls over 72 bones was ~3x an egocentric bake's set-up calls' cost.
    rows = [i for i, b in enumerate(BONES) if (info := model.bones.get(b.name)) is not None and info.right is not None]
    if not rows:
        return out
    chosen = [BONES[i] for i in rows]
    cm = bone_frame(np.array([pos[b.head] for b in chosen], float), np.array([pos[b.tail] for b in chosen], float),
                    np.array([model.bones[b.name].right for b in chosen], float))
    ok = np.isfinite(cm).all(axis=(1, 2))
    ok[ok] = abs(np.linalg.det(cm[ok]) - 1) < 1e-3
    keep = np.array(rows)[ok]
    out[keep] = frames0[keep].transpose(0, 2, 1) @ cm[ok]
    return out



_UNBUILT = object()  # a lazily made attribute not made yet (None is a made "no")


# --- the methods: one class each, the same stages -------------------------------------------------

class Method:
    """A retargeting method: what it computes once (`__init__`, on the run's shared state) and per
    chunk of frames (`chunk`: the avatar pose and the targets it aimed at). `fk_basis` and
    `realised` say how the run's rotation copy (step 2) is solved for it (`uses_fk` False: not
    at all); `ankle_places` gives the ankles the feet plan holds (None: the user's, scaled about
    the root)."""

    name = ""
    fk_basis = False
    realised: bool | list[int] = False
    uses_fk = True  # reads the rotation copy's pose (`chunk`'s fk; None when not)
    user_fingers = True  # reads the user's fingers (False: the pose source may leave them unposed)
    user_trunk = True  # reads the user's pelvis, sacrum, vertebrae or clavicles (False: likewise)
    trunk_copied = True  # reads step 2's copy of the trunk, head and feet (`avatar_pose.DELTA_COPY`; False: not made)
    user_finger_joints = True  # reads the joints of the user's fingers (False: likewise; their frames posed)

    def __init__(self, run, avatar_pos: dict):
        self.run = run

    def ankle_places(self, trackers) -> dict | None:
        return None

    def chunk(self, up, fk, pelvis, user_frames, start: int, stop: int):
        raise NotImplementedError


class RotationCopy(Method):
    """Step 2 only, the baseline every other tool does; the legs reach their planted feet."""

    name = "rotations"
    fk_basis = True
    user_finger_joints = False  # the fingers' frames are copied; their joints are the avatar's FK

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

    def __init__(self, run, avatar_pos: dict):
        super().__init__(run, avatar_pos)
        # Both surfaces re-expressed in the engine's canonical bone frames: the mapping's surface
        # coordinates (capsule angles, sphere directions) must mean the same side of the body
        # on the user and on the avatar, whatever `right` each model's producer chose.
        self.user_s = canonical_surface(surface_bones(run.user), run.user_frames0, run.user_pos)
        self.avatar_s = canonical_surface(surface_bones(run.avatar), run.rig.frames0, avatar_pos)
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
        self.bone_heads = np.array([JI[sk.BONE_BY_NAME[b].head] for b in self.graph_bones], int)
        self.bone_tails = np.array([JI[sk.BONE_BY_NAME[b].tail] for b in self.graph_bones], int)
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
        self.lower = [n for n in self.targets if n.startswith(("skull_base", "ankle_", "knee_"))]
        self.upper = [n for n in self.targets if n not in self.lower]
        # Both stages' targets are prepared on the user's side at once (the trunk's first), the
        # trunk's not mapped on the arms' elements.
        self.mapped = (self.lower if self.trunk_ids else []) + self.upper
        self.mapped_joints = np.array([JI[n] for n in self.mapped], int)
        arms = frozenset(self.ids) - frozenset(self.trunk_ids)
        self.trunk_exclude = tuple(arms if n in self.lower else frozenset() for n in self.mapped)
        self.wrist_rows = {s: self.mapped.index(f"wrist_{s}") for s in self.palm_local}
        self._own_hands = {}  # element ids -> (sides, elements) mask of each hand's own chain (palm_weights)
        # Both bodies' surfaces posed by prepared posers (all elements; and the avatar's trunk
        # alone, which a bake's trunk stage maps on: a few frames map from every element at once).
        self.posers = {who: ego.SurfacePoser(model, self.ids) for who, model in (("user", self.user_s),
                                                                                 ("avatar", self.avatar_s))}
        if self.trunk_ids:
            self.posers["avatar_trunk"] = ego.SurfacePoser(self.avatar_s, self.trunk_ids)
        self._one_frame = _UNBUILT  # `one_frame`, made on the first one-frame solve
        # the rows of `mapped` of each stage's targets: {False: the arms', True: the trunk's}
        self.rows = {stage: np.array([self.mapped.index(n) for n in names if n in self.mapped], int)
                     for stage, names in ((True, self.lower), (False, self.upper))}

    @property
    def one_frame(self) -> OneFrameMapping | None:
        """One frame (a live frame, a preview's) maps its targets over flat arrays of the pairs
        that carry weight (egocentric/one_frame.py), to float32's rounding of these kernels' values
        where one frame may (core/one_frame.ENABLED); None: this layout takes these kernels.
        Decision (speed): made on the first one-frame solve, not in `__init__`: a bake never
        solves one frame, and building it was about 17 M instructions of every bake's set-up; a
        live stream's first frame waits for it instead (about 20 ms)."""
        if self._one_frame is _UNBUILT:
            self._one_frame = OneFrameMapping.build(self.mapped, self.posers["user"], self.posers["avatar"],
                                                    self.trunk_exclude, tuple(self.palm_local),
                                                    len(self.lower) if self.trunk_ids else 0)
        return self._one_frame

    def chunk(self, up, fk, pelvis, user_frames, start, stop):
        """Steps 3-4 in two stages (Decision): the trunk and legs first, mapped against the body
        without the arms and solved; then the arms and fingers, mapped against the body with the
        trunk and legs already where the IK put them. Targets are mapped relative to the posed
        avatar, so a hand resting on a thigh must be mapped against the thigh where it ends up,
        not where the rotation copy had put it; and arm elements, which the IK moves last, must not
        pull the head or the feet."""
        run, posers = self.run, self.posers
        heads = np.take(up.joints, self.bone_heads, axis=1)
        tails = np.take(up.joints, self.bone_tails, axis=1)
        # A user's bones keep their calibrated lengths (tracked joints wobble); a character's are
        # taken as posed, like the avatar's own (a vertebra spanning two spine bones stretches).
        ub = tails - heads if run.character else normalize(tails - heads) * self.user_lengths[:, None]  # (F, NB, 3)
        lower, upper = self.lower, self.upper
        # one frame over the pairs' flat arrays (OneFrameMapping), or these kernels over frames
        one = self.one_frame if one_frame.ENABLED and len(up.joints) == 1 else None
        us = one.user_surface(up.joints[0], user_frames[0]) if one else posers["user"].pose(up.joints, user_frames)
        pts = np.take(up.joints, self.mapped_joints, axis=1)
        # Decision: the hand is mapped through the centre of its palm, the part that touches, and
        # the wrist target is that point minus the avatar's own palm offset (the hand's orientation
        # is copied): wrist and palm are a hand's size apart, and hands differ. Away from the body
        # it is mapped through the wrist (`palm_weights`): there the two palm offsets, turned
        # with the hand, moved the avatar's wrist by their difference whenever the hand turned.
        levers = {s: stack_apply(user_frames[:, BI[f"hand_{s}"]], u_loc) for s, (u_loc, _) in self.palm_local.items()}
        # The user's side of every target, once: the same for the trunk's map and the arms' passes
        # (one frame: the palms' nearest in the same pass as the targets, OneFrameMapping.prepare).
        if one:
            user_side, w = one.prepare(us, pts[0], ub[0], np.array([lv[0] for lv in levers.values()]).reshape(-1, 3),
                                       palm_ramp)
            palm = w[None]

            def mapped(pose, names, poser="avatar"):  # (1, len(names), 3): this stage's targets mapped, taken
                return one.map(user_side, pose.joints[0], pose.frames[0], int(names is not lower)).take(
                    self.rows[names is lower], axis=0)[None]
        else:
            palm = self.palm_weights(us, pts, levers)
            for i, s in enumerate(levers):
                pts[:, self.wrist_rows[s]] += palm[:, i, None] * levers[s]
            user_side = ego.prepare_targets(pts, self.mapped, us, user_bones=ub, dtype=MAPPING_DTYPE,
                                            exclude=self.trunk_exclude)

            def mapped(pose, names, poser="avatar"):
                return user_side.map(posers[poser].pose(pose.joints, pose.frames, normals=False), targets=names)
        targets = {}
        if self.trunk_ids:
            tg = mapped(fk, lower, "avatar" if one or user_side.whole is not None else "avatar_trunk")
            targets.update({n: tg[:, i] for i, n in enumerate(lower)})
        ankles = {f"ankle_{s}": fk.joints[:, JI[f"ankle_{s}"]] for s in sk.SIDES}
        targets, pelvis, _ = run.plant(targets, up.frames, pelvis, start, stop, ankles)
        frames = run.solve_ik(up, fk, pelvis, targets)
        mid = run.rig.solve(frames, pelvis, basis=False, realised=self.realised)
        wrists = [i for i, n in enumerate(upper) if n.startswith("wrist_")]
        tips = [i for i, n in enumerate(upper) if n.startswith("tip_")]
        pose, tg = mid, None
        arms_user = {}  # what the arms' IK reads of the user, the same every pass
        # each wrist target's pull back to the wrist: w times the avatar's palm offset turned with
        # the hand as `mid` poses it, the same every pass
        palm_back = {s: palm[:, i, None] * stack_apply(mid.frames[:, BI[f"hand_{s}"]], a_loc)
                     for i, (s, (_, a_loc)) in enumerate(self.palm_local.items())}
        for k in range(ARM_PASSES):
            ta = mapped(pose, upper)
            if tg is None:
                tg = ta
            else:
                tg[:, wrists] = 0.5 * (tg[:, wrists] + ta[:, wrists])
                tg[:, tips] = ta[:, tips]
            arm_targets = {n: tg[:, i] for i, n in enumerate(upper)}
            for s, back in palm_back.items():
                arm_targets[f"wrist_{s}"] = arm_targets[f"wrist_{s}"] - back
            arm_frames = run.solve_ik(up, fk, pelvis, arm_targets, frames=frames.copy(), trunk=mid,
                                      user_side=arms_user)
            if k + 1 < ARM_PASSES:
                pose = run.rig.solve(arm_frames, pelvis, basis=False, realised=self.realised)
        frames = arm_frames
        targets.update(arm_targets)
        return run.rig.solve(frames, pelvis, realised=False), targets

    def palm_weights(self, us, pts, levers: dict) -> np.ndarray:
        """(F, hands) how much each hand is mapped through its palm's centre rather than its wrist:
        1 where the user's palm (`pts`' wrist rows plus `levers`, {side: (F, 3)}) is within
        PALM_NEAR of the surface `us` it maps onto (not its own arm and hand), 0 beyond PALM_FAR."""
        if not levers:
            return np.ones((len(pts), 0))
        palms = np.stack([pts[:, self.wrist_rows[s]] + lever for s, lever in levers.items()], axis=1)
        ids = tuple(us.element_ids)
        if ids not in self._own_hands:
            self._own_hands[ids] = np.array([[eid in ego.own_chain_elements(f"wrist_{s}") for eid in ids]
                                             for s in levers])
        return palm_ramp(np.where(self._own_hands[ids], np.inf, ego.distances(palms, us)).min(axis=-1))


def palm_ramp(near: np.ndarray) -> np.ndarray:
    """A hand's palm weight from its palm centre's nearest distance to the body it maps onto: 1
    within PALM_NEAR, 0 beyond PALM_FAR, a C1 ramp between (Egocentric.palm_weights)."""
    if near.ndim == 1 and near.size <= 2:
        # one frame's hands (OneFrameMapping.prepare): Python floats, the same double operations
        # in the same order (np.clip's min and max), without six numpy calls on two values
        ramp = []
        for d in near.tolist():
            t = min(max((d - PALM_NEAR) / (PALM_FAR - PALM_NEAR), 0.0), 1.0)
            ramp.append(1.0 - t * t * (3.0 - 2.0 * t))
        return np.array(ramp)
    t = np.clip((near - PALM_NEAR) / (PALM_FAR - PALM_NEAR), 0.0, 1.0)
    return 1.0 - t * t * (3.0 - 2.0 * t)


class ExactOffsets(Method):
    """AvatarGo: exact tracker-to-joint offsets from the T-pose, the spine bent by the root-to-head
    vector, limbs by IK, fingers closed on the controller (offsets.py)."""

    name = "offsets"
    uses_fk = False  # the limbs hang from the offsets' own trunk, and there is no skull-base IK
    # Decision (speed, the same values): the offsets set the pelvis, the sacrum, every vertebra and
    # the clavicles from the trackers themselves (eq. 2-4) and the limbs read the user's limb
    # joints and hinges only, so the user's trunk pass (the spine IK: a sixth of a one-frame solve,
    # measured, DESIGN.md "Prepared solver") is not run.
    user_trunk = False
    # Decision (speed, the same values): the offsets set every bone step 2's copy turns by the
    # rest frames (`avatar_pose.DELTA_COPY`: the sacrum, vertebrae, clavicles, head and feet), so
    # the copy is not made (93,000 instructions of a one-frame solve, measured).
    trunk_copied = False

    def __init__(self, run, avatar_pos: dict):
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
        # the clavicles turn with the vertebra they hang from: its frame times these (once)
        v5 = sk.CLAVICLE_VERTEBRA - 1
        self.clavicles = [(BI[f"clavicle_{s}"], self.ofs.spine0[v5].T @ self.ofs.ref_frames[BI[f"clavicle_{s}"]])
                          for s in sk.SIDES]
        self.grip = {s: ofs.grip_fingers(run.rig, s) for s in sk.SIDES if run.has_fingers[s]}
        # Decision (speed, the same values): the grip sets every finger bone of a hand it closes,
        # so where it closes each hand that has any finger bone, nothing reads the user's fingers
        # and the pose source leaves them unposed (their tip markers' pose was a fifth of a
        # one-frame solve, measured: DESIGN.md "Prepared solver").
        self.user_fingers = any(run.finger_bones[s] and s not in self.grip for s in sk.SIDES)

    def ankle_places(self, trackers) -> dict:
        return self._effector_targets(trackers)[0]

    def _effector_targets(self, trackers) -> tuple[dict, dict]:
        """`offsets.effector_targets` of these trackers, kept for the last trackers read: the chunk
        and its feet plan (a live stream's frame: the same read) ask for the same frames in turn."""
        if getattr(self, "_last_effectors", (None,))[0] is not trackers:
            self._last_effectors = (trackers, ofs.effector_targets(self.ofs, trackers))
        return self._last_effectors[1]

    def chunk(self, up, fk, pelvis, user_frames, start, stop):
        run = self.run
        st = self.ofs
        tr = run.src.trackers(start, stop)
        p, r = self._effector_targets(tr)
        frames = up.frames.copy()
        for bone, fr in r.items():
            frames[:, BI[bone]] = fr
        sf = ofs.spine_frames(st, tr.pos, r["sacrum"])
        frames[:, _SPINE_ROWS] = sf
        for c, fixed in self.clavicles:
            frames[:, c] = stack_mul(sf[:, sk.CLAVICLE_VERTEBRA - 1], fixed)
        targets = {f"{j}_{s}": p[f"{j}_{s}"] for j in ("wrist", "ankle") for s in sk.SIDES}
        # AvatarGo stands its avatar on the floor: planted feet on it, the pelvis lowered to reach.
        targets, pelvis, _ = run.plant(targets, frames, p["pelvis"], start, stop)
        up2 = type(up)(up.time, up.joints, frames, up.valid, up.notes)
        frames = run.solve_ik(up2, fk, pelvis, targets, hands=self.grip)
        targets["skull_base"] = p["skull_base"]
        return run.rig.solve(frames, pelvis, realised=False), targets


_SPINE_ROWS = np.array([BI[b] for b in SPINE_BONES], int)
METHOD_CLASSES: dict[str, type[Method]] = {m.name: m for m in (Egocentric, ExactOffsets, RotationCopy)}
METHODS = methods_for("recording")  # every method (a recording takes them all), the default first


def surface_bones(model: BodyModel) -> BodyModel:
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
        # Decision (speed): a copy of what this rewrites (the centre, the axis offsets in `extra`,
        # each point), not copy.deepcopy of the element: the deep copies were about 35 M
        # instructions of every egocentric solver's set-up (a bake's 1.2 %).
        e = dataclasses.replace(e, points={k: dataclasses.replace(p) for k, p in e.points.items()},
                                triangles=list(e.triangles), extra=copy.deepcopy(e.extra) if e.extra else {})
        if e.center is not None:
            e.center = corr[BI[e.bone]] @ e.center if e.bone in BI else e.center.copy()
        if e.type == "capsule" and e.bone in BI and ("axis_head" in e.extra or "axis_tail" in e.extra):
            e.set_axis_offsets(*(corr[BI[e.bone]] @ e.axis_offsets().T).T)
        for p in e.points.values():
            p.local = corr[BI[p.bone]] @ p.local if p.bone in BI else p.local.copy()
        out.surface.append(e)
    return out


def surface_bone_indices(*models: BodyModel) -> list[int]:
    names = set()
    for m in models:
        for e in m.surface:
            names.add(e.bone)
            names |= {p.bone for p in e.points.values()}
    return sorted(BI[n] for n in names if n in BI)
