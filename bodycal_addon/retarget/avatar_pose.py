"""Step 2 of the pipeline (DESIGN.md §1) and the conversion every method ends with: canonical bone
frames in the world -> the avatar's pose-bone rotations (Blender's `matrix_basis`) and back.

Canonical bone frames follow `surface_layout.bone_frame`: origin at the head joint, +Y along the
bone, +X the bone's right (`canonical_rest_frames` fixes the right of every bone with ONE rule used
for the user at the reference time and for the avatar at rest, so copying a frame copies the pose).

`AvatarRig` holds the avatar's armature (`BodyModel.extra["rig"]`, written by the avatar
calibration): bones in armature space (`head`, `tail`, `matrix` = `bone.matrix_local` 3x3), the
armature's `matrix_world` and the bone map. Each avatar bone is either
- driven by one canonical bone c: it moves rigidly with it, P_A(t) = W^-1 C_c(t) C_c0^-1 W M_A;
- a spine/neck chain bone: twisted like the canonical vertebra at its middle and aimed at the
  canonical spine curve resampled at its tail's arc position (the avatar has fewer vertebrae);
- undriven (root, toes, breasts, ...): it follows its parent (identity basis).
Blender's pose rule (rotation part, armature space): P_child = P_parent M_parent^-1 M_child basis,
so basis = M_child^-1 M_parent P_parent^-1 P_child; the root bone's `location` is in its rest frame.
Canonical joints ride on avatar bones (`joints[j].frame` + local computed from the rest positions),
so the joints returned here are exactly what Blender's FK gives for the returned rotations.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..body import naming
from ..body import skeleton as sk
from ..body.bodymodel import BodyModel
from ..body.rest_frames import complete_joints, model_rest_frames
from ..body.skeleton import BONE_INDEX as BI
from ..body.skeleton import BONES, JOINTS, SPINE_BONES, SPINE_JOINTS
from ..body.skeleton import JOINT_INDEX as JI
from ..core import one_frame
from ..core.errors import BodyCalError
from ..core.transforms import (
    EPS,
    MANY_PRODUCTS,
    STACKED_FRAMES,
    matmul_stack,
    mul_stack,
    quat_between,
    quat_to_matrix,
    stack_apply,
    stack_mul,
    stacks_apply,
    stacks_mul,
    transposed,
)
from . import pose_kernels
from .rig_one_frame import ChainOneFrame


def _driver_of_segment(seg: str) -> str | None:
    """Canonical bone that drives an avatar bone mapped to `seg` (None: follows its parent)."""
    if seg == "pelvis":
        return "sacrum"
    if seg in sk.BONE_BY_NAME and not sk.BONE_BY_NAME[seg].shortcut:
        return seg
    return None


def _rig_bones(bones: dict, src: str) -> tuple[list[str], np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The rig's bones parents first (by depth, then in the rig's order): (names, parent index or
    -1, rest heads, rest tails, rest matrices), armature space. Refuses a parent outside the rig,
    a bone that is its own ancestor, and a bone without head, tail or 3x3 matrix."""
    depth = {}

    def d(n, seen=()):
        if n in depth:
            return depth[n]
        p = bones[n].get("parent") or None
        if p is not None and p not in bones:
            raise BodyCalError(f"bone '{n}' has parent '{p}' that is not in the rig", source=src, field="rig.bones")
        if n in seen:
            raise BodyCalError(f"bone '{n}' is its own ancestor", source=src, field="rig.bones")
        depth[n] = 0 if p is None else d(p, seen + (n,)) + 1
        return depth[n]

    names = sorted(bones, key=lambda n: (d(n), list(bones).index(n)))
    idx = {n: i for i, n in enumerate(names)}
    parent = np.array([idx[bones[n]["parent"]] if bones[n].get("parent") else -1 for n in names])
    try:
        head = np.array([bones[n]["head"] for n in names], float)
        tail = np.array([bones[n]["tail"] for n in names], float)
        rest = np.array([bones[n]["matrix"] for n in names], float).reshape(-1, 3, 3)
    except (KeyError, ValueError) as exc:
        raise BodyCalError(f"every rig bone needs head, tail and a 3x3 matrix ({exc})", source=src,
                           field="rig.bones") from None
    return names, parent, head, tail, rest


def _rig_world(rig: dict, src: str) -> tuple[np.ndarray, np.ndarray, float]:
    """(matrix_world (4, 4), its rotation, its mean scale); refuses a mirrored or flattened one."""
    world = np.asarray(rig.get("matrix_world", np.eye(4)), float).reshape(4, 4)
    lin = world[:3, :3]
    det = np.linalg.det(lin)
    if not det > 0:
        raise BodyCalError("the armature object is mirrored or flattened (its scale has a negative or zero "
                           "axis)", source=src, field="rig.matrix_world",
                           hint="apply the scale (Ctrl+A) and recalibrate")
    # Pose bones only rotate, so rotations go through the armature's transform as a rotation
    # and one scale: exact for a uniform scale; for a non-uniform one (the calibration warns)
    # the nearest rotation (polar decomposition) and the mean scale. Positions go through the
    # transform itself, so the joints stay what Blender's FK gives (the root lands where asked).
    u, _, vt = np.linalg.svd(lin)
    return world, u @ vt, float(np.cbrt(det))


def _drivers(bones: dict, names: list[str], idx: dict[str, int], bm: naming.BoneMap, src: str
             ) -> tuple[list, list[str]]:
    """(per bone: the canonical bone index driving it, "chain" or None; the spine and neck chain
    bones, lowest first). A bone's segment is the bone map's, else the rig's `segment` (not for
    chain segments). Refuses a rig without a pelvis, head or limb bone mapped."""
    seg_of = {}
    for seg, bn in bm.bones.items():
        seg_of.setdefault(bn, seg)
    chain = [b for c in ("spine", "neck") for b in bm.chains.get(c, []) if b in idx]
    for n in names:
        seg = bones[n].get("segment")
        if seg and n not in seg_of and seg not in sk.CHAIN_SEGMENTS:
            seg_of[n] = seg
    pelvis_bone = bm.bones.get("pelvis")
    if pelvis_bone not in idx:
        raise BodyCalError("no avatar bone is mapped to the pelvis", source=src, field="rig.bone_map",
                           hint="map the pelvis bone in the bone map panel")
    driver: list = []
    for n in names:
        if n in chain:
            driver.append("chain")
        else:
            c = _driver_of_segment(seg_of.get(n, ""))
            driver.append(BI[c] if c is not None else None)
    for seg in ("head", "upperarm_l", "upperarm_r", "forearm_l", "forearm_r", "thigh_l", "thigh_r",
                "shin_l", "shin_r"):
        if seg not in bm.bones or bm.bones[seg] not in idx:
            raise BodyCalError(f"no avatar bone is mapped to '{seg}'", source=src, field="rig.bone_map",
                               hint="map it in the bone map panel")
    return driver, chain


