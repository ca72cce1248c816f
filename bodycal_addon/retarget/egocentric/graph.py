"""The kinematic graph of the egocentric mapping (Delahaye 2023, appendix C, Figure 13; appendix D,
Figure 20): the simplified tree of bones the paths run over, each element's root node, and the
elements on a target's own limb chain that it never maps onto."""

from __future__ import annotations

from collections import deque
from functools import cache

from ...body import skeleton as sk
from ...core.errors import BodyCalError

TORSO_ROOT = sk.spine_joint(sk.CLAVICLE_VERTEBRA)

# The paper's "trunk's simplified kinematic chain" (appendix C, Figure 13; appendix D, Figure 20):
# no vertebra, no sacrum, no `hand_<s>` (it duplicates metacarpal_middle); the shortcut bones
# carry the trunk.
GRAPH_BONES: tuple[str, ...] = tuple(
    b.name for b in sk.BONES if b.name != "sacrum" and not b.name.startswith(("spine_", "hand_"))
)
GRAPH_INDEX = {name: i for i, name in enumerate(GRAPH_BONES)}
GRAPH_NODES: tuple[str, ...] = tuple(dict.fromkeys(
    j for name in GRAPH_BONES for j in (sk.BONE_BY_NAME[name].head, sk.BONE_BY_NAME[name].tail)))


@cache
def _adjacency() -> dict[str, list[tuple[str, int]]]:
    adj: dict[str, list[tuple[str, int]]] = {n: [] for n in GRAPH_NODES}
    for i, name in enumerate(GRAPH_BONES):
        b = sk.BONE_BY_NAME[name]
        adj[b.head].append((b.tail, i))
        adj[b.tail].append((b.head, i))
    return adj


@cache
def kinematic_path(start: str, end: str) -> tuple[int, ...]:
    """Indices into GRAPH_BONES of the bones between two joints of the simplified tree."""
    if start not in GRAPH_NODES or end not in GRAPH_NODES:
        bad = start if start not in GRAPH_NODES else end
        raise BodyCalError(f"joint '{bad}' is not on the kinematic tree of the egocentric mapping",
                           hint="use limb, hand, finger or foot joints, pelvis, spine_05, skull_base or head")
    adj = _adjacency()
    prev: dict[str, tuple[str, int] | None] = {start: None}
    queue = deque([start])
    while queue:
        node = queue.popleft()
        if node == end:
            break
        for nxt, bone in adj[node]:
            if nxt not in prev:
                prev[nxt] = (node, bone)
                queue.append(nxt)
    path = []
    node = end
    while prev[node] is not None:
        node, bone = prev[node]
        path.append(bone)
    return tuple(reversed(path))


def element_root(element_id: str, bone: str) -> str:
    """The root joint r_i of a surface element (Delahaye 2023, eq. 2): the head of its bone, moved onto
    the simplified tree. Decision: the torso's root is the clavicle root (`spine_05`), the trunk
    node closest to both chest and belly."""
    if element_id == "mesh:torso":
        return TORSO_ROOT
    b = sk.BONE_BY_NAME.get(bone)
    if b is None:
        return "pelvis"
    if b.head in GRAPH_NODES:
        return b.head
    if b.name.startswith("spine_"):  # a vertebra: nearest trunk node of the simplified chain
        k = int(b.name.split("_")[1]) - 1
        return "pelvis" if k < 3 else TORSO_ROOT if k < 9 else "skull_base"
    return "pelvis"


def own_chain_elements(target: str) -> frozenset[str]:
    """THE exclusion table: surface elements on a target's own limb chain, which carry no contact
    information about that target (DESIGN.md §5).

    - wrist/elbow/shoulder_<s>: upperarm_<s>, forearm_<s>, every finger capsule of side s, palm_<s>;
    - finger joints (mcp/pip/dip/tip)_<f>_<s>: the same as the wrist. Decision: the hand's other
      fingers and its palm ride on the target's own wrist, so they carry the hand's shape, not a
      contact; kept, they pull a fingertip that touches a bigger avatar's body back to where the
      avatar's FK-posed fingers are (inside it). Pinches and fists come from the finger pose;
    - ankle/knee/hip/toe_<s>: thigh_<s>, shin_<s>, sole_<s>;
    - skull_base/head: the skull sphere and the jaw.
    """
    parts = target.split("_")
    side = parts[-1] if parts[-1] in sk.SIDES else None
    if target in ("skull_base", "head"):
        return frozenset({"sphere:skull", "mesh:jaw"})
    if side is None:
        return frozenset()
    if parts[0] in ("wrist", "elbow", "shoulder", "clavicle") or (parts[0] in sk.FINGER_JOINTS and len(parts) == 3):
        ids = {f"capsule:upperarm_{side}", f"capsule:forearm_{side}", f"mesh:palm_{side}"}
        ids |= {f"capsule:{f}_{i}_{side}" for f in sk.FINGERS for i in (1, 2, 3)}
        return frozenset(ids)
    if parts[0] in ("ankle", "knee", "hip", "toe"):
        return frozenset({f"capsule:thigh_{side}", f"capsule:shin_{side}", f"mesh:sole_{side}"})
    return frozenset()
