"""Forward kinematics over frames (DESIGN.md §1, "The rig posed"; "Prepared solver"): the rig's pose from
canonical bone frames (`pose`: armature-space rotations P and heads H, bones first), the canonical
joints and frames the pose realises (`finish`), and Blender's pose evaluation from pose-bone
quaternions (`evaluate`). Every function reads a frame-independent `RigPlan`; the only state a pose
leaves is the spine chain's `ChainMemo`, passed in by its owner (`AvatarRig`).

Each avatar bone is either driven by one canonical bone c: it moves rigidly with it,
P_A(t) = W^-1 C_c(t) C_c0^-1 W M_A; a spine/neck chain bone (`chain.py`); or undriven (root, toes,
breasts, ...): it follows its parent (identity basis). Canonical joints ride on avatar bones
(`joint_bone` + `joint_local`), so the joints returned are exactly what Blender's FK gives for the
returned rotations."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...body.skeleton import BONES, JOINTS
from ...core import one_frame
from ...core.transforms import (
    STACKED_FRAMES,
    mul_stack,
    quat_to_matrix,
    stack_apply,
    stack_mul,
    stacks_apply,
    stacks_mul,
)
from .. import pose_kernels
from .chain import ChainAim, ChainMemo
from .plan import RigPlan
from .pose_plan import PosePlan


@dataclass
class RigPose:
    basis: np.ndarray  # (F, N, 4) pose-bone rotation_quaternion (matrix_basis), w x y z
    rotations: np.ndarray  # (F, N, 3, 3) armature-space pose rotations P
    heads: np.ndarray  # (F, N, 3) armature-space pose heads
    root_location: np.ndarray  # (F, 3) pose-bone location of the root bone (its rest frame)
    joints: np.ndarray  # (F, J, 3) canonical joints, world
    frames: np.ndarray  # (F, B, 3, 3) canonical bone frames, world, as the rig realises them

    @classmethod
    def turned(cls, w_rot: np.ndarray, basis, P, H, root_location, joints, frames) -> RigPose:
        """The pose of one frame posed in the turned armature's space (`posed`: P' = W P,
        H' = W H): its armature-space `rotations` and `heads` are made when first read (a
        solve reads the joints, frames and basis only)."""
        pose = cls.__new__(cls)
        pose.basis, pose.root_location, pose.joints, pose.frames = basis, root_location, joints, frames
        pose._turned = (w_rot, P, H)
        return pose

    def __getattr__(self, name):  # only for the fields a turned pose makes when read
        turned = self.__dict__.get("_turned")
        if turned is None or name not in ("rotations", "heads"):
            raise AttributeError(name)
        w_rot, P, H = turned
        self.rotations = np.matmul(w_rot.T, P).swapaxes(0, 1)  # W^-1 P'
        self.heads = (H @ w_rot).swapaxes(0, 1)  # W^-1 H' (rows)
        del self._turned
        return getattr(self, name)


# Poses of fewer frames than this place the heads the spine chain does not read in one padded
# pass after the levels (PosePlan.deferred: a few numpy calls instead of a few per level, where
# the per-call overhead is the cost); longer ones level by level. The same sums in the same order.
# Measured (bench_instructions' take, one-frame solves): these paths save 247,000 instructions of a
# rotations frame's 4.15 M and 995,000 of an egocentric one's 18.95 M.
FEW_FRAMES = 16


def pose(rig: RigPlan, memo: ChainMemo, frames, pelvis, bones=None, float64=False):
    """`posed`'s rotations and heads in the armature's space."""
    P, H, turned, _ = posed(rig, memo, frames, pelvis, bones, float64)
    if turned:  # W^-1 P', W^-1 H'
        return np.matmul(rig.w_rot.T, P), H @ rig.w_rot
    return P, H


def posed(rig: RigPlan, memo: ChainMemo, frames, pelvis, bones=None, float64=False):
    """Bones-first armature-space pose rotations P (N, F, 3, 3) and heads H (N, F, 3) of
    `bones` (ascending; default all, the others left unset) realising canonical world frames
    (F, B, 3, 3) with the canonical pelvis joint at `pelvis` (F, 3, world), a depth of the
    hierarchy at a time (`pose_plan`): each step is one stacked product over the bones of that
    depth. The chain's rotations are `memo`'s when its inputs are the last pose's (`ChainMemo`);
    one frame's chain is aimed in mathutils (float32, `rig_one_frame`) unless `float64`.
    Returns (P, H, turned, joints): turned, one frame of a turned armature posed in its turned
    space, P' = W P and H' = W H (`plan.TurnedOne`), which `finish`, `basis.solve` and
    `basis.root_location` take as they are; joints, one frame's canonical joints' offsets on
    their carriers P_car o_j (J, 1, 3), turned in the heads' product (`PosePlan.flat_joints`;
    else None), which `finish` adds to the carriers' heads."""
    nf = frames.shape[0]
    plan = rig.pose_plan(None if bones is None else tuple(bones))
    chain = rig.chain if plan.chained else None
    float32 = chain is not None and nf == 1 and one_frame.ENABLED and not float64
    key = held = None
    if chain is not None:
        key = ChainMemo.key_of(chain, frames, pelvis, b"float32" if float32 else b"")
        held = memo.held(key)
    if held is None and float32:
        # one frame: the chain aimed in mathutils (rig_one_frame.py), the rest in one flat pass
        held = rig.chain_one().aimed(frames, np.asarray(pelvis, float))
        memo.keep(key, held)
    few = plan.deferred is not None and nf < FEW_FRAMES
    flat = few and (chain is None or held is not None)
    turned = flat and nf == 1 and not rig.w_identity and (chain is None or float32)
    if float32 and held is not None and not turned and not rig.w_identity:
        held = np.matmul(rig.w_rot.T, held)  # the one-frame chain's turned rotations, W^-1 R'
    joints = plan.flat_joints if flat and nf == 1 else None
    P, H, HT = _pose_buffers(len(rig.names), plan, nf, few, flat, joints)
    delta = _driven(rig, plan, chain if chain is not None and held is None else None, frames, P, turned)
    aiming = None if delta is None else ChainAim(rig, delta, frames, nf)
    if flat:
        P, H = pose_flat(rig, plan, None if chain is None else chain.rows, held, P, H, pelvis, HT, turned, joints)
        return P, H, turned, None if joints is None else HT[joints[4]]
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
            _place_root(rig, P, H, pelvis)
    if few:
        _deferred_heads(plan.deferred, P, H, HT)
    if aiming is not None and aiming.count == len(chain.index):
        memo.keep(key, aiming.aimed)
    return P, H, False, None