@dataclass
class _Level:
    """The bones of one depth of the rig's hierarchy, by how they are posed (AvatarRig._pose_plan)."""

    heads: np.ndarray  # bones whose head hangs from their parent: H_p + P_p offset
    head_par: np.ndarray
    head_off: np.ndarray  # (K, 3) the offsets in the parents' rest frames
    loose: np.ndarray  # parentless bones (not the root): at their rest head
    rest: np.ndarray  # parentless undriven bones: at rest
    follow: np.ndarray  # undriven bones with a parent: P_p M_p^-1 M_A
    follow_par: np.ndarray
    follow_fixed: np.ndarray  # (K, 3, 3)
    chain: list[int]  # spine chain bones, aimed one by one
    root: bool  # the root bone is at this depth (placed from the pelvis once posed)
    loose_at: np.ndarray | None = None  # (K, 1, 3) the loose bones' rest heads
    rest_at: np.ndarray | None = None  # (K, 1, 3, 3) the rest bones' rest matrices
    head_off4: np.ndarray | None = None  # (K, 1, 3, 1) head_off as a few frames' products take it
    follow_fixed4: np.ndarray | None = None  # (K, 1, 3, 3) follow_fixed as a few frames' products take it


@dataclass
class _PosePlan:
    driven: np.ndarray  # bones driven by a canonical bone
    canon: np.ndarray  # their canonical bones
    fixed: np.ndarray  # (K, 3, 3) C0^-1 W M_A
    levels: list[_Level]
    chained: bool  # the spine chain's bones are posed
    has_root: bool = False  # the root bone is posed
    # A few frames (fewer than FEW_FRAMES): `levels` placing only the heads the chain reads (`few`),
    # the others in one pass after it (`deferred`: rows, parents, offsets, the padded sum table).
    few: list[_Level] | None = None
    deferred: tuple | None = None
    # A few frames whose spine chain needs no aiming (its rotations held, or no chain): every
    # rotation first, then every head in one padded pass from the root and the parentless bones
    # (`_pose`); (rest bones, their matrices, loose bones, their heads, [(follow bones, parents,
    # fixed)] by depth, and the heads' rows, parents, offsets and padded sum table)
    flat: tuple | None = None


# Poses of fewer frames than this place the heads the spine chain does not read in one padded
# pass after the levels (_PosePlan.deferred: a few numpy calls instead of a few per level, where
# the per-call overhead is the cost); longer ones level by level. The same sums in the same order.
# Measured (bench_instructions' take, one-frame solves): these paths save 247,000 instructions of a
# rotations frame's 4.15 M and 995,000 of an egocentric one's 18.95 M.
FEW_FRAMES = 16


@dataclass
class _ChainPlan:
    """The spine chain's bones (AvatarRig._aim_chains), in order, with what aiming each one takes."""

    index: dict  # bone -> its row here
    vertebra: np.ndarray  # the canonical vertebra whose twist it takes
    fixed: np.ndarray  # (n, 3, 3) that vertebra's C0^-1 W
    rest: np.ndarray  # (n, 3, 3) the bone's M_A
    aim: np.ndarray  # (n, 3) its aim point in its rest frame
    off: np.ndarray  # (n, 3) the aim point's offset from the rest curve
    k: np.ndarray  # (n,) the curve segment of its arc position
    t: np.ndarray  # (n,) and the position along it
    inputs: np.ndarray  # every canonical bone whose frame the chain's rotations read (with the pelvis)
    order: np.ndarray | None = None  # the bones by their row here

    def __post_init__(self):
        self.w0 = (1 - self.t)[:, None, None]  # the target's weights on the curve points k, k + 1
        self.w1 = self.t[:, None, None]
        self.k1 = self.k + 1


@dataclass
class RigPose:
    basis: np.ndarray  # (F, N, 4) pose-bone rotation_quaternion (matrix_basis), w x y z
    rotations: np.ndarray  # (F, N, 3, 3) armature-space pose rotations P
    heads: np.ndarray  # (F, N, 3) armature-space pose heads
    root_location: np.ndarray  # (F, 3) pose-bone location of the root bone (its rest frame)
    joints: np.ndarray  # (F, J, 3) canonical joints, world
    frames: np.ndarray  # (F, B, 3, 3) canonical bone frames, world, as the rig realises them


