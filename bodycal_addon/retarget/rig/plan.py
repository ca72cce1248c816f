"""The avatar's rig as a frame-independent plan (DESIGN.md §1 step 2, "Prepared solver"): everything
posing reads that does not depend on the frames, built once from the avatar body model's rig
(`BodyModel.extra["rig"]`, written by the avatar calibration).

Bones in armature space (`head`, `tail`, `rest` = `bone.matrix_local` 3x3), parents first; the
armature's `matrix_world` W; per bone what drives it (a canonical bone, the spine chain, or nothing:
it follows its parent); the canonical joints riding on avatar bones (`joint_bone`, `joint_local`) and
the canonical frames carried by them (`carrier`). Then the constants the posing products take,
computed here once (each field says which formula it is a factor of), and three small caches owned
by the plan, keyed by value: the pose plans per bone subset, the joints' plans of
`joint_positions` per joint list, the realised rows per set of canonical bones.

Decision (correctness): these were lazy attributes and caches on `AvatarRig`, one keyed by `id()` of
a pose plan; an `id()` can be reused by a new object once the first is collected, so every key here
is a value (a tuple of bone or joint indices) and every constant a field computed at construction.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ...body import naming
from ...body import skeleton as sk
from ...body.bodymodel import BodyModel
from ...body.rest_frames import complete_joints, model_rest_frames
from ...body.skeleton import BONE_INDEX as BI
from ...body.skeleton import BONES, JOINTS, SPINE_BONES, SPINE_JOINTS
from ...body.skeleton import JOINT_INDEX as JI
from ...core.errors import BodyCalError
from ...core.transforms import EPS, mul_stack
from ..rig_one_frame import ChainOneFrame
from .basis import BasisPlan
from .chain import ChainPlan
from .pose_plan import PosePlan, build_pose_plan


@dataclass(frozen=True)
class TurnedOne:
    """One frame's constants in a turned armature's own turned space (`RigPlan.turned_one`).

    Decision (speed, measured in instructions): every one-frame product carried the armature's
    rotation W (the driven bones' W^-1 C, the realised frames' W P, the chain's W^-1 C), a
    stacked product over ~50 bones each, ~40,000 instructions a call. Posed as P' = W P and
    H' = W H, the driven bones are C (C0^-1 W M_A), each child's rule is unchanged (W P_p M_p^-1
    M_c), the basis's P_p^T P_c is unchanged, and W^-1 is left to these constants and to the
    pose's rotations and heads when read (`fk.RigPose.turned`)."""

    root: tuple  # `RigPlan.one_root` with W W^-1's rows
    lin_t: np.ndarray  # (3, 3) W lin^T: turned rows to the world (plus the shift)


@dataclass(eq=False)
class RigPlan:
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

    # The constants of the posing products, computed once (`__post_init__`)
    # the coordinate maps' factors: the armature's translation, its linear part transposed and its
    # inverse transposed (views of `world` and `w_inv`, as `to_world` and `to_armature` take them)
    shift: np.ndarray = field(init=False, repr=False)
    lin_t: np.ndarray = field(init=False, repr=False)
    inv_t: np.ndarray = field(init=False, repr=False)
    w_identity: bool = field(init=False, repr=False)  # W's rotation is the identity (W^-1 m = m)
    # per bone: (parent, driver, head offset in the parent's rest frame, the fixed right factor of
    # its rotation: C0^-1 W M_A when driven, M_parent^-1 M_A when it follows its parent)
    bone_rows: list[tuple] = field(init=False, repr=False)
    # the pelvis joint in the root bone's rest frame (it may ride on another bone: the root is
    # placed so that bone's joint lands)
    pelvis_at: np.ndarray = field(init=False, repr=False)
    # the spine curve's start: its bone's rest rotation under its parent M_p^-1 M_b (None: no parent)
    start_rel: np.ndarray | None = field(init=False, repr=False)
    chain: ChainPlan = field(init=False, repr=False)  # the spine chain's bones and their aims
    basis_plan: BasisPlan = field(init=False, repr=False)  # the basis solve's fixed factors
    # the canonical frames' carriers' fixed factors M_car^-1 W^-1 C_c0 (`fk.finish`)
    carrier_rel: np.ndarray = field(init=False, repr=False)
    # the bones carrying joints, grouped by how many they carry (K): (the bones (G,), their joints
    # (G, K), the joints' rest-frame offsets (G, 3, K))
    joint_groups: list[tuple] = field(init=False, repr=False)
    # `joint_groups` as one padded group: (the carrying bones (G,), their joints' offsets padded
    # with zeros (G, 3, K), each joint's row in the (G K) padded rows)
    joint_table: tuple = field(init=False, repr=False)
    # one frame's (`fk.finish_one`): the joint table's bones, its offsets (G, 1, 3, K), each joint's
    # three entries in the (G, 1, 3, K) product
    one_joints: tuple = field(init=False, repr=False)
    # one frame's root placement in Python floats (`fk._place_root`): the armature's translation,
    # W^-1's rows and `pelvis_at`, as lists
    one_root: tuple = field(init=False, repr=False)
    # one frame of a turned armature posed in its turned space (`fk.posed`: P' = W P, H' = W H):
    # `one_root` with W W^-1 for W^-1, and the joints' `to_world` factor W^-1 folded in, W lin^T
    turned_one: TurnedOne = field(init=False, repr=False)

    def __post_init__(self):
        self.shift, self.lin_t, self.inv_t = self.world[:3, 3], self.world[:3, :3].T, self.w_inv.T
        self.w_identity = bool(np.allclose(self.w_rot, np.eye(3), atol=EPS))
        self.bone_rows = _bone_rows(self)
        self.pelvis_at = self._pelvis_local()
        self.one_root = (self.shift.tolist(), self.w_inv.tolist(), self.pelvis_at.tolist())
        self.turned_one = TurnedOne((self.shift.tolist(), (self.w_rot @ self.w_inv).tolist(), self.pelvis_at.tolist()),
                                    self.w_rot @ self.lin_t)
        b = self.joint_bone[JI["spine_root"]]
        p = self.parent[b]
        self.start_rel = self.rest[p].T @ self.rest[b] if p >= 0 else None
        self.chain = ChainPlan.of(self)
        self.basis_plan = BasisPlan.of(self.parent, self.rest, self.head, self.root)
        self.carrier_rel = self.rest[self.carrier].swapaxes(-1, -2) @ self.w_rot.T @ self.frames0
        self.joint_groups = _joint_groups(self.joint_bone, self.joint_local)
        self.joint_table = _joint_table(self.joint_groups)
        bones, local, order = self.joint_table
        width = local.shape[-1]
        g, kk = np.divmod(order, width)  # joint j: carrier row g, padded column kk
        jrows = ((g * 3)[:, None] + np.arange(3)) * width + kk[:, None]  # (J, 3) into (G, 1, 3, K)
        self.one_joints = (bones, local[:, None], jrows)
        # the caches, keyed by value (bone subsets, joint names, canonical bone sets)
        self._pose_plans: dict = {}
        self._joint_plans: dict = {}
        self._realised: dict = {}
        self._realised_one: dict = {}
        self._chain_one: ChainOneFrame | None = None

    @classmethod
    def from_model(cls, model: BodyModel):
        """The plan of an avatar body model's rig (`extra["rig"]`, written by the avatar
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
        w_inv = np.linalg.inv(world[:3, :3])
        bm = naming.BoneMap.from_dict(rig.get("bone_map", {}))
        driver, chain = _drivers(rig["bones"], names, idx, bm, src)
        root = idx[bm.bones.get("pelvis")]
        pos = complete_joints(model)
        joint_world = np.stack([pos[j] for j in JOINTS])
        drv_bone = {BONES[c].name: i for i, c in enumerate(driver) if isinstance(c, (int, np.integer))}
        arm = _to_armature(world, w_inv)
        joint_bone, joint_local = _ride_joints(model, names, head, tail, rest, root, arm(joint_world), idx,
                                               chain, drv_bone)
        spine_rest = arm(np.stack([pos[j] for j in SPINE_JOINTS]))
        chain_s, chain_aim, chain_off, chain_vertebra = _aim_chains(names, parent, head, tail, rest, idx, chain,
                                                                    bm.bones.get("head"), spine_rest)
        return cls(model, str(rig.get("armature", model.name)), names, parent, head, tail, rest, world, w_rot,
                   w_scale, w_inv, root, driver, chain_s, chain_aim, chain_off, chain_vertebra, joint_world,
                   joint_bone, joint_local, model_rest_frames(model, pos),
                   np.array([np.linalg.norm(pos[b.tail] - pos[b.head]) for b in BONES]),
                   _carry_frames(drv_bone, joint_bone, root))

    def __getstate__(self) -> dict:
        """A pickled plan leaves its one-frame chain aim behind (mathutils objects do not pickle);
        it is made again on the next one-frame pose."""
        state = dict(self.__dict__)
        state["_chain_one"] = None
        return state

    # --- coordinates ----------------------------------------------------------------------------

    def to_armature(self, p):
        p = np.asarray(p, float) - self.shift
        return (p.reshape(-1, 3) @ self.inv_t).reshape(p.shape)

    def to_world(self, p):
        p = np.asarray(p, float)  # one BLAS call on (N, 3) rows (einsum is several times slower)
        out = p.reshape(-1, 3) @ self.lin_t
        out += self.shift  # in place (the same sum)
        return out.reshape(p.shape)

    def joint_world_arm(self, j):
        return self.to_armature(self.joint_world[j])

    @property
    def bone_index(self) -> dict[str, int]:
        return {n: i for i, n in enumerate(self.names)}

    def from_world(self, m):
        """W^-1 m for a stack of 3x3 matrices (the armature's rotation is usually the identity)."""
        return m if self.w_identity else mul_stack(self.w_rot.T, m)

    def to_world_rot(self, m):
        """W m for a stack of 3x3 matrices."""
        return m if self.w_identity else mul_stack(self.w_rot, m)

    # --- the plans of a bone subset, a joint list, a realised set (once each, keyed by value) ---

    def pose_plan(self, bones: tuple | None) -> PosePlan:
        """`pose_plan.build_pose_plan` of `bones` (ascending; None: all), once per subset."""
        plan = self._pose_plans.get(bones)
        if plan is None:
            plan = self._pose_plans[bones] = build_pose_plan(self, bones)
        return plan

    def joints_plan(self, joints: tuple[str, ...]) -> tuple:
        """(the bones posed for `joints`: their carriers and ancestors, and the chain's inputs when
        a chain bone is among them; the joints' carriers; their offsets), once per joint list."""
        plan = self._joint_plans.get(joints)
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
            plan = self._joint_plans[joints] = (tuple(sorted(need)), self.joint_bone[jidx], self.joint_local[jidx])
        return plan

    def realised_rows(self, realised) -> tuple:
        """(the canonical bones realised (True: all; a list of indices), their carriers' fixed factors,
        their carriers, the bones not realised), once per set."""
        key = "all" if realised is True else tuple(realised)  # numpy's integers hash as Python's
        rows = self._realised.get(key)
        if rows is None:
            idx = np.arange(len(BONES)) if realised is True else np.asarray(realised, int)
            rows = self._realised[key] = (idx, self.carrier_rel[idx], self.carrier[idx],
                                          np.setdiff1d(np.arange(len(BONES)), idx))
        return rows

    def realised_one(self, realised) -> np.ndarray:
        """Per realised set (True or a list of canonical bone indices), once: each canonical bone's
        row in `fk.finish_one`'s realised stack (its index among the realised, else the NaN row
        after them)."""
        key = realised is True or tuple(realised)
        rows = self._realised_one.get(key)
        if rows is None:
            idx = self.realised_rows(realised)[0]
            rows = np.full(len(BONES), len(idx), int)
            rows[idx] = np.arange(len(idx))
            self._realised_one[key] = rows
        return rows

    def chain_one(self) -> ChainOneFrame:
        """The spine chain's one-frame aim (mathutils constants), made on the first one-frame pose."""
        if self._chain_one is None:
            self._chain_one = ChainOneFrame(self)
        return self._chain_one

    def _pelvis_local(self) -> np.ndarray:
        if self.joint_bone[JI["pelvis"]] != self.root:
            return self.rest[self.root].T @ (self.joint_world_arm(JI["pelvis"]) - self.head[self.root])
        return self.joint_local[JI["pelvis"]]


# --- construction ---------------------------------------------------------------------------------


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


def _to_armature(world: np.ndarray, w_inv: np.ndarray):
    """`RigPlan.to_armature` before the plan exists (the same products)."""
    def arm(p):
        p = np.asarray(p, float) - world[:3, 3]
        return (p.reshape(-1, 3) @ w_inv.T).reshape(p.shape)
    return arm


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


def _ride_joints(model: BodyModel, names, head, tail, rest, root: int, arm_pts, idx: dict[str, int],
                 chain: list[str], drv_bone: dict[str, int]) -> tuple[np.ndarray, np.ndarray]:
    """(`joint_bone`, `joint_local`) of the joints at `arm_pts` (armature space). A joint rides
    on the model's choice of bone, else the bone driven by a canonical bone that starts (then
    ends) at the joint, else (a vertebra) the nearest chain bone, else the pelvis bone."""
    jb = np.empty(len(JOINTS), int)
    for j, name in enumerate(JOINTS):
        frame = model.joints[name].frame if name in model.joints else None
        if frame in idx:
            jb[j] = idx[frame]
            continue
        cands = [drv_bone[b.name] for b in BONES if b.head == name and b.name in drv_bone]
        cands += [drv_bone[b.name] for b in BONES if b.tail == name and b.name in drv_bone]
        if not cands and chain:  # a vertebra: the chain bone nearest to it
            segs = [(np.linalg.norm(_closest_on_segment(arm_pts[j], head[idx[c]], tail[idx[c]]) - arm_pts[j]),
                     idx[c]) for c in chain]
            cands = [min(segs)[1]]
        jb[j] = cands[0] if cands else root
    return jb, np.einsum("jba,jb->ja", rest[jb], arm_pts - head[jb])


def _carry_frames(drv_bone: dict[str, int], joint_bone: np.ndarray, root: int) -> np.ndarray:
    """`carrier`: a canonical frame rides on the avatar bone it drives, else (vertebrae, shortcuts)
    on its head joint's bone, else on its parent's carrier."""
    car = np.empty(len(BONES), int)
    for i, b in enumerate(BONES):
        if b.name in drv_bone:
            car[i] = drv_bone[b.name]
        elif b.name in SPINE_BONES or b.name.startswith("shortcut_"):
            car[i] = joint_bone[JI[b.head]]
        elif b.parent is not None:
            car[i] = car[BI[b.parent]]
        else:
            car[i] = root
    return car


def _aim_chains(names, parent, head, tail, rest, idx: dict[str, int], chain: list[str], head_bone: str | None,
                spine_rest: np.ndarray) -> tuple:
    """(`chain_s`, `chain_aim`, `chain_off`, `chain_vertebra`), zero for bones off the chain. Chain
    bones aim their "aim point" at the canonical spine curve (`spine_rest`, armature space, at
    rest): the head of their child up the spine (chain bone or `head_bone`) when they have one (rig
    chains need not be connected: a tail may sit off the spine), else their tail; its arc position
    on the rest curve and its place in the bone's rest frame (so the rest pose aims at itself).
    Twist: the canonical vertebra at the bone's middle."""
    chain_s = np.zeros(len(names))
    chain_aim = np.zeros((len(names), 3))
    chain_off = np.zeros((len(names), 3))
    chain_vertebra = np.zeros(len(names), int)
    up_spine = set(chain) | {head_bone}
    for c in chain:
        i = idx[c]
        kids = [j for j in range(len(names)) if parent[j] == i and names[j] in up_spine]
        aim = head[kids[0]] if kids else tail[i]
        s_t = arc_param(spine_rest, aim)
        s_h = arc_param(spine_rest, head[i])
        chain_s[i] = s_t
        chain_aim[i] = rest[i].T @ (aim - head[i])
        # where the aim point sits off the curve, carried by the vertebra: the rest pose aims at itself
        chain_off[i] = aim - curve_point(spine_rest[None], s_t)[0]
        chain_vertebra[i] = int(np.clip(np.floor(0.5 * (s_t + s_h)), 0, sk.SPINE_COUNT - 1))
    return chain_s, chain_aim, chain_off, chain_vertebra


def _bone_rows(rig: RigPlan) -> list[tuple]:
    """`RigPlan.bone_rows`."""
    rows = []
    for i, (p, drv) in enumerate(zip(rig.parent, rig.driver)):
        offset = rig.rest[p].T @ (rig.head[i] - rig.head[p]) if p >= 0 else None
        if isinstance(drv, (int, np.integer)):
            fixed = rig.frames0[drv].T @ rig.w_rot @ rig.rest[i]
        elif drv is None and p >= 0:
            fixed = rig.rest[p].T @ rig.rest[i]
        else:
            fixed = None
        rows.append((int(p), drv, offset, fixed))
    return rows


def _joint_groups(joint_bone: np.ndarray, joint_local: np.ndarray) -> list[tuple]:
    """`RigPlan.joint_groups`."""
    by_count: dict[int, list] = {}
    for b in np.unique(joint_bone):
        js = np.flatnonzero(joint_bone == b)
        by_count.setdefault(len(js), []).append((int(b), js))
    return [(np.array([b for b, _ in g], int), np.stack([js for _, js in g]),
             np.stack([joint_local[js].T for _, js in g])) for _, g in sorted(by_count.items())]


def _joint_table(groups: list[tuple]) -> tuple:
    """`RigPlan.joint_table`."""
    width = max(js.shape[1] for _, js, _ in groups)
    bones = np.concatenate([b for b, _, _ in groups])
    local = np.zeros((len(bones), 3, width))
    order = np.zeros(len(JOINTS), int)
    g0 = 0
    for b, js, loc in groups:
        local[g0:g0 + len(b), :, :js.shape[1]] = loc
        order[js] = (g0 + np.arange(len(b)))[:, None] * width + np.arange(js.shape[1])
        g0 += len(b)
    return bones, local, order


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