def _pose_buffers(n: int, plan: PosePlan, nf: int, few: bool, flat: bool, joints=None) -> tuple:
    """(P, H, HT): a few frames' heads H are the first rows of HT, whose rows after them take
    the one padded pass's offsets and its zero (`_deferred_heads`: no concatenated copy of H);
    with `joints` (`PosePlan.flat_joints`), the joints' offsets' terms too."""
    P = np.empty((n, nf, 3, 3))
    if joints is not None:
        HT = np.empty((joints[-1], nf, 3))
        HT[-1] = 0.0
        return P, HT[:n], HT
    if few and nf < STACKED_FRAMES:
        late = (plan.flat if flat else plan.deferred)[-5]
        HT = np.empty((n + len(late) + 1, nf, 3))
        HT[-1] = 0.0
        return P, HT[:n], HT
    return P, np.empty((n, nf, 3)), None


def _driven(rig: RigPlan, plan: PosePlan, chain, frames, P, turned=False):
    """The driven bones' rotations into P, W^-1 C(t) (C0^-1 W M_A) (the canonical bone's rotation
    since rest, on the bone's rest; `turned`: C(t) (C0^-1 W M_A), no W^-1), and with a `chain` to
    aim, its vertebrae's turns since rest W^-1 C(t) C0^-1 W (returned; else None)."""
    nf = frames.shape[0]
    delta = None
    if chain is not None and nf < STACKED_FRAMES and len(plan.driven):
        # A few frames: the driven bones' and the chain vertebrae's products in one stacked
        # product (each its own BLAS call either way, so the same bits)
        rows, fixed = plan.driven_and_chain
        both = pose_kernels.few_matmul(frames.swapaxes(0, 1).take(rows, axis=0), fixed, (len(rows), nf, 3, 3))
        if not rig.w_identity:  # `from_world`'s W^-1 of them all, one product
            both = pose_kernels.few_matmul(rig.w_rot.T, both, both.shape)
        P[plan.driven_rows] = both[:len(plan.driven)]
        return both[len(plan.driven):]
    if nf >= STACKED_FRAMES and rig.w_identity:
        # Many frames: each driven bone's product written where it goes (`stacks_mul`'s BLAS
        # call bone by bone, without its stack to copy into P)
        for b, c, fixed in zip(plan.driven.tolist(), plan.canon.tolist(), plan.fixed):
            np.matmul(frames[:, c].reshape(-1, 3), fixed, out=P[b].reshape(-1, 3))
    elif len(plan.driven) and nf < STACKED_FRAMES:  # `stacks_mul`'s stacked product, called directly
        rel = pose_kernels.few_matmul(frames.swapaxes(0, 1).take(plan.canon, axis=0), plan.fixed[:, None],
                                      (len(plan.canon), nf, 3, 3))
        P[plan.driven_rows] = rel if rig.w_identity or turned else pose_kernels.few_matmul(rig.w_rot.T, rel, rel.shape)
    elif len(plan.driven):
        P[plan.driven] = rig.from_world(stacks_mul(frames.swapaxes(0, 1), plan.fixed, plan.canon))
    if chain is not None:
        delta = rig.from_world(stacks_mul(frames.swapaxes(0, 1), chain.fixed, chain.vertebra))
    return delta


