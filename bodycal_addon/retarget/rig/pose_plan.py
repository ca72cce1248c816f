"""How a subset of the rig's bones is posed (`fk.pose`), depth by depth of the hierarchy: the driven
bones (W^-1 C_c(t) (C0^-1 W M_A), each on its own) and, per depth, the heads placed from their
parents (H_p + P_p offset), the bones that follow their parents (P_p M_p^-1 M_A), the parentless ones
(at rest) and the spine chain's (aimed one by one). Bones of one depth need only shallower ones.
Frame-independent: built once per bone subset (`RigPlan.pose_plan`; a `rig` here is a `plan.RigPlan`,
which imports this module, so the type is not imported back)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ...body.skeleton import JOINT_INDEX as JI


@dataclass
class Level:
    """The bones of one depth of the rig's hierarchy, by how they are posed."""

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
class PosePlan:
    driven: np.ndarray  # bones driven by a canonical bone
    canon: np.ndarray  # their canonical bones
    fixed: np.ndarray  # (K, 3, 3) C0^-1 W M_A
    levels: list[Level]
    chained: bool  # the spine chain's bones are posed
    has_root: bool = False  # the root bone is posed
    # A few frames (fewer than fk.FEW_FRAMES): `levels` placing only the heads the chain reads
    # (`few`), the others in one pass after it (`deferred`: rows, parents, offsets, the padded sum table).
    few: list[Level] | None = None
    deferred: tuple | None = None
    # A few frames whose spine chain needs no aiming (its rotations held, or no chain): every
    # rotation first, then every head in one padded pass from the root and the parentless bones
    # (`fk.pose_flat`); (rest bones, their matrices, loose bones, their heads, [(follow bones,
    # parents, fixed)] by depth, and the heads' rows, parents, offsets and padded sum table)
    flat: tuple | None = None
    # With a chain, a few frames' driven bones and the chain's vertebrae in one product: (the
    # canonical bones read by the driven bones then by the vertebrae, their fixed factors (K, 1, 3, 3))
    driven_and_chain: tuple | None = None
    driven_rows: slice | np.ndarray | None = None  # `driven` as P's rows take them (`rows_of`)
    # `flat`'s rest matrices and loose heads turned by the armature's rotation, W M_A and W h
    # (one frame of a turned armature, `fk.posed`)
    flat_turned: tuple | None = None
    # One frame of every bone (`fk.pose_flat`): `flat`'s heads, their offsets' product also turning
    # the canonical joints' offsets on their carriers (`_joint_head_table`)
    flat_joints: tuple | None = None


def build_pose_plan(rig, bones: tuple | None) -> PosePlan:
    """The pose plan of `bones` (ascending; None: all)."""
    keep = set(range(len(rig.names))) if bones is None else set(bones)
    depth = np.zeros(len(rig.names), int)
    for i, p in enumerate(rig.parent):  # parents come first
        depth[i] = depth[p] + 1 if p >= 0 else 0
    rows = rig.bone_rows
    driven = [i for i in sorted(keep) if isinstance(rows[i][1], (int, np.integer))]
    chained = any(rows[i][1] == "chain" for i in keep)
    # The heads the spine chain reads while it is aimed: its bones' and the spine curve's
    # start bone's, with their ancestors'. A few frames place only these level by level.
    early: set[int] = set()
    if chained:
        for b in [i for i in keep if rows[i][1] == "chain"] + [int(rig.joint_bone[JI["spine_root"]])]:
            while b >= 0 and b not in early:
                early.add(int(b))
                b = rig.parent[b]
    levels = _levels(rig, keep, depth, lambda i: True)
    plan = PosePlan(np.array(driven, int), np.array([rows[i][1] for i in driven], int),
                    np.array([rows[i][3] for i in driven], float).reshape(-1, 3, 3), levels, chained,
                    rig.root in keep)
    plan.driven_rows = rows_of(plan.driven)
    if chained:
        plan.driven_and_chain = (np.concatenate([plan.canon, rig.chain.vertebra]),
                                 np.concatenate([plan.fixed, rig.chain.fixed])[:, None])
    # The other heads, for a few frames: each is its anchor's head (the nearest ancestor placed
    # in the levels: an early bone, the root or a parentless one) plus the offsets P_p o down
    # the path, added in the levels' order (H_a + c_1) + c_2 + ..., padded with exact zeros.
    late = [i for i in sorted(keep) if i != rig.root and rows[i][0] >= 0 and i not in early]
    if late:
        plan.few = [lv for lv in _levels(rig, keep, depth, lambda i: i in early)  # the depths with work left
                    if len(lv.heads) or len(lv.loose) or len(lv.rest) or len(lv.follow) or lv.chain or lv.root]
        plan.deferred = _head_table(rig, late)
        # With no chain to aim, every head in that one pass: each its root's or parentless
        # ancestor's head plus the offsets down the path, the same sums in the same order.
        hanging = [i for i in sorted(keep) if i != rig.root and rows[i][0] >= 0]
        follows = [(lv.follow, lv.follow_par, lv.follow_fixed) for lv in levels if len(lv.follow)]
        rest = np.array([i for lv in levels for i in lv.rest.tolist()], int)
        loose = np.array([i for lv in levels for i in lv.loose.tolist()], int)
        follows = [(rows_of(b), p, f) for b, p, f in follows]
        plan.flat = (rows_of(rest), rig.rest[rest][:, None], rows_of(loose), rig.head[loose][:, None], follows,
                     *_head_table(rig, hanging))
        plan.flat_turned = (np.matmul(rig.w_rot, plan.flat[1]), plan.flat[3] @ rig.w_rot.T)
        if bones is None:
            plan.flat_joints = _joint_head_table(rig, hanging)
    return plan


