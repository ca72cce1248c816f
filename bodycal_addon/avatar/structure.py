"""A bone map from a rig's shape when no naming scheme reads its names (DESIGN.md §2, "Rigs as
files bring them"): a COLLADA export's `Skeleton_torso_joint_1`, `leg_joint_L_2`,
`Skeleton_arm_joint_L__4_`, or any humanoid rig with names of its own. Numpy only.

The rig stands along `up` (armature space). Its two lowest leaves are the feet's ends and the
bone both hang from, with the spine, is the pelvis; the spine runs from it to the highest bone;
the two branches of the spine that reach furthest sideways are the arms. Along a leg the bones
whose heads lie nearest to the hip, half way down (the knee) and 90 % down (the ankle) are the
thigh, shin and foot, and the next one the toe; along an arm the hand is the bone its fingers fan
out from (or the arm's last bone), then the forearm, upper arm and clavicle back towards the
spine (no clavicle on a three-bone arm). Above the bone the arms hang from, the last bone is the
head and any before it the neck. Sides come from the names' L/R or Left/Right words. A rig this
cannot read gives None, and the caller keeps the name-based map and its one line.
"""

from __future__ import annotations

import re

import numpy as np

from ..body import naming

SCHEME = "structure"
KNEE, ANKLE = 0.5, 0.9  # of the leg's length below the hip
REACH = 0.2  # an arm reaches at least this fraction of the rig's height from the spine


def _side_of(name: str) -> str | None:
    words = {w.lower() for w in re.findall(r"[A-Z]?[a-z]+|[A-Z]+(?![a-z])|\d+", name)}
    left, right = bool(words & {"l", "left"}), bool(words & {"r", "right"})
    return "l" if left and not right else "r" if right and not left else None


def _path(bone: str, parent: dict, stop: str | None = None) -> list[str]:
    """`bone` and its ancestors up to (not including) `stop`, top first."""
    out = []
    while bone is not None and bone != stop:
        out.append(bone)
        bone = parent.get(bone)
    return out[::-1]


def _lca(bones: list[str], parent: dict) -> str | None:
    paths = [_path(b, parent) for b in bones]
    common = None
    for level in zip(*paths):
        if len(set(level)) > 1:
            break
        common = level[0]
    return common


def _leg(path: list[str], h: dict) -> dict[str, str] | None:
    """thigh, shin, foot (and toe) along a leg's bones, hip first."""
    if len(path) < 3:
        return None
    top, length = h[path[0]], h[path[0]] - min(h[b] for b in path)
    thigh = max(i for i, b in enumerate(path) if h[b] >= top - 0.1 * length)
    rest = path[thigh + 1:]
    if len(rest) < 2:
        return None
    shin = min(rest, key=lambda b: abs(h[b] - (h[path[thigh]] - KNEE * length)))
    after = rest[rest.index(shin) + 1:]
    if not after:
        return None
    foot = min(after, key=lambda b: abs(h[b] - (h[path[thigh]] - ANKLE * length)))
    out = {"thigh": path[thigh], "shin": shin, "foot": foot}
    toe = after[after.index(foot) + 1:]
    if toe:
        out["toe"] = toe[0]
    return out


def _arm(path: list[str], children: dict) -> dict[str, str] | None:
    """clavicle, upperarm, forearm, hand along an arm's bones, spine side first."""
    fans = [i for i, b in enumerate(path) if len(children.get(b, ())) >= 2]
    k = fans[0] if fans else len(path) - 1
    if k < 2:
        return None
    out = {"hand": path[k], "forearm": path[k - 1], "upperarm": path[k - 2]}
    if k >= 3:
        out["clavicle"] = path[k - 3]
    return out


def map_by_structure(rest: dict[str, tuple[str | None, np.ndarray]], up: np.ndarray) -> naming.BoneMap | None:
    """The bone map of a humanoid rig from its shape: `rest` {bone: (parent, head)} in armature
    space, `up` the armature-space direction the rig stands along. None when it is not one."""
    parent = {n: p for n, (p, _h) in rest.items()}
    head = {n: np.asarray(v, float) for n, (_p, v) in rest.items()}
    h = {n: float(v @ up) for n, v in head.items()}
    children: dict[str, list[str]] = {}
    for n, p in parent.items():
        if p is not None:
            children.setdefault(p, []).append(n)
    leaves = sorted((n for n in rest if n not in children), key=lambda n: h[n])
    if len(leaves) < 4:
        return None
    height = max(h.values()) - min(h.values())
    top = max(rest, key=lambda n: h[n])
    feet = [leaves[0]]
    for leaf in leaves[1:]:
        lca = _lca([feet[0], leaf], parent)
        if lca is not None and h[lca] > h[leaf] + 0.3 * height:
            feet.append(leaf)
            break
    pelvis = _lca([*feet, top], parent) if len(feet) == 2 else None
    if pelvis is None:
        return None
    return _assemble(pelvis, feet, top, parent, children, head, h, up, height)


def _assemble(pelvis, feet, top, parent, children, head, h, up, height) -> naming.BoneMap | None:
    spine_path = _path(top, parent, pelvis)
    on_spine = set(spine_path) | {pelvis}
    flat = {n: v - (v @ up) * up for n, v in head.items()}

    def reach(root):  # the furthest sideways a branch gets from the pelvis, and its bone there
        stack, best = [root], (0.0, root)
        while stack:
            b = stack.pop()
            best = max(best, (float(np.linalg.norm(flat[b] - flat[pelvis])), b))
            stack += children.get(b, [])
        return best

    branches = [(reach(c), c, s) for s in spine_path for c in children.get(s, []) if c not in on_spine]
    arms = sorted((b for b in branches if b[0][0] > REACH * height), reverse=True)[:2]
    if len(arms) < 2:
        return None
    bones, chest = {"pelvis": pelvis}, max(spine_path.index(s) for _r, _c, s in arms)
    for foot in feet:
        leg = _leg(_path(foot, parent, pelvis), h)
        side = _side_of(foot)
        if leg is None or side is None:
            return None
        bones |= {f"{seg}_{side}": b for seg, b in leg.items()}
    for (_reach, far), root, _s in arms:
        arm = _arm(_path(far, parent, parent[root]), children)
        side = _side_of(root)
        if arm is None or side is None:
            return None
        bones |= {f"{seg}_{side}": b for seg, b in arm.items()}
    above = spine_path[chest + 1:]
    if not above:
        return None
    bones["head"] = above[-1]
    chains = {"spine": spine_path[:chest + 1], "neck": above[:-1]}
    used = set(bones.values()) | set(chains["spine"]) | set(chains["neck"])
    bm = naming.BoneMap(SCHEME, bones, chains, [n for n in head if n not in used])
    return bm if not bm.missing() else None