def _place_root(rig: RigPlan, P, H, pelvis, turned=False) -> None:
    """H_root = W^-1 (pelvis - t) - P_root pelvis_local: `to_armature` and `stack_apply`'s
    products, called directly. One frame's in Python floats: the same terms in the same order
    (three numpy products on a (1, 3) row cost about 40,000 instructions, these about a fifth);
    `turned`, W H_root, W W^-1 (`RigPlan.turned_one`'s) in place of W^-1."""
    nf = P.shape[1]
    if nf == 1:
        shift, rows, (r0, r1, r2) = rig.turned_one.root if turned else rig.one_root
        d = [a - b for a, b in zip(np.ravel(pelvis).tolist(), shift)]
        at = [(d[0] * c0 + d[1] * c1) + d[2] * c2 for c0, c1, c2 in rows]
        H[rig.root, 0] = [a - ((r[0] * r0 + r[1] * r1) + r[2] * r2) for a, r in zip(at, P[rig.root, 0].tolist())]
        return
    at = (np.asarray(pelvis, float) - rig.shift).reshape(-1, 3) @ rig.inv_t
    np.subtract(at.reshape(nf, 3), (P[rig.root].reshape(-1, 3) @ rig.pelvis_at).reshape(nf, 3), out=H[rig.root])


def _deferred_heads(table_plan, P, H, HT) -> None:
    """The heads of `table_plan` (rows, parents, offsets, the padded sum table, where they go) in
    one padded pass: each its anchor's head plus the offsets down its path, in order. A few
    frames' (HT: H with rows after it) take their offsets' products written after H and a zero
    row; consecutive rows take their sums in place."""
    late, par, off, table, at = table_plan
    if HT is None:
        terms = np.concatenate([H, stacks_apply(P, off, par), np.zeros((1,) + H.shape[1:])])
    else:
        n = len(H)
        np.matmul(P.take(par, axis=0), off[:, None, :, None], out=HT[n:-1].reshape(len(late), -1, 3, 1))
        terms = HT
    if isinstance(at, slice):  # over the path, in order
        np.add.reduce(terms.take(table, axis=0), axis=0, out=H[at])
    else:
        H[at] = np.add.reduce(terms.take(table, axis=0), axis=0)


def pose_flat(rig: RigPlan, plan: PosePlan, chain_bones, held, P, H, pelvis, HT=None, turned=False, joints=None):
    """`pose`'s few frames whose chain needs no aiming, the driven bones posed: every other
    rotation, then every head in one padded pass. Decision (speed, the same values): a solve's
    later poses hold the chain's rotations, so nothing is aimed level by level; each head is
    the same sum in the same order as level by level, (H_anchor + c_1) + c_2 + ... `turned`:
    one frame in the turned armature's space (`posed`), the rest bones and loose heads turned.
    `joints` (one frame, `PosePlan.flat_joints`): the canonical joints' offsets on their carriers
    turned in the heads' product (`posed`)."""
    rest, rest_at, loose, loose_at, follows, late, par, off, table, at = plan.flat
    if turned:
        rest_at, loose_at = plan.flat_turned
    if len(rest_at):
        P[rest] = rest_at
    if chain_bones is not None:
        P[chain_bones] = held
    for bones_f, par_f, fixed_f in follows:
        if P.shape[1] < STACKED_FRAMES:  # `stacks_mul`'s stacked product, called directly
            P[bones_f] = np.matmul(P.take(par_f, axis=0), fixed_f[:, None])
        else:
            P[bones_f] = stacks_mul(P, fixed_f, par_f)
    if len(loose_at):
        H[loose] = loose_at
    if plan.has_root:
        _place_root(rig, P, H, pelvis, turned)
    if joints is not None:  # the joints' offsets P_car o_j in the heads' offsets' product
        par, off4, table, at, _, _ = joints
        np.matmul(P.take(par, axis=0), off4, out=HT[len(H):-1].reshape(len(par), -1, 3, 1))
        if isinstance(at, slice):  # over the path, in order (`_deferred_heads`)
            np.add.reduce(HT.take(table, axis=0), axis=0, out=H[at])
        else:
            H[at] = np.add.reduce(HT.take(table, axis=0), axis=0)
        return P, H
    _deferred_heads((late, par, off, table, at), P, H, HT)
    return P, H


