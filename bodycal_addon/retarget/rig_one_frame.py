"""The spine chain of ONE frame aimed in mathutils (`core/one_frame.py`; DESIGN.md "Prepared solver"):
the chain's bones aim one at a time (each at its point of the canonical spine curve, from its head,
which hangs from the one before), so the numpy path poses a frame's rig level by level up to them,
several numpy calls a level on one or two bones. Here the few bones the aims read (the chain, the
bone the spine curve starts on and their ancestors) are posed bone by bone on single matrices, the
aimed rotations handed back, and the rest of the rig is posed in numpy's few passes over all its
bones (`rig/fk.py` `pose_flat`), as it is when a chain's rotations are held.

Per bone, parents first (the rig's bone order): its head H_b = H_p + P_p o_b (a parentless bone at
its rest head; the root bone placed from the pelvis once posed), then its rotation: driven,
W^-1 C_c (C_c0^-1 W M_A); following its parent, P_p (M_p^-1 M_A); parentless and undriven, M_A;
a chain bone, its vertebra's twist turned to aim at the curve (`rig/chain.py` `ChainAim`'s steps).
The values are the numpy path's to float32's rounding (mathutils' precision: one_frame.py).
A turned armature's are posed in its turned space, W P and W H (`rig/plan.py` `TurnedOne`): the
canonical frames taken as they are (no W^-1 C), the rest matrices, loose heads and the maps
between positions and the armature turned once here; the aimed rotations handed back are W R.

Decision (speed, measured in instructions): only the chain is aimed here. A whole rig pose of one
frame in mathutils (bone by bone: 53 bones, their quaternions and 72 joints) took 1.71 M
instructions against numpy's 0.72 M: a mathutils operation costs 1,100-1,700 instructions and
making a Matrix from a list 3,200, where numpy's stacked products over every bone of a level cost
5,000-10,000 a call whatever the count of bones."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..body.skeleton import BONE_INDEX as BI
from ..body.skeleton import JOINT_INDEX as JI
from ..body.skeleton import SPINE_BONES
from ..core import one_frame
from ..core.one_frame import Matrix, Vector

# How a bone's head and rotation are placed (`_Plan.steps`); UNUSED: a joint's carrier whose
# rotation nothing reads (the joint at its head, no bone posed from it)
HANG, LOOSE, ROOT = 0, 1, 2
DRIVEN, FOLLOW, REST, CHAIN, UNUSED = 0, 1, 2, 3, 4


@dataclass
class _Plan:
    """Per rig and joint list, once: the canonical bones read (`canon`: their rows in the frames),
    per bone, in order, (bone, parent, head kind, its constant, rotation kind, its constant), and
    per joint its carrier and its offset on it (None: at the carrier's head)."""

    canon: np.ndarray
    steps: list
    joints: list


class _Turn:
    """W @ m for the armature's rotation W, m itself where the armature is not turned (the same
    bits as before it was turned)."""

    def __init__(self, w_rot):
        self.w_rot = w_rot

    def __matmul__(self, m):
        return m if self.w_rot is None else self.w_rot @ m


class ChainOneFrame:
    """One rig's spine chain aimed for one frame: its constants as mathutils objects, made once
    (`RigPlan.chain_one`)."""

    def __init__(self, rig):
        self.rig = rig
        self.root = rig.root
        # a turned armature is posed in its turned space (W P, W H): its constants turned by W
        self.turn = turn = _Turn(None if rig.w_identity else rig.w_rot)
        self.shift = Vector(rig.world[:3, 3].tolist())
        self.inv = Matrix((turn @ rig.w_inv).tolist())
        self.pelvis_at = Vector(rig.pelvis_at.tolist())
        ch = rig.chain
        self.chain = ch
        self.chain_row = dict(ch.index)
        self.chain_fixed = one_frame.matrices(ch.fixed)
        self.chain_rest = one_frame.matrices(ch.rest)
        self.chain_aim = one_frame.vectors(ch.aim)
        self.chain_off = one_frame.vectors(ch.off)
        self.chain_w = list(zip(ch.w0[:, 0, 0].tolist(), ch.w1[:, 0, 0].tolist(), ch.k.tolist()))
        j0 = JI["spine_root"]
        b = self.curve_bone = int(rig.joint_bone[j0])
        self.curve_local = Vector(rig.joint_local[j0].tolist())
        p = int(rig.parent[b])
        self.curve_start = Matrix((turn @ rig.rest[b] if p < 0 else rig.rest[p].T @ rig.rest[b]).tolist())
        spine_rows = np.array([BI[n] for n in SPINE_BONES], int)
        # the vertebrae's +Y entries in a frame's flat (B 3 3) row-major entries, their lengths
        self.spine_y = (spine_rows[:, None] * 9 + np.array([1, 4, 7])).ravel()
        self.spine_len = rig.lengths[spine_rows][:, None]
        self.w_inv_m = Matrix((turn @ rig.w_inv).tolist())
        # per chain bone, its target's curve points k, k + 1 as rows of the running sum (-1: the
        # curve's start, no step yet) and their weights
        self.chain_pick = [(int(k) - 1, int(k), float(w0), float(w1)) for w0, w1, k in
                           zip(ch.w0[:, 0, 0].tolist(), ch.w1[:, 0, 0].tolist(), ch.k.tolist())]
        self.lin = Matrix((turn @ rig.lin_t).T.tolist())  # the armature's linear part (turned positions to the world)
        self.plans = {}

    def _plan(self, joints: tuple) -> _Plan:
        """The steps posing the bones the aims read (the chain, the bone the spine curve starts on,
        their ancestors) and those the canonical `joints` ride on (with theirs), in order, and the
        canonical bones they read."""
        rig, rows = self.rig, self.rig.bone_rows
        need: set[int] = set()

        def with_ancestors(bones):
            for b in bones:
                while b >= 0 and b not in need:
                    need.add(b)
                    b = int(rig.parent[b])

        with_ancestors([int(i) for i in self.chain.order] + [self.curve_bone])
        carried = [(int(rig.joint_bone[JI[j]]), rig.joint_local[JI[j]]) for j in joints]
        # a rotation is read by the aims, by a child's head, or by a joint off its carrier's head
        rotated = set(need) | {c for c, off in carried if np.any(off)}
        with_ancestors([c for c, _ in carried])
        rotated |= {int(rig.parent[b]) for b in need}
        canon: list[int] = []

        def slot(c: int) -> int:
            if c not in canon:
                canon.append(c)
            return canon.index(c)

        steps = []
        for b in sorted(need):
            p, drv, off, fixed = rows[b]
            if b == rig.root:
                hk, hv = ROOT, None
            elif p >= 0:
                hk, hv = HANG, Vector(off.tolist())
            else:
                hk, hv = LOOSE, Vector((self.turn @ rig.head[b]).tolist())
            if b not in rotated:
                rk, rv = UNUSED, None
            elif isinstance(drv, (int, np.integer)):
                rk, rv = DRIVEN, (slot(int(drv)), Matrix(fixed.tolist()))
            elif drv == "chain":
                rk, rv = CHAIN, self.chain_row[b]
            elif p >= 0:
                rk, rv = FOLLOW, Matrix(fixed.tolist())
            else:
                rk, rv = REST, Matrix((self.turn @ rig.rest[b]).tolist())
            steps.append((b, int(p), hk, hv, rk, rv))
        for v in self.chain.vertebra.tolist():
            slot(int(v))
        return _Plan(np.array(canon, int), steps,
                     [(c, Vector(off.tolist()) if np.any(off) else None) for c, off in carried])

    def aimed(self, frames: np.ndarray, pelvis: np.ndarray) -> np.ndarray:
        """The chain bones' armature-space rotations (n, 1, 3, 3) (a turned armature's turned,
        W R), by their rows in the chain plan, of canonical world frames (1, B, 3, 3) with the
        pelvis joint at `pelvis` (1, 3)."""
        return self.aimed_and_joints(frames, pelvis, ())[0]

    def aimed_and_joints(self, frames: np.ndarray, pelvis: np.ndarray, joints: tuple) -> tuple:
        """(`aimed`'s rotations, the world positions (1, K, 3) of the canonical `joints` (names)
        in the same pose): the bones they ride on posed in the same bone-by-bone pass as the
        chain's (a live frame's limb roots, `fk.joint_positions`, in the pass the chain needs
        anyway, instead of a numpy pose of the trunk after it)."""
        plan = self.plans.get(joints)
        if plan is None:
            plan = self.plans[joints] = self._plan(joints)
        C = [Matrix(m) for m in frames[0].take(plan.canon, axis=0).tolist()]  # (turned: no W^-1 C)
        P, H = {}, {}
        aim = _Aim(self, C, plan, frames)
        at = self.inv @ (Vector(pelvis[0].tolist()) - self.shift)
        for b, p, hk, hv, rk, rv in plan.steps:
            if hk == HANG:
                H[b] = H[p] + P[p] @ hv
            elif hk == LOOSE:
                H[b] = hv
            if rk == DRIVEN:
                P[b] = C[rv[0]] @ rv[1]
            elif rk == FOLLOW:
                P[b] = P[p] @ rv
            elif rk == REST:
                P[b] = rv
            elif rk == CHAIN:
                P[b] = aim.bone(b, rv, P, H)
            if hk == ROOT:
                H[b] = at - P[b] @ self.pelvis_at
        aimed = one_frame.matrix_array(aim.aimed)[:, None]
        if not plan.joints:  # `aimed`'s (making an empty array of no joints cost 9,000 instructions)
            return aimed, _NO_JOINTS
        at_joints = [self.lin @ (H[c] if off is None else H[c] + P[c] @ off) + self.shift for c, off in plan.joints]
        return aimed, one_frame.vector_array(at_joints)[None]


_NO_JOINTS = np.empty((1, 0, 3))
_NO_JOINTS.setflags(write=False)


class _Aim:
    """The spine chain aimed one bone at a time (`rig/chain.py` `ChainAim`): each bone's vertebra's
    turn since rest and twist, its aim point, its target on the canonical spine curve (built once
    the bone it starts on is posed), the shortest turn from one to the other."""

    def __init__(self, one: ChainOneFrame, C: list, plan: _Plan, frames):
        self.one, self.frames = one, frames
        pos = {c: k for k, c in enumerate(plan.canon.tolist())}
        # C_v (C_v0^-1 W) (W times the vertebra's turn since rest W^-1 C_v C_v0^-1 W, the turned
        # space's; unturned, W = I), the twist, the aim point, its target's offset
        self.delta = [C[pos[v]] @ f for v, f in zip(one.chain.vertebra.tolist(), one.chain_fixed)]
        self.twist = [d @ r for d, r in zip(self.delta, one.chain_rest)]
        self.aim = [t @ a for t, a in zip(self.twist, one.chain_aim)]
        self.off = [d @ o for d, o in zip(self.delta, one.chain_off)]
        self.target = None
        self.aimed = [None] * len(self.delta)

    def _targets(self, P, H) -> None:
        """The canonical spine curve (`rig/chain.py` `spine_curve`: its start on the bone it starts
        on, then the vertebrae's +Y times their lengths in armature units) at each bone's arc
        position, and each bone's target. The running sum of the steps in float64 numpy (the
        world's steps, W^-1 after the weighting: a linear map, the same curve), only the points
        the targets read made Vectors. Decision (speed, measured in instructions): the curve of
        twelve Vector additions and its steps' numpy products took 91,000 instructions a frame."""
        one = self.one
        b = one.curve_bone
        if one.rig.driver[b] == "chain":  # not posed yet: oriented as at rest under its parent
            p = int(one.rig.parent[b])
            rot = one.curve_start if p < 0 else P[p] @ one.curve_start
        else:
            rot = P[b]
        start = H[b] + rot @ one.curve_local
        sums = np.cumsum(self.frames.reshape(-1).take(one.spine_y).reshape(-1, 3) * one.spine_len, axis=0).tolist()
        zero = [0.0, 0.0, 0.0]
        self.target = []
        for (k0, k1, w0, w1), off in zip(one.chain_pick, self.off):
            a = sums[k0] if k0 >= 0 else zero
            c = sums[k1]
            step = Vector([a[0] * w0 + c[0] * w1, a[1] * w0 + c[1] * w1, a[2] * w0 + c[2] * w1])
            self.target.append(start + one.w_inv_m @ step + off)

    def bone(self, b: int, j: int, P, H):
        if self.target is None:
            self._targets(P, H)
        turn = self.aim[j].rotation_difference(self.target[j] - H[b]).to_matrix()
        self.aimed[j] = turn @ self.twist[j]
        return self.aimed[j]
