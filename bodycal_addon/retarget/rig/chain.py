"""The avatar's spine and neck chain (DESIGN.md §1, "The rig posed"): each chain bone is twisted like the
canonical vertebra at its middle and aimed at the canonical spine curve resampled at its aim
point's arc position (the avatar has fewer vertebrae than the canonical spine). `ChainPlan` is what
aiming reads that does not depend on the frames; `ChainAim` aims a pose's chain bones one by one in
numpy (one frame's in mathutils: `rig_one_frame`); `ChainMemo` holds the last pose's aimed rotations.
A `rig` here is a `plan.RigPlan` (which imports this module, so the type is not imported back)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...body.skeleton import BONE_INDEX as BI
from ...body.skeleton import JOINT_INDEX as JI
from ...body.skeleton import SPINE_BONES, SPINE_JOINTS
from ...core.transforms import quat_between, quat_to_matrix, stacks_apply, stacks_mul
from .pose_plan import rows_of


@dataclass
class ChainPlan:
    """The spine chain's bones, in order, with what aiming each one takes."""

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
        self.rows = None if self.order is None else rows_of(self.order)  # where P takes the bones (`fk.pose_flat`)

    @classmethod
    def of(cls, rig) -> ChainPlan:
        bones = [i for i, d in enumerate(rig.driver) if d == "chain"]
        vert = np.array([BI[SPINE_BONES[rig.chain_vertebra[i]]] for i in bones], int)
        s = rig.chain_s[bones]
        k = np.clip(np.floor(s), 0, len(SPINE_JOINTS) - 2).astype(int)
        # What the chain's rotations read: the canonical frames driving the chain's ancestors
        # and the bone the spine curve starts on (and its ancestors), the vertebrae's twists,
        # and the spine bones the curve is built along.
        above: set[int] = set()
        for b in bones + [int(rig.joint_bone[JI["spine_root"]])]:
            b = rig.parent[b] if b in bones else b
            while b >= 0 and b not in above:
                above.add(int(b))
                b = rig.parent[b]
        inputs = {int(rig.driver[b]) for b in above if isinstance(rig.driver[b], (int, np.integer))}
        inputs |= {int(v) for v in vert} | {BI[b] for b in SPINE_BONES}
        return cls({b: j for j, b in enumerate(bones)}, vert,
                   np.array([rig.frames0[c].T @ rig.w_rot for c in vert]).reshape(-1, 3, 3),
                   rig.rest[bones], rig.chain_aim[bones], rig.chain_off[bones], k, s - k,
                   np.array(sorted(inputs), int), np.array(bones, int))


class ChainMemo:
    """The chain's aimed rotations of the last pose, with the bytes of every input they read.

    Decision (speed): the chain's rotations are the costliest part of a pose and a solve often
    poses the same trunk again (the egocentric method poses the avatar four times a block, the
    arms alone changing after the first IK): when every input they read is the last pose's, bit
    for bit, they are the last pose's. The key is the inputs' bytes, compared whole (not hashed):
    bytes compare bit for bit, where numpy's equality would take -0.0 for 0.0 (a different
    rotation's bits downstream) and never match a NaN. Its tag marks how they were aimed (b"float32":
    one frame's in mathutils), so a pose aimed another way never takes them. One entry: a pose
    either repeats the last one's trunk or moves on."""

    def __init__(self):
        self.key: bytes | None = None
        self.rotations: np.ndarray | None = None

    def clear(self) -> None:
        self.key = self.rotations = None

    @staticmethod
    def key_of(chain: ChainPlan, frames: np.ndarray, pelvis, tag: bytes = b"") -> bytes:
        return frames.take(chain.inputs, axis=1).tobytes() + np.asarray(pelvis, float).tobytes() + tag

    def held(self, key: bytes):
        """The kept rotations when `key` is the last pose's, else None."""
        return self.rotations if self.key is not None and self.key == key else None

    def keep(self, key: bytes, rotations: np.ndarray) -> None:
        self.key, self.rotations = key, rotations


class ChainAim:
    """The spine chain's bones aimed one by one (`fk.pose`): what each aim needs but its parent's
    pose (its vertebra's turn since rest, the twist; the aim point it carries; the offset of its
    target off the curve), the canonical spine curve once the bone it starts on is posed, and the
    aimed rotations, written into one stack (the memo's)."""

    def __init__(self, rig, delta, frames, nf: int):
        chain = rig.chain
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
            curve = spine_curve(self.rig, self.frames, P, H)
            self.target = chain.w0 * curve.take(chain.k, axis=1).swapaxes(0, 1) \
                + chain.w1 * curve.take(chain.k1, axis=1).swapaxes(0, 1) + self.off
        turn = quat_to_matrix(quat_between(self.aim[j], self.target[j] - H[i]))
        np.matmul(turn, self.twist[j], out=self.aimed[j])
        P[i] = self.aimed[j]
        self.count += 1


def spine_curve(rig, frames, P, H):
    """Canonical spine joints (F, 13, 3), armature space: spine_root on its avatar bone, then
    the canonical vertebrae with the avatar's lengths along the frames' +Y."""
    j0 = JI["spine_root"]
    b = rig.joint_bone[j0]
    if rig.driver[b] == "chain":  # not posed yet: its head is placed, orient it as at rest
        rot = rig.rest[b] if rig.start_rel is None else P[rig.parent[b]] @ rig.start_rel
    else:
        rot = P[b]
    start = H[b] + rot @ rig.joint_local[j0]
    nf = len(start)
    if frames.flags.c_contiguous:  # the vertebrae's +Y columns in one take
        ys = frames.reshape(nf, -1).take(_SPINE_Y, axis=1).reshape(nf, -1, 3) * rig.lengths[_SPINE_ROWS][:, None]
    else:
        ys = frames[:, _SPINE_ROWS][..., :, 1] * rig.lengths[_SPINE_ROWS][:, None]
    steps = ys @ rig.w_inv.T  # world steps in armature units
    curve = np.empty((nf, len(_SPINE_ROWS) + 1, 3))  # start, then start + the running sum
    curve[:, 0] = start
    np.cumsum(steps, axis=1, out=curve[:, 1:])
    curve[:, 1:] += start[:, None]
    return curve


_SPINE_ROWS = np.array([BI[b] for b in SPINE_BONES], int)  # the canonical vertebrae (spine_curve)
_SPINE_Y = (_SPINE_ROWS[:, None] * 9 + np.array([1, 4, 7])).ravel()  # their frames' +Y entries, row-major