def joint_positions(rig: RigPlan, memo: ChainMemo, frames: np.ndarray, pelvis: np.ndarray,
                    joints: list[str]) -> np.ndarray:
    """(F, len(joints), 3) world positions of a few canonical joints for the pose `pose` would
    give, posing only the bones they hang from (the IK's limb roots need the trunk only). One
    frame whose joints hang from the spine chain: placed in the chain's own bone-by-bone pass in
    mathutils (`rig_one_frame`, float32; the chain's rotations kept in `memo` for the pose after),
    aimed again whatever `memo` holds, so a frame's joints never depend on the pose before it.
    Decision (speed, measured in instructions): a one-frame offsets solve's limb roots took
    532,000 instructions (the chain's pass 263,000, then the trunk's numpy pose), 356,000 so."""
    bones, carriers, local = rig.joints_plan(tuple(joints))
    frames = np.asarray(frames, float)
    if len(frames) == 1 and one_frame.ENABLED and rig.pose_plan(bones).chained:
        held, at = rig.chain_one().aimed_and_joints(frames, np.asarray(pelvis, float), tuple(joints))
        memo.keep(ChainMemo.key_of(rig.chain, frames, pelvis, b"float32"), held)
        return at
    P, H, turned, _ = posed(rig, memo, frames, pelvis, bones)
    out = H[carriers] + stacks_apply(P, local, carriers)  # (K, F, 3)
    if turned:  # W^-1 of the turned rows folded into `to_world`'s product
        return (out.reshape(-1, 3) @ rig.turned_one.lin_t + rig.shift).reshape(1, -1, 3)
    return rig.to_world(np.ascontiguousarray(out.swapaxes(0, 1)))


def finish(rig: RigPlan, basis, P, H, root_loc, realised=True, turned=False, joints=None) -> RigPose:
    """The RigPose of bones-first pose rotations P (N, F, 3, 3) and heads H (N, F, 3): the
    canonical joints riding on their bones and the realised canonical frames (True: all, a list
    of canonical bone indices: those, the others NaN; False or None: none). `turned`: one
    frame's P' = W P, H' = W H (`posed`); `joints`: one frame's joints' P_car o_j (`posed`)."""
    nf = P.shape[1]
    if nf == 1:
        return _finish_one(rig, basis, P, H, root_loc, realised, turned, joints)
    if nf < FEW_FRAMES:  # every carrier at once, its joints padded to the most any bone carries
        bones, local, order = rig.joint_table
        rel = stacks_mul(P, local, bones)  # (G, F, 3, K)
        ride = H[bones][:, :, None, :] + rel.swapaxes(-1, -2)  # (G, F, K, 3)
        joints = ride.swapaxes(0, 1).reshape(nf, -1, 3).take(order, axis=1)
    else:
        joints = np.empty((nf, len(JOINTS), 3))
        for bones, js, local in rig.joint_groups:  # the bones carrying K joints each, at once
            rel = stacks_mul(P, local, bones)  # (G, F, 3, K)
            if nf >= STACKED_FRAMES:  # each joint written where it goes, H + P o (no (G, F, K, 3) stack to scatter)
                for g, (b, row) in enumerate(zip(bones.tolist(), js.tolist())):
                    for kk, j in enumerate(row):
                        np.add(H[b], rel[g, :, :, kk], out=joints[:, j])
            else:
                joints[:, js] = (H[bones][:, :, None, :] + rel.swapaxes(-1, -2)).swapaxes(0, 1)
    joints = rig.to_world(joints)
    # C_c(t) = W P_car(t) M_car^-1 W^-1 C_c0
    if realised is False or realised is None:
        frames = None
    else:
        idx, car_rel, car, unrealised = rig.realised_rows(realised)
        frames = np.empty((nf, len(BONES), 3, 3))  # NaN where not realised (written once)
        if len(unrealised):
            frames[:, unrealised] = np.nan
        if len(idx) and nf >= STACKED_FRAMES and rig.w_identity:
            # `stacks_mul`'s product bone by bone into one buffer, copied where it goes (no
            # (K, F, 3, 3) stack to allocate and scatter)
            buf = np.empty((nf, 3, 3))
            for c, b, rel in zip(idx.tolist(), car.tolist(), car_rel):
                np.matmul(P[b].reshape(-1, 3), rel, out=buf.reshape(-1, 3))
                frames[:, c] = buf
        elif len(idx):
            rel = rig.to_world_rot(stacks_mul(P, car_rel, car))
            frames[:, idx] = rel.swapaxes(0, 1)
    return RigPose(basis, P.swapaxes(0, 1), H.swapaxes(0, 1), root_loc, joints, frames)