@dataclass
class AvatarRig:
    model: BodyModel
    armature: str
    names: list[str]
    parent: np.ndarray  # (N,) int, -1 for none
    head: np.ndarray  # (N, 3) armature space, rest
    tail: np.ndarray
    rest: np.ndarray  # (N, 3, 3)
    world: np.ndarray  # (4, 4)
    w_rot: np.ndarray  # (3, 3) the armature's rotation (rotations map through it)
    w_scale: float  # its (mean) uniform scale
    w_inv: np.ndarray  # (3, 3) the exact inverse of its linear part (positions map through it)
    root: int
    driver: list  # per bone: canonical bone index, "chain" or None
    chain_s: np.ndarray  # (N,) arc position (0..12 vertebrae) of a chain bone's aim point
    chain_aim: np.ndarray  # (N, 3) a chain bone's aim point in its rest frame
    chain_off: np.ndarray  # (N, 3) the aim point's offset from the rest spine curve (armature)
    chain_vertebra: np.ndarray  # (N,) int vertebra (0-based) whose twist a chain bone takes
    joint_world: np.ndarray  # (J, 3) rest
    joint_bone: np.ndarray  # (J,) int
    joint_local: np.ndarray  # (J, 3) armature units, bone rest frame
    frames0: np.ndarray  # (B, 3, 3) canonical rest frames, world
    lengths: np.ndarray  # (B,) canonical bone lengths, world units
    carrier: np.ndarray  # (B,) avatar bone that carries each canonical bone's frame
    notes: list[str] = field(default_factory=list)

    # --- construction ------------------------------------------------------------------------

    @classmethod
    def from_model(cls, model: BodyModel) -> AvatarRig:
        """The solver for an avatar body model's rig (`extra["rig"]`, written by the avatar
        calibration). Raises BodyCalError naming the field when the rig cannot be posed: no bones,
        a broken hierarchy, a mirrored armature, the pelvis or a limb not mapped."""
        rig = model.extra.get("rig")
        src = model.name or "avatar"
        if not isinstance(rig, dict) or not isinstance(rig.get("bones"), dict) or not rig["bones"]:
            raise BodyCalError("the avatar body model has no rig (extra.rig.bones)", source=src, field="rig",
                               hint="calibrate the avatar again")
        names, parent, head, tail, rest = _rig_bones(rig["bones"], src)
        idx = {n: i for i, n in enumerate(names)}
        world, w_rot, w_scale = _rig_world(rig, src)
        bm = naming.BoneMap.from_dict(rig.get("bone_map", {}))
        driver, chain = _drivers(rig["bones"], names, idx, bm, src)

        self = cls.__new__(cls)
        self.model, self.armature = model, str(rig.get("armature", model.name))
        self.names, self.parent, self.head, self.tail, self.rest = names, parent, head, tail, rest
        self.world, self.w_rot, self.w_scale, self.root = world, w_rot, w_scale, idx[bm.bones.get("pelvis")]
        self.w_inv = np.linalg.inv(world[:3, :3])
        self.driver, self.notes = driver, []
        pos = complete_joints(model)
        self.joint_world = np.stack([pos[j] for j in JOINTS])
        self.frames0 = model_rest_frames(model, pos)
        self.lengths = np.array([np.linalg.norm(pos[b.tail] - pos[b.head]) for b in BONES])
        drv_bone = {BONES[c].name: i for i, c in enumerate(driver) if isinstance(c, (int, np.integer))}
        self._ride_joints(idx, chain, drv_bone)
        self._carry_frames(drv_bone)
        self._aim_chains(idx, chain, bm.bones.get("head"), pos)
        return self

    def _ride_joints(self, idx: dict[str, int], chain: list[str], drv_bone: dict[str, int]) -> None:
        """Construction pass: sets `joint_bone` and `joint_local` from `joint_world`. A joint rides
        on the model's choice of bone, else the bone driven by a canonical bone that starts (then
        ends) at the joint, else (a vertebra) the nearest chain bone, else the pelvis bone."""
        head, tail = self.head, self.tail
        arm_pts = self.to_armature(self.joint_world)
        jb = np.empty(len(JOINTS), int)
        for j, name in enumerate(JOINTS):
            frame = self.model.joints[name].frame if name in self.model.joints else None
            if frame in idx:
                jb[j] = idx[frame]
                continue
            cands = [drv_bone[b.name] for b in BONES if b.head == name and b.name in drv_bone]
            cands += [drv_bone[b.name] for b in BONES if b.tail == name and b.name in drv_bone]
            if not cands and chain:  # a vertebra: the chain bone nearest to it
                segs = [(np.linalg.norm(_closest_on_segment(arm_pts[j], head[idx[c]], tail[idx[c]]) - arm_pts[j]),
                         idx[c]) for c in chain]
                cands = [min(segs)[1]]
            jb[j] = cands[0] if cands else self.root
        self.joint_bone = jb
        self.joint_local = np.einsum("jba,jb->ja", self.rest[jb], arm_pts - head[jb])

    def _carry_frames(self, drv_bone: dict[str, int]) -> None:
        """Construction pass: sets `carrier`. A canonical frame rides on the avatar bone it drives,
        else (vertebrae, shortcuts) on its head joint's bone, else on its parent's carrier. Needs
        `joint_bone`."""
        car = np.empty(len(BONES), int)
        for i, b in enumerate(BONES):
            if b.name in drv_bone:
                car[i] = drv_bone[b.name]
            elif b.name in SPINE_BONES or b.name.startswith("shortcut_"):
                car[i] = self.joint_bone[JI[b.head]]
            elif b.parent is not None:
                car[i] = car[BI[b.parent]]
            else:
                car[i] = self.root
        self.carrier = car

    def _aim_chains(self, idx: dict[str, int], chain: list[str], head_bone: str | None, pos: dict) -> None:
        """Construction pass: sets `chain_s`, `chain_aim`, `chain_off` and `chain_vertebra` (zero for
        bones off the chain). Chain bones aim their "aim point" at the canonical spine curve: the
        head of their child up the spine (chain bone or `head_bone`) when they have one (rig chains
        need not be connected: a tail may sit off the spine), else their tail; its arc position on
        the rest curve and its place in the bone's rest frame (so the rest pose aims at itself).
        Twist: the canonical vertebra at the bone's middle."""
        names, parent, head, tail, rest = self.names, self.parent, self.head, self.tail, self.rest
        spine_rest = self.to_armature(np.stack([pos[j] for j in SPINE_JOINTS]))
        self.chain_s = np.zeros(len(names))
        self.chain_aim = np.zeros((len(names), 3))
        self.chain_off = np.zeros((len(names), 3))
        self.chain_vertebra = np.zeros(len(names), int)
        up_spine = set(chain) | {head_bone}
        for c in chain:
            i = idx[c]
            kids = [j for j in range(len(names)) if parent[j] == i and names[j] in up_spine]
            aim = head[kids[0]] if kids else tail[i]
            s_t = arc_param(spine_rest, aim)
            s_h = arc_param(spine_rest, head[i])
            self.chain_s[i] = s_t
            self.chain_aim[i] = rest[i].T @ (aim - head[i])
            # where the aim point sits off the curve, carried by the vertebra: the rest pose aims at itself
            self.chain_off[i] = aim - curve_point(spine_rest[None], s_t)[0]
            self.chain_vertebra[i] = int(np.clip(np.floor(0.5 * (s_t + s_h)), 0, sk.SPINE_COUNT - 1))

    # --- coordinates ----------------------------------------------------------------------------

    def to_armature(self, p):
        shift, _, inv_t = self._world_parts
        p = np.asarray(p, float) - shift
        return (p.reshape(-1, 3) @ inv_t).reshape(p.shape)

    def to_world(self, p):
        shift, lin_t, _ = self._world_parts
        p = np.asarray(p, float)  # one BLAS call on (N, 3) rows (einsum is several times slower)
        out = p.reshape(-1, 3) @ lin_t
        out += shift  # in place (the same sum)
        return out.reshape(p.shape)

    @property
    def _world_parts(self) -> tuple:
        """(the armature's translation, its linear part transposed, its inverse transposed): views
        of `world` and `w_inv` as the coordinate maps take them, once."""
        if getattr(self, "_wparts", None) is None:
            self._wparts = (self.world[:3, 3], self.world[:3, :3].T, self.w_inv.T)
        return self._wparts

    @property
    def bone_index(self) -> dict[str, int]:
        return {n: i for i, n in enumerate(self.names)}

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

    # --- canonical frames -> pose ---------------------------------------------------------------

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
        P, H = self._pose(np.asarray(frames, float), pelvis, float64=float64)
        if not basis:
            return self._finish(None, P, H, None, realised)
        return self._finish(self._basis(P), P, H, self._root_location(P, H), realised)

    def joint_positions(self, frames: np.ndarray, pelvis: np.ndarray, joints: list[str]) -> np.ndarray:
        """(F, len(joints), 3) world positions of a few canonical joints for the pose `solve` would
        give, posing only the bones they hang from (the IK's limb roots need the trunk only)."""
        frames = np.asarray(frames, float)
        key = tuple(joints)
        plan = self._caches.get(("joints", key))
        if plan is None:
            jidx = np.array([JI[j] for j in joints], int)
            need: set[int] = set()

            def with_ancestors(b):
                while b >= 0 and b not in need:
                    need.add(int(b))
                    b = self.parent[b]

            for b in self.joint_bone[jidx]:
                with_ancestors(b)
            if any(self.driver[b] == "chain" for b in need):  # the chain aims at the spine curve
                with_ancestors(self.joint_bone[JI["spine_root"]])
            plan = (tuple(sorted(need)), self.joint_bone[jidx], self.joint_local[jidx])
            self._caches[("joints", key)] = plan
        bones, carriers, local = plan
        P, H = self._pose(frames, pelvis, bones)
        out = H[carriers] + stacks_apply(P, local, carriers)  # (K, F, 3)
        return self.to_world(np.ascontiguousarray(out.swapaxes(0, 1)))

    @property
    def _chain_one(self) -> ChainOneFrame:
        """The spine chain's one-frame aim (mathutils constants), once per rig."""
        if getattr(self, "_chain_aim_one", None) is None:
            self._chain_aim_one = ChainOneFrame(self)
        return self._chain_aim_one

    def __getstate__(self) -> dict:
        """A pickled rig leaves its one-frame aim behind (mathutils objects do not pickle); it is
        made again on the next one-frame pose."""
        state = dict(self.__dict__)
        state.pop("_chain_aim_one", None)
        return state

    @property
    def _caches(self) -> dict:
        """Per rig, once: the posing plans (`_pose_plan`) and the joints' plans of `joint_positions`."""
        if getattr(self, "_cache", None) is None:
            self._cache = {}
        return self._cache

    def _pose(self, frames, pelvis, bones=None, float64=False):
        """Bones-first armature-space pose rotations P (N, F, 3, 3) and heads H (N, F, 3) of
        `bones` (ascending; default all, the others left unset), a depth of the hierarchy at a time
        (`_pose_plan`): each step is one stacked product over the bones of that depth."""
        nf = frames.shape[0]
        plan = self._pose_plan(None if bones is None else tuple(bones))
        chain = self._chain_plan if plan.chained else None
        float32 = chain is not None and nf == 1 and one_frame.ENABLED and not float64
        key, held = self._held_chain(chain, frames, pelvis, b"float32" if float32 else b"")
        if held is None and float32:
            # one frame: the chain aimed in mathutils (rig_one_frame.py), the rest in one flat pass
            held = self._chain_one.aimed(frames, np.asarray(pelvis, float))
            self._chain_memo = (key, held)
        few = plan.deferred is not None and nf < FEW_FRAMES
        flat = few and (chain is None or held is not None)
        P, H, HT = self._pose_buffers(plan, nf, few, flat)
        delta = self._driven(plan, chain if chain is not None and held is None else None, frames, P)
        aiming = None if delta is None else _ChainAim(self, chain, delta, frames, nf)
        if flat:
            return self._pose_flat(plan, None if chain is None else chain.order, held, P, H, pelvis, HT)
        many = nf >= STACKED_FRAMES  # one BLAS call per bone on (3F, 3) rows, as stacks_mul and stacks_apply
        for lv in plan.few if few else plan.levels:
            if len(lv.heads) and many:  # `stacks_apply`'s product bone by bone, where it goes, plus H_p
                for b, p, off_b in zip(lv.heads.tolist(), lv.head_par.tolist(), lv.head_off):
                    np.matmul(P[p].reshape(-1, 3), off_b, out=H[b].reshape(-1))
                    H[b] += H[p]
            elif len(lv.heads):  # `stacks_apply`'s stacked product, called directly
                H[lv.heads] = H.take(lv.head_par, axis=0) + np.matmul(P.take(lv.head_par, axis=0), lv.head_off4)[..., 0]
            if len(lv.loose):
                H[lv.loose] = lv.loose_at
            if len(lv.rest):
                P[lv.rest] = lv.rest_at
            if len(lv.follow) and many:
                P[lv.follow] = stacks_mul(P, lv.follow_fixed, lv.follow_par)
            elif len(lv.follow):  # `stacks_mul`'s stacked product, called directly
                P[lv.follow] = np.matmul(P.take(lv.follow_par, axis=0), lv.follow_fixed4)
            for i in lv.chain:
                if held is not None:
                    P[i] = held[chain.index[i]]
                else:
                    aiming.bone(i, P, H)
            if lv.root:
                self._place_root(P, H, pelvis)
        if few:
            self._deferred_heads(plan.deferred, P, H, HT)
        if aiming is not None and aiming.count == len(chain.index):
            self._chain_memo = (key, aiming.aimed)
        return P, H

    def _held_chain(self, chain, frames, pelvis, tag: bytes = b"") -> tuple:
        """(the chain's inputs' bytes, its rotations when they are the last pose's, else None).
        Decision (speed): the chain's rotations are the costliest part of a pose and a solve often
        poses the same trunk again (the egocentric method poses the avatar four times a block, the
        arms alone changing after the first IK): when every input they read is the last pose's,
        bit for bit, they are the last pose's. `tag` marks how they were aimed (b"float32": one
        frame's in mathutils), so a pose aimed another way never takes them."""
        if chain is None:
            return None, None
        key = frames.take(chain.inputs, axis=1).tobytes() + np.asarray(pelvis, float).tobytes() + tag
        memo = getattr(self, "_chain_memo", None)
        return key, (memo[1] if memo is not None and memo[0] == key else None)  # bit for bit

    def _pose_buffers(self, plan: _PosePlan, nf: int, few: bool, flat: bool) -> tuple:
        """(P, H, HT): a few frames' heads H are the first rows of HT, whose rows after them take
        the one padded pass's offsets and its zero (`_deferred_heads`: no concatenated copy of H)."""
        n = len(self.names)
        P = np.empty((n, nf, 3, 3))
        if few and nf < STACKED_FRAMES:
            late = (plan.flat if flat else plan.deferred)[-4]
            HT = np.empty((n + len(late) + 1, nf, 3))
            HT[-1] = 0.0
            return P, HT[:n], HT
        return P, np.empty((n, nf, 3)), None

    def _driven(self, plan: _PosePlan, chain, frames, P):
        """The driven bones' rotations into P, W^-1 C(t) (C0^-1 W M_A) (the canonical bone's rotation
        since rest, on the bone's rest), and with a `chain` to aim, its vertebrae's turns since rest
        W^-1 C(t) C0^-1 W (returned; else None)."""
        nf = frames.shape[0]
        delta = None
        if chain is not None and nf < STACKED_FRAMES and len(plan.driven):
            # A few frames: the driven bones' and the chain vertebrae's products in one stacked
            # product (each its own BLAS call either way, so the same bits)
            rows, fixed = self._driven_and_chain(plan, chain)
            both = np.matmul(frames.swapaxes(0, 1).take(rows, axis=0), fixed)
            P[plan.driven] = self._from_world(both[:len(plan.driven)])
            return self._from_world(both[len(plan.driven):])
        if nf >= STACKED_FRAMES and self._w_identity:
            # Many frames: each driven bone's product written where it goes (`stacks_mul`'s BLAS
            # call bone by bone, without its stack to copy into P)
            for b, c, fixed in zip(plan.driven.tolist(), plan.canon.tolist(), plan.fixed):
                np.matmul(frames[:, c].reshape(-1, 3), fixed, out=P[b].reshape(-1, 3))
        elif len(plan.driven) and nf < STACKED_FRAMES:  # `stacks_mul`'s stacked product, called directly
            P[plan.driven] = self._from_world(np.matmul(frames.swapaxes(0, 1).take(plan.canon, axis=0),
                                                        plan.fixed[:, None]))
        elif len(plan.driven):
            P[plan.driven] = self._from_world(stacks_mul(frames.swapaxes(0, 1), plan.fixed, plan.canon))
        if chain is not None:
            delta = self._from_world(stacks_mul(frames.swapaxes(0, 1), chain.fixed, chain.vertebra))
        return delta

    def _place_root(self, P, H, pelvis) -> None:
        """H_root = W^-1 (pelvis - t) - P_root pelvis_local: `to_armature` and `stack_apply`'s
        products, called directly."""
        shift, _, inv_t = self._world_parts
        nf = P.shape[1]
        at = (np.asarray(pelvis, float) - shift).reshape(-1, 3) @ inv_t
        np.subtract(at.reshape(nf, 3), (P[self.root].reshape(-1, 3) @ self._pelvis_at).reshape(nf, 3), out=H[self.root])

    def _deferred_heads(self, table_plan, P, H, HT) -> None:
        """The heads of `table_plan` (rows, parents, offsets, the padded sum table) in one padded
        pass: each its anchor's head plus the offsets down its path, in order. A few frames' (HT:
        H with rows after it) take their offsets' products written after H and a zero row."""
        late, par, off, table = table_plan
        if HT is None:
            terms = np.concatenate([H, stacks_apply(P, off, par), np.zeros((1,) + H.shape[1:])])
        else:
            n = len(H)
            np.matmul(P.take(par, axis=0), off[:, None, :, None], out=HT[n:-1].reshape(len(late), -1, 3, 1))
            terms = HT
        H[late] = np.add.reduce(terms.take(table, axis=0), axis=0)  # over the path, in order

    def _driven_and_chain(self, plan: _PosePlan, chain: _ChainPlan) -> tuple[np.ndarray, np.ndarray]:
        """(the canonical bones read by the driven bones then by the chain's vertebrae, their fixed
        factors (K, 1, 3, 3)), once per pose plan."""
        key = ("driven+chain", id(plan))
        got = self._caches.get(key)
        if got is None:
            got = self._caches[key] = (np.concatenate([plan.canon, chain.vertebra]),
                                       np.concatenate([plan.fixed, chain.fixed])[:, None])
        return got

    def _pose_flat(self, plan: _PosePlan, chain_bones, held, P, H, pelvis, HT=None):
        """`_pose`'s few frames whose chain needs no aiming, the driven bones posed: every other
        rotation, then every head in one padded pass. Decision (speed, the same values): a solve's
        later poses hold the chain's rotations, so nothing is aimed level by level; each head is
        the same sum in the same order as level by level, (H_anchor + c_1) + c_2 + ..."""
        rest, rest_at, loose, loose_at, follows, late, par, off, table = plan.flat
        if len(rest):
            P[rest] = rest_at
        if chain_bones is not None:
            P[chain_bones] = held
        for bones_f, par_f, fixed_f in follows:
            if P.shape[1] < STACKED_FRAMES:  # `stacks_mul`'s stacked product, called directly
                P[bones_f] = np.matmul(P.take(par_f, axis=0), fixed_f[:, None])
            else:
                P[bones_f] = stacks_mul(P, fixed_f, par_f)
        if len(loose):
            H[loose] = loose_at
        if plan.has_root:
            self._place_root(P, H, pelvis)
        self._deferred_heads((late, par, off, table), P, H, HT)
        return P, H

    @property
    def _pelvis_at(self) -> np.ndarray:
        """`_pelvis_local`, once."""
        if getattr(self, "_pelvis_loc", None) is None:
            self._pelvis_loc = self._pelvis_local
        return self._pelvis_loc

    @property
    def _pelvis_local(self) -> np.ndarray:
        """The pelvis joint in the root bone's rest frame (it may ride on another bone: the root is
        placed so that bone's joint lands)."""
        if self.joint_bone[JI["pelvis"]] != self.root:
            return self.rest[self.root].T @ (self.joint_world_arm(JI["pelvis"]) - self.head[self.root])
        return self.joint_local[JI["pelvis"]]

    def _pose_plan(self, bones: tuple | None) -> _PosePlan:
        """Per rig and bone subset, once: the driven bones (W^-1 C_c(t) (C0^-1 W M_A), each on its own)
        and, depth by depth, the heads placed from their parents (H_p + P_p offset), the bones that
        follow their parents (P_p M_p^-1 M_A), the parentless ones (at rest) and the spine chain's
        (aimed one by one). Bones of one depth need only shallower ones."""
        plan = self._caches.get(("pose", bones))
        if plan is not None:
            return plan
        keep = set(range(len(self.names))) if bones is None else set(bones)
        depth = np.zeros(len(self.names), int)
        for i, p in enumerate(self.parent):  # parents come first
            depth[i] = depth[p] + 1 if p >= 0 else 0
        rows = self._bone_plan
        driven = [i for i in sorted(keep) if isinstance(rows[i][1], (int, np.integer))]
        chained = any(rows[i][1] == "chain" for i in keep)
        # The heads the spine chain reads while it is aimed: its bones' and the spine curve's
        # start bone's, with their ancestors'. A few frames place only these level by level.
        early: set[int] = set()
        if chained:
            for b in [i for i in keep if rows[i][1] == "chain"] + [int(self.joint_bone[JI["spine_root"]])]:
                while b >= 0 and b not in early:
                    early.add(int(b))
                    b = self.parent[b]

        def levels_of(placed):
            out = []
            for d in range(int(depth.max()) + 1 if len(depth) else 0):
                at = [i for i in sorted(keep) if depth[i] == d]
                heads = [i for i in at if i != self.root and rows[i][0] >= 0 and placed(i)]
                follow = [i for i in at if rows[i][1] is None and rows[i][0] >= 0]
                out.append(_Level(
                    np.array(heads, int), np.array([rows[i][0] for i in heads], int),
                    np.array([rows[i][2] for i in heads], float).reshape(-1, 3),
                    np.array([i for i in at if i != self.root and rows[i][0] < 0], int),
                    np.array([i for i in at if rows[i][1] is None and rows[i][0] < 0], int),
                    np.array(follow, int), np.array([rows[i][0] for i in follow], int),
                    np.array([rows[i][3] for i in follow], float).reshape(-1, 3, 3),
                    [i for i in at if rows[i][1] == "chain"], self.root in at))
                out[-1].loose_at = self.head[out[-1].loose][:, None]
                out[-1].rest_at = self.rest[out[-1].rest][:, None]
                out[-1].head_off4 = out[-1].head_off[:, None, :, None]
                out[-1].follow_fixed4 = out[-1].follow_fixed[:, None]
            return out

        levels = levels_of(lambda i: True)
        plan = _PosePlan(np.array(driven, int), np.array([rows[i][1] for i in driven], int),
                         np.array([rows[i][3] for i in driven], float).reshape(-1, 3, 3), levels, chained,
                         self.root in keep)
        # The other heads, for a few frames: each is its anchor's head (the nearest ancestor placed
        # in the levels: an early bone, the root or a parentless one) plus the offsets P_p o down
        # the path, added in the levels' order (H_a + c_1) + c_2 + ..., padded with exact zeros.
        late = [i for i in sorted(keep) if i != self.root and rows[i][0] >= 0 and i not in early]
        if late:
            plan.few = [lv for lv in levels_of(lambda i: i in early)  # the depths with work left
                        if len(lv.heads) or len(lv.loose) or len(lv.rest) or len(lv.follow) or lv.chain or lv.root]
            plan.deferred = self._head_table(late, rows)
            # With no chain to aim, every head in that one pass: each its root's or parentless
            # ancestor's head plus the offsets down the path, the same sums in the same order.
            hanging = [i for i in sorted(keep) if i != self.root and rows[i][0] >= 0]
            follows = [(lv.follow, lv.follow_par, lv.follow_fixed) for lv in levels if len(lv.follow)]
            rest = np.array([i for lv in levels for i in lv.rest.tolist()], int)
            loose = np.array([i for lv in levels for i in lv.loose.tolist()], int)
            plan.flat = (rest, self.rest[rest][:, None], loose, self.head[loose][:, None], follows,
                         *self._head_table(hanging, rows))
        self._caches[("pose", bones)] = plan
        return plan

    def _head_table(self, late: list[int], rows: list) -> tuple:
        """For the heads of bones `late`, placed in one pass (`_pose`): (the bones, their parents,
        the offsets in the parents' rest frames, the padded sum table: per bone its anchor's row in
        H (the nearest ancestor not in `late`) and its path's offsets' rows after H's, top down,
        padded with the row of a zero)."""
        row = {b: k for k, b in enumerate(late)}
        n = len(self.names)
        paths = []
        for b in late:
            path = [b]
            while path[-1] in row and self.parent[path[-1]] in row:
                path.append(int(self.parent[path[-1]]))
            paths.append((int(self.parent[path[-1]]), [n + row[k] for k in reversed(path)]))
        width = max(len(p) for _, p in paths)
        zero = n + len(late)
        table = np.array([[a] + p + [zero] * (width - len(p)) for a, p in paths], int).T  # (1 + width, D)
        return (np.array(late, int), np.array([rows[i][0] for i in late], int),
                np.array([rows[i][2] for i in late], float).reshape(-1, 3), table)

    @property
    def _chain_plan(self) -> _ChainPlan:
        if getattr(self, "_chain_rows", None) is None:
            bones = [i for i, d in enumerate(self.driver) if d == "chain"]
            vert = np.array([BI[SPINE_BONES[self.chain_vertebra[i]]] for i in bones], int)
            s = self.chain_s[bones]
            k = np.clip(np.floor(s), 0, len(SPINE_JOINTS) - 2).astype(int)
            # What the chain's rotations read: the canonical frames driving the chain's ancestors
            # and the bone the spine curve starts on (and its ancestors), the vertebrae's twists,
            # and the spine bones the curve is built along.
            above: set[int] = set()
            for b in bones + [int(self.joint_bone[JI["spine_root"]])]:
                b = self.parent[b] if b in bones else b
                while b >= 0 and b not in above:
                    above.add(int(b))
                    b = self.parent[b]
            inputs = {int(self.driver[b]) for b in above if isinstance(self.driver[b], (int, np.integer))}
            inputs |= {int(v) for v in vert} | {BI[b] for b in SPINE_BONES}
            self._chain_rows = _ChainPlan({b: j for j, b in enumerate(bones)}, vert,
                                          np.array([self.frames0[c].T @ self.w_rot for c in vert]).reshape(-1, 3, 3),
                                          self.rest[bones], self.chain_aim[bones], self.chain_off[bones], k, s - k,
                                          np.array(sorted(inputs), int), np.array(bones, int))
        return self._chain_rows

    @property
    def _bone_plan(self) -> list[tuple]:
        """Per bone, once per rig: (parent, driver, head offset in the parent's rest frame, the
        fixed right factor of its rotation: C0^-1 W M_A when driven, M_parent^-1 M_A when it
        follows its parent)."""
        if getattr(self, "_plan", None) is None:
            plan = []
            for i, (p, drv) in enumerate(zip(self.parent, self.driver)):
                offset = self.rest[p].T @ (self.head[i] - self.head[p]) if p >= 0 else None
                if isinstance(drv, (int, np.integer)):
                    fixed = self.frames0[drv].T @ self.w_rot @ self.rest[i]
                elif drv is None and p >= 0:
                    fixed = self.rest[p].T @ self.rest[i]
                else:
                    fixed = None
                plan.append((int(p), drv, offset, fixed))
            self._plan = plan
        return self._plan

    def _from_world(self, m):
        """W^-1 m for a stack of 3x3 matrices (the armature's rotation is usually the identity)."""
        return m if self._w_identity else mul_stack(self.w_rot.T, m)

    def _to_world_rot(self, m):
        """W m for a stack of 3x3 matrices."""
        return m if self._w_identity else mul_stack(self.w_rot, m)

    @property
    def _w_identity(self) -> bool:
        if getattr(self, "_w_id", None) is None:
            self._w_id = bool(np.allclose(self.w_rot, np.eye(3), atol=EPS))
        return self._w_id

    def _basis(self, P):
        """Pose-bone quaternions from bones-first armature-space pose rotations P (N, F, 3, 3):
        basis = M_child^-1 M_parent P_parent^-1 P_child (a parentless bone: M^-1 P)."""
        kids, parents, fixed = self._basis_plan
        if P.shape[1] >= STACKED_FRAMES and len(kids) * P.shape[1] >= MANY_PRODUCTS:
            return self._basis_many(P)
        # X = P_parent^-1 P_child, built transposed (X^T = P_child^T P_parent: the same products)
        rel_t = transposed(P)
        rel_t[kids] = matmul_stack(P.take(kids, axis=0).swapaxes(-1, -2), P.take(parents, axis=0))
        # basis^T = X^T (M^-1 M_p)^T for each bone, one stacked product (as mul_stack, bone by bone)
        basis_t = stacks_mul(rel_t, fixed)  # (N, F, 3, 3)
        # the quaternions from basis entries' rows, frames first: basis[f, n, i, j] = basis_t[n, f, j, i]
        n, nf = basis_t.shape[:2]
        # quat_from_rows' values (pose_kernels.quat_from_entries: fewer numpy calls)
        return pose_kernels.quat_from_entries(basis_t.transpose(3, 2, 1, 0).reshape(9, nf * n)).T.reshape(nf, n, 4)

    def _basis_many(self, P):
        """`_basis` of many frames (a bake's chunk), the same values: the products and quaternions
        read the rotations' entries as contiguous rows (`pose_kernels`) instead of strided entries
        of gathered and transposed copies of the whole stack. Decision (speed, the same bits):
        X^T's entries are `matmul_stack`'s sums, each product by its fixed factor the same BLAS
        call on the same (3F, 3) rows as `stacks_mul`, the quaternions `quat_from_rows`'s."""
        kids, parents, fixed = self._basis_plan
        n, nf = P.shape[:2]
        ent = pose_kernels.entry_rows(P)  # (9, N, F)
        rel_t = np.empty((len(kids), nf, 3, 3))  # X^T of the bones with a parent
        pose_kernels.product_t_into(rel_t, ent.take(kids, axis=1), ent.take(parents, axis=1))
        row = self._basis_rows
        basis_t = np.empty((n, nf, 3, 3))
        for b in range(n):  # basis^T = X^T (M^-1 M_p)^T, `stacks_mul`'s product bone by bone
            src = rel_t[row[b]] if row[b] >= 0 else np.ascontiguousarray(P[b].swapaxes(-1, -2))
            np.matmul(src.reshape(-1, 3), fixed[b], out=basis_t[b].reshape(-1, 3))
        # basis[f, n, i, j] = basis_t[n, f, j, i]: the basis's entry rows are basis_t's transposed
        q = pose_kernels.quat_from_entries(pose_kernels.entry_rows(basis_t, _TRANSPOSE_ROWS).reshape(9, -1))
        return q.reshape(4, n, nf).transpose(2, 1, 0)

    @property
    def _basis_rows(self) -> list[int]:
        """Per bone, its row among the bones with a parent (`_basis_plan`), -1 for none; once."""
        if getattr(self, "_brows", None) is None:
            kids = self._basis_plan[0].tolist()
            self._brows = [kids.index(b) if b in kids else -1 for b in range(len(self.names))]
        return self._brows

    @property
    def _basis_plan(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(bones with a parent, their parents, per bone the fixed left factor's transpose (N, 3, 3):
        (M^-1 M_p)^T, or (M^-1)^T for a parentless bone), once per rig."""
        if getattr(self, "_bplan", None) is None:
            rel_t = self.rest.swapaxes(-1, -2)
            kids = np.flatnonzero(self.parent >= 0)
            fixed = np.stack([(rel_t[i] if p < 0 else rel_t[i] @ self.rest[p]).T for i, p in enumerate(self.parent)])
            self._bplan = (kids, self.parent[kids], np.ascontiguousarray(fixed))
        return self._bplan

    def joint_world_arm(self, j):
        return self.to_armature(self.joint_world[j])

    def _root_location(self, P, H):
        i, p = self.root, self.parent[self.root]
        if p < 0:
            return (H[i] - self.head[i]) @ self.rest[i]
        if getattr(self, "_root_rel", None) is None:  # (M_i^-1 M_p)^T and M_i^-1 (h_i - h_p), once
            self._root_rel = ((self.rest[i].T @ self.rest[p]).T, self.rest[i].T @ (self.head[i] - self.head[p]))
        rel_t, rest_off = self._root_rel
        local = (P[p].swapaxes(-1, -2) @ (H[i] - H[p])[..., None])[..., 0]
        return local @ rel_t - rest_off

    def _spine_curve(self, frames, P, H):
        """Canonical spine joints (F, 13, 3), armature space: spine_root on its avatar bone, then
        the canonical vertebrae with the avatar's lengths along the frames' +Y."""
        j0 = JI["spine_root"]
        b = self.joint_bone[j0]
        if self.driver[b] == "chain":  # not posed yet: its head is placed, orient it as at rest
            p = self.parent[b]
            if p < 0:
                rot = self.rest[b]
            else:
                if getattr(self, "_start_rel", None) is None:  # M_p^-1 M_b, once
                    self._start_rel = self.rest[p].T @ self.rest[b]
                rot = P[p] @ self._start_rel
        else:
            rot = P[b]
        start = H[b] + rot @ self.joint_local[j0]
        nf = len(start)
        if frames.flags.c_contiguous:  # the vertebrae's +Y columns in one take
            ys = frames.reshape(nf, -1).take(_SPINE_Y, axis=1).reshape(nf, -1, 3) * self.lengths[_SPINE_ROWS][:, None]
        else:
            ys = frames[:, _SPINE_ROWS][..., :, 1] * self.lengths[_SPINE_ROWS][:, None]
        steps = ys @ self.w_inv.T  # world steps in armature units
        curve = np.empty((nf, len(_SPINE_ROWS) + 1, 3))  # start, then start + the running sum
        curve[:, 0] = start
        np.cumsum(steps, axis=1, out=curve[:, 1:])
        curve[:, 1:] += start[:, None]
        return curve

    def _finish(self, basis, P, H, root_loc, realised=True) -> RigPose:
        """The RigPose of bones-first pose rotations P (N, F, 3, 3) and heads H (N, F, 3): the
        canonical joints riding on their bones and the realised canonical frames."""
        nf = P.shape[1]
        if nf == 1:
            return self._finish_one(basis, P, H, root_loc, realised)
        if nf < FEW_FRAMES:  # every carrier at once, its joints padded to the most any bone carries
            bones, local, order = self._joint_table
            rel = stacks_mul(P, local, bones)  # (G, F, 3, K)
            ride = H[bones][:, :, None, :] + rel.swapaxes(-1, -2)  # (G, F, K, 3)
            joints = ride.swapaxes(0, 1).reshape(nf, -1, 3).take(order, axis=1)
        else:
            joints = np.empty((nf, len(JOINTS), 3))
            for bones, js, local in self._joint_groups:  # the bones carrying K joints each, at once
                rel = stacks_mul(P, local, bones)  # (G, F, 3, K)
                if nf >= STACKED_FRAMES:  # each joint written where it goes, H + P o (no (G, F, K, 3) stack to scatter)
                    for g, (b, row) in enumerate(zip(bones.tolist(), js.tolist())):
                        for kk, j in enumerate(row):
                            np.add(H[b], rel[g, :, :, kk], out=joints[:, j])
                else:
                    joints[:, js] = (H[bones][:, :, None, :] + rel.swapaxes(-1, -2)).swapaxes(0, 1)
        joints = self.to_world(joints)
        # C_c(t) = W P_car(t) M_car^-1 W^-1 C_c0
        if realised is False or realised is None:
            frames = None
        else:
            idx, car_rel, car, unrealised = self._realised_rows(realised)
            frames = np.empty((nf, len(BONES), 3, 3))  # NaN where not realised (written once)
            if len(unrealised):
                frames[:, unrealised] = np.nan
            if len(idx) and nf >= STACKED_FRAMES and self._w_identity:
                # `stacks_mul`'s product bone by bone into one buffer, copied where it goes (no
                # (K, F, 3, 3) stack to allocate and scatter)
                buf = np.empty((nf, 3, 3))
                for c, b, rel in zip(idx.tolist(), car.tolist(), car_rel):
                    np.matmul(P[b].reshape(-1, 3), rel, out=buf.reshape(-1, 3))
                    frames[:, c] = buf
            elif len(idx):
                rel = self._to_world_rot(stacks_mul(P, car_rel, car))
                frames[:, idx] = rel.swapaxes(0, 1)
        return RigPose(basis, P.swapaxes(0, 1), H.swapaxes(0, 1), root_loc, joints, frames)

    def _finish_one(self, basis, P, H, root_loc, realised) -> RigPose:
        """`_finish` of one frame, the same values in fewer numpy calls: the joints' padded product
        (`_joint_table`) with its heads added in place and gathered in one `take` (`_one_tables`),
        the realised frames written into a stack whose last row is NaN and gathered in one `take`."""
        bones, local, jrows, car_rows = self._one_tables
        ride = np.matmul(P.take(bones, axis=0), local)  # (G, 1, 3, K): P_car offset, as `stacks_mul`
        ride += H.take(bones, axis=0)[..., None]  # H + P o (the same sum)
        shift, lin_t, _ = self._world_parts
        joints = np.matmul(ride.take(jrows), lin_t)  # `to_world` of the (J, 3) rows
        joints += shift
        joints = joints.reshape(1, -1, 3)
        if realised is False or realised is None:
            frames = None
        else:
            idx, car_rel, car, _ = self._realised_rows(realised)
            rows = np.empty((len(idx) + 1, 1, 3, 3))
            rows[-1] = np.nan
            if len(idx):
                if self._w_identity:
                    np.matmul(P.take(car, axis=0), car_rel[:, None], out=rows[:-1])
                else:
                    rows[:-1] = self._to_world_rot(stacks_mul(P, car_rel, car))
            frames = rows.take(car_rows[realised is True or tuple(realised)], axis=0).reshape(1, len(BONES), 3, 3)
        return RigPose(basis, P.swapaxes(0, 1), H.swapaxes(0, 1), root_loc, joints, frames)

    @property
    def _one_tables(self) -> tuple:
        """`_finish_one`'s tables, once per rig: the joints' carriers, their padded offsets (G, 1, 3,
        K), each joint's three entries in the (G, 1, 3, K) product, and per realised set (a dict
        keyed like `_realised_rows`, filled on first use) each canonical bone's row in the realised
        stack (its own, or the NaN row after them)."""
        if getattr(self, "_one_tab", None) is None:
            bones, local, order = self._joint_table
            width = local.shape[-1]
            g, kk = np.divmod(order, width)  # joint j: carrier row g, padded column kk
            jrows = ((g * 3)[:, None] + np.arange(3)) * width + kk[:, None]  # (J, 3) into (G, 1, 3, K)
            self._one_tab = (bones, local[:, None], jrows, _RealisedTables(self))
        return self._one_tab

    def _realised_rows(self, realised) -> tuple:
        """(the canonical bones realised (True: all; a list of indices), their carriers' fixed factors,
        their carriers, the bones not realised), once per set."""
        key = "all" if realised is True else tuple(realised)  # numpy's integers hash as Python's
        rows = self._caches.get(("realised", key))
        if rows is None:
            idx = np.arange(len(BONES)) if realised is True else np.asarray(realised, int)
            rows = self._caches[("realised", key)] = (idx, self._carrier_rel[idx], self.carrier[idx],
                                                      np.setdiff1d(np.arange(len(BONES)), idx))
        return rows

    @property
    def _joint_groups(self) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Once per rig: the bones carrying joints, grouped by how many they carry (K): (the bones
        (G,), their joints (G, K), the joints' rest-frame offsets (G, 3, K))."""
        if getattr(self, "_jgroups", None) is None:
            by_count: dict[int, list] = {}
            for b in np.unique(self.joint_bone):
                js = np.flatnonzero(self.joint_bone == b)
                by_count.setdefault(len(js), []).append((int(b), js))
            self._jgroups = [(np.array([b for b, _ in g], int), np.stack([js for _, js in g]),
                              np.stack([self.joint_local[js].T for _, js in g]))
                             for _, g in sorted(by_count.items())]
        return self._jgroups

    @property
    def _joint_table(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`_joint_groups` as one padded group, once per rig: (the carrying bones (G,), their joints'
        offsets padded with zeros (G, 3, K), each joint's row in the (G K) padded rows)."""
        if getattr(self, "_jtable", None) is None:
            width = max(js.shape[1] for _, js, _ in self._joint_groups)
            bones = np.concatenate([b for b, _, _ in self._joint_groups])
            local = np.zeros((len(bones), 3, width))
            order = np.zeros(len(JOINTS), int)
            g0 = 0
            for b, js, loc in self._joint_groups:
                local[g0:g0 + len(b), :, :js.shape[1]] = loc
                order[js] = (g0 + np.arange(len(b)))[:, None] * width + np.arange(js.shape[1])
                g0 += len(b)
            self._jtable = (bones, local, order)
        return self._jtable

    @property
    def _carrier_rel(self):
        if getattr(self, "_car_rel", None) is None:
            car = self.carrier
            self._car_rel = self.rest[car].swapaxes(-1, -2) @ self.w_rot.T @ self.frames0
        return self._car_rel

    # --- pose -> joints (Blender's FK, for checks and for the offsets method) --------------------

    def fk(self, basis: np.ndarray, root_location: np.ndarray, *, locations: np.ndarray | None = None,
           realised=True) -> RigPose:
        """Blender's pose evaluation from pose-bone quaternions (F, N, 4) and the root bone's
        location (F, 3); `locations` (F, N, 3), when given, are every bone's pose location (an
        animated character's: a bone above the pelvis may carry the motion), the root's included."""
        basis = np.asarray(basis, float)
        nf, n = basis.shape[:2]
        B = quat_to_matrix(basis).swapaxes(0, 1)
        P = np.empty((n, nf, 3, 3))
        H = np.empty((n, nf, 3))
        zero = np.zeros((nf, 3))
        for i in range(n):
            p = self.parent[i]
            if locations is not None:
                loc = locations[:, i]
            else:
                loc = root_location if i == self.root else zero
            if p < 0:
                P[i] = mul_stack(self.rest[i], B[i])
                H[i] = self.head[i] + loc @ self.rest[i].T
            else:
                rel = self.rest[p].T @ self.rest[i]
                pr = stack_mul(P[p], rel)
                P[i] = pr @ B[i]
                H[i] = H[p] + stack_apply(P[p], self.rest[p].T @ (self.head[i] - self.head[p])) \
                    + (pr @ loc[..., None])[..., 0]
        return self._finish(basis, P, H, np.asarray(root_location, float), realised)


class _ChainAim:
    """The spine chain's bones aimed one by one (`AvatarRig._pose`): what each aim needs but its
    parent's pose (its vertebra's turn since rest, the twist; the aim point it carries; the offset
    of its target off the curve), the canonical spine curve once the bone it starts on is posed,
    and the aimed rotations, written into one stack (the memo's)."""

    def __init__(self, rig: AvatarRig, chain: _ChainPlan, delta, frames, nf: int):
        self.rig, self.chain, self.frames, self.nf = rig, chain, frames, nf
        self.twist = stacks_mul(delta, chain.rest)
        self.aim = stacks_apply(self.twist, chain.aim)
        self.off = stacks_apply(delta, chain.off)
        self.target = None
        self.aimed = np.empty((len(chain.index), nf, 3, 3))
        self.count = 0

    def bone(self, i: int, P, H) -> None:
        """Aims chain bone i (its head placed, its parent posed) at its point of the spine curve."""
        chain, j = self.chain, self.chain.index[i]
        if self.target is None:  # the canonical spine curve, once the bone it starts on is posed
            curve = self.rig._spine_curve(self.frames, P, H)
            self.target = chain.w0 * curve.take(chain.k, axis=1).swapaxes(0, 1) \
                + chain.w1 * curve.take(chain.k1, axis=1).swapaxes(0, 1) + self.off
        turn = quat_to_matrix(quat_between(self.aim[j], self.target[j] - H[i]))
        np.matmul(turn, self.twist[j], out=self.aimed[j])
        P[i] = self.aimed[j]
        self.count += 1


class _RealisedTables(dict):
    """Per realised set (True or a tuple of canonical bone indices): each canonical bone's row in
    `_finish_one`'s realised stack (its index among the realised, else the NaN row after them)."""

    def __init__(self, rig: AvatarRig):
        super().__init__()
        self.rig = rig

    def __missing__(self, key):
        idx = self.rig._realised_rows(True if key is True else list(key))[0]
        rows = np.full(len(BONES), len(idx), int)
        rows[idx] = np.arange(len(idx))
        self[key] = rows
        return rows


def _closest_on_segment(p, a, b):
    ab = b - a
    t = np.clip(np.dot(p - a, ab) / max(np.dot(ab, ab), EPS), 0.0, 1.0)
    return a + t * ab


def arc_param(curve: np.ndarray, p: np.ndarray) -> float:
    """Position of p's projection on the polyline, in segments (0..len-1)."""
    best = (np.inf, 0.0)
    for k in range(len(curve) - 1):
        a, b = curve[k], curve[k + 1]
        ab = b - a
        t = float(np.clip(np.dot(p - a, ab) / max(np.dot(ab, ab), EPS), 0.0, 1.0))
        dist = np.linalg.norm(a + t * ab - p)
        if dist < best[0] - 1e-9:
            best = (dist, k + t)
    return best[1]


def curve_point(curve: np.ndarray, s: float) -> np.ndarray:
    """Points (F, 3) at arc parameter `s` (in segments, `arc_param`) on polylines `curve` (F, N, 3)."""
    k = int(np.clip(np.floor(s), 0, curve.shape[1] - 2))
    t = s - k
    return (1 - t) * curve[:, k] + t * curve[:, k + 1]


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
_TRANSPOSE_ROWS = np.array([0, 3, 6, 1, 4, 7, 2, 5, 8])  # a 3x3's entries (i, j) -> (j, i), row-major
_SPINE_ROWS = np.array([BI[b] for b in SPINE_BONES], int)  # the canonical vertebrae (_spine_curve)
_SPINE_Y = (_SPINE_ROWS[:, None] * 9 + np.array([1, 4, 7])).ravel()  # their frames' +Y entries, row-major