def _levels(rig, keep: set[int], depth: np.ndarray, placed) -> list[Level]:
    """The levels of the bones `keep`, one per depth of the hierarchy, placing the heads of the
    bones `placed` says (the others are left to a padded pass)."""
    rows = rig.bone_rows
    out = []
    for d in range(int(depth.max()) + 1 if len(depth) else 0):
        at = [i for i in sorted(keep) if depth[i] == d]
        heads = [i for i in at if i != rig.root and rows[i][0] >= 0 and placed(i)]
        follow = [i for i in at if rows[i][1] is None and rows[i][0] >= 0]
        out.append(Level(
            np.array(heads, int), np.array([rows[i][0] for i in heads], int),
            np.array([rows[i][2] for i in heads], float).reshape(-1, 3),
            np.array([i for i in at if i != rig.root and rows[i][0] < 0], int),
            np.array([i for i in at if rows[i][1] is None and rows[i][0] < 0], int),
            np.array(follow, int), np.array([rows[i][0] for i in follow], int),
            np.array([rows[i][3] for i in follow], float).reshape(-1, 3, 3),
            [i for i in at if rows[i][1] == "chain"], rig.root in at))
        out[-1].loose_at = rig.head[out[-1].loose][:, None]
        out[-1].rest_at = rig.rest[out[-1].rest][:, None]
        out[-1].head_off4 = out[-1].head_off[:, None, :, None]
        out[-1].follow_fixed4 = out[-1].follow_fixed[:, None]
    return out


def _head_table(rig, late: list[int]) -> tuple:
    """For the heads of bones `late`, placed in one pass (`fk.pose`): (the bones, their parents,
    the offsets in the parents' rest frames, the padded sum table: per bone its anchor's row in
    H (the nearest ancestor not in `late`) and its path's offsets' rows after H's, top down,
    padded with the row of a zero; where they go in H: a slice when they are consecutive rows
    (the sums written there, no gathered copy to scatter), else the bones)."""
    rows = rig.bone_rows
    row = {b: k for k, b in enumerate(late)}
    n = len(rig.names)
    paths = []
    for b in late:
        path = [b]
        while path[-1] in row and rig.parent[path[-1]] in row:
            path.append(int(rig.parent[path[-1]]))
        paths.append((int(rig.parent[path[-1]]), [n + row[k] for k in reversed(path)]))
    width = max(len(p) for _, p in paths)
    zero = n + len(late)
    table = np.array([[a] + p + [zero] * (width - len(p)) for a, p in paths], int).T  # (1 + width, D)
    at = rows_of(late)
    return (np.array(late, int), np.array([rows[i][0] for i in late], int),
            np.array([rows[i][2] for i in late], float).reshape(-1, 3), table, at)


def _joint_head_table(rig, late: list[int]) -> tuple:
    """`_head_table` of the heads of bones `late` whose offsets' products also turn the canonical
    joints' offsets on their carriers, P_car o_j, for one frame's pass (`fk.pose_flat`), which
    `fk.finish` adds to the carriers' heads. The buffer's rows (`fk._pose_buffers`): the heads H
    (N), the bones' offset terms (L), the joints' (J), a zero. (the terms' parents and offsets
    (L + J, 1, 3, 1), the padded table, where the sums go, the joints' terms' rows, the buffer's
    length). Decision (speed, measured in instructions): `finish` turned the joints' offsets in
    a product of its own over their carriers, padded to five joints a bone, and gathered them
    (~50,000 a pose); the heads' product takes them for a few thousand. Also measured: the
    joints summed in the heads' padded pass (their carriers' paths and one more term) cost more
    than it saved (a table of 123 columns against 51: +65,000, -84,000)."""
    n, nj, nl = len(rig.names), len(rig.joint_bone), len(late)
    rows = rig.bone_rows
    row = {b: k for k, b in enumerate(late)}
    zero = n + nl + nj
    cols = []
    for b in late:
        path = [b]
        while rig.parent[path[-1]] in row:
            path.append(int(rig.parent[path[-1]]))
        cols.append((int(rig.parent[path[-1]]), [n + row[k] for k in reversed(path)]))
    width = max(len(p) for _, p in cols)
    table = np.array([[a] + p + [zero] * (width - len(p)) for a, p in cols], int).T
    par = np.array([rows[i][0] for i in late] + rig.joint_bone.tolist(), int)
    off = np.concatenate([np.array([rows[i][2] for i in late], float).reshape(-1, 3), rig.joint_local])
    return par, off[:, None, :, None], table, rows_of(late), slice(n + nl, zero), zero + 1


def rows_of(bones) -> slice | np.ndarray:
    """Where the rows of ascending `bones` are written (P[rows] = ...): a slice when they are
    consecutive, else their indices. Decision (speed): a few frames' scatter by an index array
    costs about 16,000 instructions, a slice's copy a fifth of that."""
    bones = [int(b) for b in bones]
    if bones and bones == list(range(bones[0], bones[-1] + 1)):
        return slice(bones[0], bones[-1] + 1)
    return np.array(bones, int)