def _finish_one(rig: RigPlan, basis, P, H, root_loc, realised, turned=False, ride=None) -> RigPose:
    """`finish` of one frame, the same values in fewer numpy calls: the joints' padded product
    (`joint_table`) gathered in one `take` (`one_joints`), their carriers' heads added on the
    gathered (J, 3) rows (a broadcast add over the padded product cost 35,000 instructions),
    the realised frames written into a stack whose last row is NaN and gathered in one `take`.
    `turned` (P' = W P, H' = W H): the joints W^-1's folded into `to_world`'s product, the
    frames W P_car rel = P' rel, no W product. `ride`: the joints' P_car o `posed` turned."""
    if ride is None:
        bones, local, jrows = rig.one_joints
        ride = pose_kernels.few_matmul(P.take(bones, axis=0), local, (len(bones), 1, 3, local.shape[-1]))  # P_car o
        at = ride.take(jrows)  # (J, 3) each joint's P_car o
        at += H.reshape(-1, 3).take(rig.joint_bone, axis=0)  # H + P o (the same sum, on the joints' rows)
    else:
        at = ride.reshape(-1, 3) + H.reshape(-1, 3).take(rig.joint_bone, axis=0)
    joints = np.matmul(at.reshape(-1, 3), rig.turned_one.lin_t if turned else rig.lin_t)  # `to_world` of the rows
    joints += rig.shift
    joints = joints.reshape(1, -1, 3)
    if realised is False or realised is None:
        frames = None
    else:
        idx, car_rel, car, _ = rig.realised_rows(realised)
        rows = np.empty((len(idx) + 1, 1, 3, 3, 2))[..., 0]  # strided: numpy's own loop (pose_kernels.few_matmul)
        rows[-1] = np.nan
        if len(idx):
            if rig.w_identity or turned:
                np.matmul(P.take(car, axis=0), car_rel[:, None], out=rows[:-1])
            else:  # W (P_car rel), `to_world_rot`'s product
                rel = pose_kernels.few_matmul(P.take(car, axis=0), car_rel[:, None], (len(car), 1, 3, 3))
                np.matmul(rig.w_rot, rel, out=rows[:-1])
        frames = rows.take(rig.realised_one(realised), axis=0).reshape(1, len(BONES), 3, 3)
    if turned:
        return RigPose.turned(rig.w_rot, basis, P, H, root_loc, joints, frames)
    return RigPose(basis, P.swapaxes(0, 1), H.swapaxes(0, 1), root_loc, joints, frames)


def evaluate(rig: RigPlan, basis: np.ndarray, root_location: np.ndarray, locations: np.ndarray | None = None
             ) -> tuple[np.ndarray, np.ndarray]:
    """Blender's pose evaluation: bones-first pose rotations P and heads H from pose-bone
    quaternions (F, N, 4) and the root bone's location (F, 3); `locations` (F, N, 3), when given,
    are every bone's pose location (the root's included)."""
    nf, n = basis.shape[:2]
    B = quat_to_matrix(basis).swapaxes(0, 1)
    P = np.empty((n, nf, 3, 3))
    H = np.empty((n, nf, 3))
    zero = np.zeros((nf, 3))
    for i in range(n):
        p = rig.parent[i]
        if locations is not None:
            loc = locations[:, i]
        else:
            loc = root_location if i == rig.root else zero
        if p < 0:
            P[i] = mul_stack(rig.rest[i], B[i])
            H[i] = rig.head[i] + loc @ rig.rest[i].T
        else:
            rel = rig.rest[p].T @ rig.rest[i]
            pr = stack_mul(P[p], rel)
            P[i] = pr @ B[i]
            H[i] = H[p] + stack_apply(P[p], rig.rest[p].T @ (rig.head[i] - rig.head[p])) \
                + (pr @ loc[..., None])[..., 0]
    return P, H
