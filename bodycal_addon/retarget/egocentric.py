"""Egocentric self-contact mapping (Delahaye 2023, appendix C; DESIGN.md §5), numpy only, vectorised
over a leading frame axis.

Three steps, each a public function:

1. `pose_surface(model, joints, bone_rotations) -> PosedSurface`: every surface element of a body
   model placed per frame from the canonical joint positions and bone frames (columns x, y, z as
   `surface_layout.bone_frame` gives: +Y along the bone, +X its right).
2. `project(points, surface) -> Projections`: each target point projected on each element
   (`x_ij`, `v_ij = p_j - x_ij`), with the surface coordinates that re-pose the projection on
   another body, and the angular factor of the raw weight.
3. `retarget_points(...)`: the retro-projection of Delahaye 2023, eq. 1, with the kinematic
   normalisation of eq. 2 and the floor singularity.

Example (helper code builds `joints` / `bone_rotations` dicts of (F, 3) / (F, 3, 3) arrays)::

    ids = common_elements(user_model, avatar_model)
    us = pose_surface(user_model, user_joints, user_rots, element_ids=ids)
    av = pose_surface(avatar_model, avatar_fk_joints, avatar_fk_rots, element_ids=ids)
    names = ["wrist_l", "wrist_r", "elbow_l", "elbow_r", "tip_index_l", "skull_base"]
    pts = np.stack([user_joints[n] for n in names], axis=1)          # (F, P, 3)
    new = retarget_points(pts, names, us, av)                          # (F, P, 3) avatar targets

Conventions and decisions (each one named in the code where it applies):
- Element order in a `PosedSurface`: capsules, then spheres, then meshes (`element_ids`). The user
  and the avatar must be posed with the same `element_ids` (see `common_elements`).
- A mesh element contributes its closest point (on its closest triangle, per frame and target);
  its angular factor blends its triangles' own by how near each is to being the closest
  (FACTOR_BLEND), so the weight moves continuously across edges and corners. Known limit: where
  two separate parts of a mesh are equally near (far beside the crude torso, its front and
  back), the closest point itself jumps; the step seen is ~1 mm.
- Targets are canonical joint names; the elements on a target's own limb chain are excluded
  (`own_chain_elements`, the single table of exclusions).
- Kinematic paths run over the simplified tree `GRAPH_BONES`: the limb, hand, finger, foot and
  head bones plus the shortcut bones (sacrum -> hips, sacrum -> clavicle root, clavicle root ->
  skull base); the vertebrae are skipped as the paper's Figure 13 does. Each element has one root
  node (`element_root`); the path runs from that node to the target's own joint, so the paper's
  extremity term `v.(p_j - e_j)` is the last bone of the path (the target is the tail of its
  bone). DESIGN.md Decision: absolute values in eq. 2.
- Floor: `h'_j = h_j tau'/tau` with the path from the supporting (lower) ankle to the target; the
  "x - r" extremity of that path is the ankle's height above the floor. Decision: with both feet
  down, the two feet's ratios are blended (SUPPORT_BLEND), so the choice never flips on noise.
- Raw weights: distances are floored at MIN_DISTANCE (1 mm), so a target on a surface takes (almost)
  all the weight of that element and nothing divides by zero; the triangle's cos(v, n) is taken
  from the plane shifted PENETRATION_TOLERANCE into the body (see _triangle_factor).
- Chains with zero weight are skipped: own-chain pairs have no chain at all (paper: "when the
  associated lambda for a kinematic chain is null, the computation ... is skipped").
- A mesh whose triangles differ between user and avatar (e.g. palms with other point counts) is
  re-posed in its bone's frame scaled by the bone length ratio instead of by barycentrics.

Speed: the hot path keeps vector components first ((3, F, P, E) arrays) and runs blocks of
BLOCK_PAIRS frames x targets x elements so the temporaries stay in the CPU caches; everything
frame-independent (exclusions, kinematic paths as index arrays sorted by length) is computed once
per target/element set; targets that exclude the same elements are mapped on the others only;
the user's side is prepared once (`prepare_targets`) and mapped onto each avatar pose; the
pipeline computes it in float32 (`dtype`).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from functools import cache, lru_cache

import numpy as np

from .. import skeleton as sk
from ..errors import BodyCalError
from ..transforms import frame_from_axes

MIN_DISTANCE = 1e-3  # m: raw weights are capped at 1 / MIN_DISTANCE**2 (a target on a surface)
PENETRATION_TOLERANCE = 0.01  # m: see _triangle_factor
FACTOR_BLEND = 0.002  # m: distance beyond the nearest over which a mesh triangle's factor fades (_project)
SUPPORT_BLEND = 0.02  # m: ankle height difference over which the supporting foot hands over (_map_block)
TORSO_ROOT = sk.spine_joint(sk.CLAVICLE_VERTEBRA)

# --- kinematic tree ----------------------------------------------------------------------------

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


# --- posed surface -----------------------------------------------------------------------------

@dataclass
class PosedSurface:
    """A body model's surface elements placed per frame (F frames). Elements are ordered capsules,
    spheres, meshes; E = C + S + M."""

    element_ids: list[str]
    element_bones: list[str]  # the bone each element rides on (mesh: the element's `bone`)
    element_roots: list[str]  # root joint r_i of each element (element_root)
    caps_head: np.ndarray  # (F, C, 3) segment start (the bone's head joint)
    caps_tail: np.ndarray  # (F, C, 3)
    caps_rot: np.ndarray  # (F, C, 3, 3) bone frames
    caps_radius: np.ndarray  # (C, 2) radius at head, at tail
    sph_center: np.ndarray  # (F, S, 3)
    sph_rot: np.ndarray  # (F, S, 3, 3)
    sph_radius: np.ndarray  # (S,)
    tri: np.ndarray  # (F, T, 3, 3) triangle corners, outward winding
    tri_normal: np.ndarray  # (F, T, 3) unit outward normals
    tri_elem: np.ndarray  # (T,) element index (into element_ids) of each triangle
    mesh_slices: list[tuple[int, int]]  # per mesh element, its triangle range in `tri`
    mesh_head: np.ndarray  # (F, M, 3) head joint of each mesh element's bone
    mesh_rot: np.ndarray  # (F, M, 3, 3) frame of each mesh element's bone
    mesh_scale: np.ndarray  # (M,) length of each mesh element's bone (re-posing fallback)
    joints: dict[str, np.ndarray]  # canonical joint -> (F, 3)
    notes: list[str] = field(default_factory=list)

    @property
    def frames(self) -> int:
        return self.tri.shape[0] if self.tri.size else next(iter(self.joints.values())).shape[0]

    @property
    def counts(self) -> tuple[int, int, int]:
        return self.caps_radius.shape[0], self.sph_radius.shape[0], len(self.mesh_slices)

    def take(self, start: int, stop: int) -> PosedSurface:
        """The frames [start, stop) (views, no copy)."""
        s = slice(start, stop)
        return PosedSurface(self.element_ids, self.element_bones, self.element_roots, self.caps_head[s],
                            self.caps_tail[s], self.caps_rot[s], self.caps_radius, self.sph_center[s], self.sph_rot[s],
                            self.sph_radius, self.tri[s], self.tri_normal[s], self.tri_elem, self.mesh_slices,
                            self.mesh_head[s], self.mesh_rot[s], self.mesh_scale,
                            {k: v[s] for k, v in self.joints.items()}, self.notes)

    def astype(self, dtype) -> PosedSurface:
        """The surface with its placed geometry in `dtype` (itself if already; joints unchanged)."""
        if self.caps_head.dtype == dtype:
            return self
        c = [np.asarray(a, dtype) for a in (self.caps_head, self.caps_tail, self.caps_rot, self.caps_radius,
                                            self.sph_center, self.sph_rot, self.sph_radius, self.tri, self.tri_normal)]
        return PosedSurface(self.element_ids, self.element_bones, self.element_roots, *c, self.tri_elem,
                            self.mesh_slices, np.asarray(self.mesh_head, dtype), np.asarray(self.mesh_rot, dtype),
                            np.asarray(self.mesh_scale, dtype), self.joints, self.notes)

    def select(self, keep) -> PosedSurface:
        """The elements at indices `keep` (ascending: capsules, spheres, meshes stay in order)."""
        keep = np.asarray(keep, int)
        C, S, _ = self.counts
        ci, si, mi = keep[keep < C], keep[(keep >= C) & (keep < C + S)] - C, keep[keep >= C + S] - C - S
        rows, elem, slices = [], [], []
        for k, m in enumerate(mi):
            a, b = self.mesh_slices[m]
            slices.append((len(rows), len(rows) + b - a))
            rows += range(a, b)
            elem += [len(ci) + len(si) + k] * (b - a)
        rows = np.array(rows, int)

        def cols(a, idx):  # np.take along an inner axis is ~2x faster than fancy indexing
            return np.take(a, idx, axis=1)

        return PosedSurface([self.element_ids[k] for k in keep], [self.element_bones[k] for k in keep],
                            [self.element_roots[k] for k in keep], cols(self.caps_head, ci), cols(self.caps_tail, ci),
                            cols(self.caps_rot, ci), self.caps_radius[ci], cols(self.sph_center, si),
                            cols(self.sph_rot, si), self.sph_radius[si], cols(self.tri, rows),
                            cols(self.tri_normal, rows), np.array(elem, int), slices, cols(self.mesh_head, mi),
                            cols(self.mesh_rot, mi), self.mesh_scale[mi], self.joints, self.notes)


def common_elements(*models) -> list[str]:
    """Element ids present in every model (in the first model's order): pose the user and the
    avatar with these so their elements pair one to one."""
    ids = [e.id for e in models[0].surface]
    for m in models[1:]:
        have = {e.id for e in m.surface}
        ids = [i for i in ids if i in have]
    return ids


def _frames_of(joints: dict[str, np.ndarray]) -> int:
    for v in joints.values():
        return np.asarray(v).shape[0]
    raise BodyCalError("no joint positions given to pose the surface")


def _rotation(bone, joints, bone_rotations, model, frames):
    if bone in bone_rotations:
        return np.asarray(bone_rotations[bone], float)
    info = model.bones.get(bone)
    b = sk.BONE_BY_NAME.get(bone)
    if b is None or b.head not in joints or b.tail not in joints:
        raise BodyCalError(f"no frame for bone '{bone}'", source=model.name,
                           hint="pass its (F, 3, 3) rotation in bone_rotations")
    right = info.right if info is not None and info.right is not None else np.array([1.0, 0.0, 0.0])
    return frame_from_axes(np.asarray(joints[b.tail]) - np.asarray(joints[b.head]), np.broadcast_to(right, (frames, 3)))


def _head_of(bone, model) -> str:
    if bone in sk.BONE_BY_NAME:
        return sk.BONE_BY_NAME[bone].head
    info = model.bones.get(bone)
    if info is None:
        raise BodyCalError(f"unknown bone '{bone}'", source=model.name)
    return info.head


def pose_surface(model, joints: dict[str, np.ndarray], bone_rotations: dict[str, np.ndarray],
                 element_ids: list[str] | None = None) -> PosedSurface:
    """Place every surface element of `model` per frame.

    `joints`: canonical joint -> (F, 3) world positions; `bone_rotations`: bone -> (F, 3, 3) bone
    frames (a bone missing here gets frame_from_axes(tail - head, the model's rest `right`)).
    Capsules run from their bone's head joint to its tail joint (plus the element's axis offsets,
    in the bone's frame); sphere centres and mesh points are
    local to their bones (origin at the bone's head joint). `element_ids` restricts and orders the
    elements (default: all of the model's); an element whose joints are missing is left out and
    named in `notes`."""
    frames = _frames_of(joints)
    joints = {k: np.asarray(v, float) for k, v in joints.items()}
    wanted = element_ids if element_ids is not None else [e.id for e in model.surface]
    by_id = {e.id: e for e in model.surface}
    notes = []
    caps, sphs, meshes = [], [], []
    for eid in wanted:
        e = by_id.get(eid)
        if e is None:
            raise BodyCalError(f"surface element '{eid}' is not in the body model", source=model.name)
        if e.type == "capsule":
            b = sk.BONE_BY_NAME.get(e.bone)
            info = model.bones.get(e.bone)
            if b is None or b.head not in joints or b.tail not in joints:
                notes.append(f"{eid}: joints not posed, element left out")
                continue
            if info is None or info.radius_head is None or info.radius_tail is None:
                notes.append(f"{eid}: no capsule radii, element left out")
                continue
            caps.append(e)
        elif e.type == "sphere":
            if _head_of(e.bone, model) not in joints or e.center is None or e.radius is None:
                notes.append(f"{eid}: incomplete sphere, element left out")
                continue
            sphs.append(e)
        else:
            if not e.triangles or any(_head_of(p.bone, model) not in joints for p in e.points.values()):
                notes.append(f"{eid}: mesh points not posed, element left out")
                continue
            meshes.append(e)
    ordered = caps + sphs + meshes

    def stack(arrs, shape):
        return np.stack(arrs, axis=1) if arrs else np.zeros((frames, 0) + shape)

    caps_rot = stack([_rotation(e.bone, joints, bone_rotations, model, frames) for e in caps], (3, 3))
    caps_off = np.array([e.axis_offsets() for e in caps], float).reshape(-1, 2, 3)
    caps_head = stack([joints[sk.BONE_BY_NAME[e.bone].head] for e in caps], (3,))
    caps_tail = stack([joints[sk.BONE_BY_NAME[e.bone].tail] for e in caps], (3,))
    if np.any(caps_off):  # axes off the bone line (bodymodel: axis_head / axis_tail)
        caps_head = caps_head + np.einsum("fcij,cj->fci", caps_rot, caps_off[:, 0])
        caps_tail = caps_tail + np.einsum("fcij,cj->fci", caps_rot, caps_off[:, 1])
    caps_radius = np.array([[model.bones[e.bone].radius_head, model.bones[e.bone].radius_tail] for e in caps],
                           float).reshape(-1, 2)
    sph_rot = stack([_rotation(e.bone, joints, bone_rotations, model, frames) for e in sphs], (3, 3))
    sph_origin = stack([joints[_head_of(e.bone, model)] for e in sphs], (3,))
    sph_local = np.array([e.center for e in sphs], float).reshape(-1, 3)
    sph_center = sph_origin + np.einsum("fsij,sj->fsi", sph_rot, sph_local)
    sph_radius = np.array([e.radius for e in sphs], float)

    # Mesh points: one gather over every point of every mesh.
    point_bones, point_local, tri_rows, tri_elem, slices = [], [], [], [], []
    rot_cache: dict[str, np.ndarray] = {}

    def rot_of(bone):
        if bone not in rot_cache:
            rot_cache[bone] = _rotation(bone, joints, bone_rotations, model, frames)
        return rot_cache[bone]

    for m, e in enumerate(meshes):
        names = list(e.points)
        base = len(point_bones)
        point_bones += [e.points[n].bone for n in names]
        point_local += [e.points[n].local for n in names]
        start = len(tri_rows)
        tri_rows += [[base + names.index(n) for n in t] for t in e.triangles]
        tri_elem += [len(caps) + len(sphs) + m] * len(e.triangles)
        slices.append((start, len(tri_rows)))
    if point_bones:
        # Per bone, its points in one BLAS call (frames stay the outer axis: C order throughout).
        world = np.empty((frames, len(point_bones), 3))
        local = np.array(point_local, float)
        for b in dict.fromkeys(point_bones):
            rows = np.array([i for i, pb in enumerate(point_bones) if pb == b])
            rot = np.ascontiguousarray(rot_of(b))
            world[:, rows] = joints[_head_of(b, model)][:, None, :] + np.swapaxes(
                (rot.reshape(-1, 3) @ local[rows].T).reshape(frames, 3, len(rows)), 1, 2)
        tri = np.take(world, np.array(tri_rows), axis=1)  # (F, T, 3, 3), C order (world[:, rows] is not)
    else:
        tri = np.zeros((frames, 0, 3, 3))
    n = np.cross(tri[:, :, 1] - tri[:, :, 0], tri[:, :, 2] - tri[:, :, 0])
    nn = np.linalg.norm(n, axis=-1, keepdims=True)
    tri_normal = np.divide(n, nn, out=np.zeros_like(n), where=nn > 1e-15)

    # A mesh's own bone (its frame is the re-posing fallback); an element that names no single
    # bone (e.g. "spine_*") takes its first point's.
    mesh_bones = [e.bone if e.bone in model.bones or e.bone in sk.BONE_BY_NAME else next(iter(e.points.values())).bone
                  for e in meshes]
    mesh_head = stack([joints[_head_of(b, model)] for b in mesh_bones], (3,))
    mesh_rot = stack([rot_of(b) for b in mesh_bones], (3, 3))
    mesh_scale = np.array([model.bones[b].length if b in model.bones else 1.0 for b in mesh_bones], float)

    return PosedSurface(
        element_ids=[e.id for e in ordered], element_bones=[e.bone for e in caps + sphs] + mesh_bones,
        element_roots=[element_root(e.id, b) for e, b in zip(ordered, [e.bone for e in caps + sphs] + mesh_bones)],
        caps_head=caps_head, caps_tail=caps_tail, caps_rot=caps_rot, caps_radius=caps_radius,
        sph_center=sph_center, sph_rot=sph_rot, sph_radius=sph_radius,
        tri=tri, tri_normal=tri_normal, tri_elem=np.array(tri_elem, int), mesh_slices=slices,
        mesh_head=mesh_head, mesh_rot=mesh_rot, mesh_scale=mesh_scale, joints=joints, notes=notes)


# --- projection --------------------------------------------------------------------------------

@dataclass
class Projections:
    """Projections of P target points on the E elements of a PosedSurface, per frame.

    x, v: (F, P, E, 3) closest points and v = p - x; dist: (F, P, E) |v|; factor: (F, P, E) the
    angular factor of the raw weight (capsule |sin(v, axis)|, sphere 1, triangle max(0, cos(v, n)));
    surface coordinates: capsules `cap_t` (F, P, C) axial fraction and `cap_dir` (F, P, C, 3) unit
    direction from the axis in the bone frame; spheres `sph_dir` (F, P, S, 3) in the bone frame;
    meshes `tri_index` (F, P, M) the closest triangle (index into surface.tri) and `tri_bary`
    (F, P, M, 3) its barycentric coordinates."""

    x: np.ndarray
    v: np.ndarray
    dist: np.ndarray
    factor: np.ndarray
    cap_t: np.ndarray
    cap_dir: np.ndarray
    sph_dir: np.ndarray
    tri_index: np.ndarray
    tri_bary: np.ndarray


def _comp(a) -> np.ndarray:
    """(..., 3) -> (3, ...) contiguous. The hot path keeps vector components first, so every
    operation runs over contiguous arrays (numpy is several times slower on a trailing axis of 3)."""
    return np.ascontiguousarray(np.moveaxis(_floating(a), -1, 0))


def _rot_comp(rot) -> np.ndarray:
    """(F, X, 3, 3) -> (3, 3, F, 1, X): R_ij as contiguous (F, 1, X) arrays (1 = the target axis)."""
    return np.ascontiguousarray(_floating(rot).transpose(2, 3, 0, 1))[:, :, :, None, :]


def _floating(a) -> np.ndarray:
    """float32 stays float32 (the pipeline maps in single precision); anything else is float64."""
    a = np.asarray(a)
    return a if a.dtype == np.float32 else a.astype(float, copy=False)


def _dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _normalised(v, fallback):
    """Unit vectors of (3, ...) `v` and their norms; `fallback` where v vanishes (never NaN)."""
    n = np.sqrt(_dot(v, v))
    ok = n > 1e-12
    u = v / np.where(ok, n, 1.0)
    if not ok.all():
        u = np.where(ok, u, fallback)
    return u, n


def _apply(rc, v):
    """R v for (3, 3, ...) rotation components and (3, ...) vectors."""
    return _rows_dot(rc, v, transpose=False)


def _apply_t(rc, v):
    """R^T v (world -> bone frame)."""
    return _rows_dot(rc, v, transpose=True)


def _rows_dot(rc, v, transpose):
    out = np.empty((3,) + np.broadcast_shapes(rc.shape[2:], v.shape[1:]), np.result_type(rc, v))
    tmp = np.empty(out.shape[1:], out.dtype)
    for i in range(3):
        r = rc[:, i] if transpose else rc[i]
        np.multiply(r[0], v[0], out=out[i])
        for k in (1, 2):  # in place: no temporaries beyond one
            np.multiply(r[k], v[k], out=tmp)
            out[i] += tmp
    return out


def _closest_on_triangles(ap, ab, ac):
    """Ericson's closest point on a triangle (Real-Time Collision Detection 5.1.5), branch-free
    over arrays in components-first layout: ap = p - a (3, F, P, T), ab, ac (3, F, 1, T).
    Returns the barycentric weights (v, w) of b and c, (F, P, T)."""
    d1 = _dot(ab, ap)
    d2 = _dot(ac, ap)
    abab = _dot(ab, ab)
    acac = _dot(ac, ac)
    abac = _dot(ab, ac)
    d3, d4 = d1 - abab, d2 - abac  # (p - b).ab, (p - b).ac
    d5, d6 = d1 - abac, d2 - acac  # (p - c).ab, (p - c).ac
    vc = d1 * d4 - d3 * d2
    vb = d5 * d2 - d1 * d6
    va = d3 * d6 - d5 * d4

    def safe(num, den):
        return num / np.where(den != 0, den, 1.0)

    denom = va + vb + vc
    inside_v, inside_w = safe(vb, denom), safe(vc, denom)
    e_ab = safe(d1, d1 - d3)
    e_ac = safe(d2, d2 - d6)
    e_bc = safe(d4 - d3, (d4 - d3) + (d5 - d6))
    # Ericson's early returns in order A, B, AB, C, AC, BC, inside: applied in reverse so the
    # first region that holds wins.
    bv, bw = inside_v, inside_w
    for cond, cv, cw in (((va <= 0) & (d4 >= d3) & (d5 >= d6), 1 - e_bc, e_bc),
                         ((vb <= 0) & (d2 >= 0) & (d6 <= 0), 0.0, e_ac),
                         ((d6 >= 0) & (d5 <= d6), 0.0, 1.0),
                         ((vc <= 0) & (d1 >= 0) & (d3 <= 0), e_ab, 0.0),
                         ((d3 >= 0) & (d4 <= d3), 1.0, 0.0),
                         ((d1 <= 0) & (d2 <= 0), 0.0, 0.0)):
        bv = np.where(cond, cv, bv)
        bw = np.where(cond, cw, bw)
    return bv, bw


@dataclass
class _Proj:
    """Projections in components-first layout (the hot path); see Projections for the meaning."""

    x: np.ndarray  # (3, F, P, E)
    v: np.ndarray  # (3, F, P, E)
    dist: np.ndarray  # (F, P, E)
    factor: np.ndarray  # (F, P, E)
    cap_t: np.ndarray  # (F, P, C)
    cap_dir: np.ndarray  # (3, F, P, C) unit direction from the axis, in the bone frame
    sph_dir: np.ndarray  # (3, F, P, S) in the bone frame
    tri_index: np.ndarray  # (F, P, M)
    tri_bary: np.ndarray  # (3, F, P, M)

    def public(self, surface: PosedSurface) -> Projections:
        m = np.moveaxis
        return Projections(m(self.x, 0, -1), m(self.v, 0, -1), self.dist, self.factor, self.cap_t,
                           m(self.cap_dir, 0, -1), m(self.sph_dir, 0, -1), self.tri_index, m(self.tri_bary, 0, -1))


def _project(p, surface: PosedSurface, tol: float) -> _Proj:
    F, P = p.shape[:2]
    pc = _comp(p)[..., None]  # (3, F, P, 1)
    C, S, M = surface.counts
    # Capsules: closest point on the axis segment pushed out by the radius interpolated along it.
    a = _comp(surface.caps_head)[:, :, None, :]
    ab = _comp(surface.caps_tail)[:, :, None, :] - a
    abab = np.maximum(_dot(ab, ab), 1e-24)
    ap = pc - a
    t = np.clip(_dot(ap, ab) / abab, 0.0, 1.0)
    rc = _rot_comp(surface.caps_rot)
    d, n = _normalised(ap - t * ab, rc[:, 0])  # on the axis: the bone's +X
    r = surface.caps_radius[:, 0] + t * (surface.caps_radius[:, 1] - surface.caps_radius[:, 0])
    cap_v = (n - r) * d
    cos_ax = _dot(d, ab) / np.sqrt(abab)  # v is parallel to d, also when v -> 0
    cap_factor = np.sqrt(np.clip(1.0 - cos_ax * cos_ax, 0.0, 1.0))
    # Spheres.
    sc = _comp(surface.sph_center)[:, :, None, :]
    src = _rot_comp(surface.sph_rot)
    sd, sn = _normalised(pc - sc, src[:, 1])
    sph_v = (sn - surface.sph_radius) * sd
    # Meshes: the closest triangle of each element.
    if M:
        ta = _comp(surface.tri[:, :, 0])[:, :, None, :]
        tab = _comp(surface.tri[:, :, 1])[:, :, None, :] - ta
        tac = _comp(surface.tri[:, :, 2])[:, :, None, :] - ta
        tap = pc - ta
        bv, bw = _closest_on_triangles(tap, tab, tac)
        tv = tap - bv * tab - bw * tac  # p - x
        td2 = _dot(tv, tv)
        sel = np.stack([np.argmin(td2[..., s:e], axis=-1) + s for s, e in surface.mesh_slices], axis=-1)
        starts = np.array([s for s, _ in surface.mesh_slices])
        of_tri = np.repeat(np.arange(M), [e - s for s, e in surface.mesh_slices])
        mesh_v = np.stack([np.take_along_axis(tv[i], sel, axis=2) for i in range(3)])
        bv, bw = np.take_along_axis(bv, sel, axis=2), np.take_along_axis(bw, sel, axis=2)
        tri_bary = np.stack([1.0 - bv - bw, bv, bw])
        # Decision: the angular factor is every triangle's own, weighted by how close the triangle
        # is to being the nearest (exp(-(d_t - d_min) / FACTOR_BLEND)). A closest point on an
        # edge or a corner is the closest point of every triangle that shares it, whose normals
        # differ: taking the nearest triangle's factor let rounding pick it, and a point leaving a
        # corner for an edge dropped the corner's other triangles at once (steps of 1 cm in the
        # mapped target for 0.3 mm of motion beside the crude torso). Each triangle's factor and
        # distance move continuously, so the blend does.
        tri_factor = _triangle_factor(tv, _comp(surface.tri_normal)[:, :, None, :], tol)  # (F, P, T)
        td = np.sqrt(td2)
        closest = np.take(np.take_along_axis(td, sel, axis=2), of_tri, axis=2)  # (F, P, T) its mesh's min
        near = np.exp((closest - td) * (1.0 / FACTOR_BLEND))
        mesh_factor = np.add.reduceat(near * tri_factor, starts, axis=2) / np.add.reduceat(near, starts, axis=2)
    else:
        sel = np.zeros((F, P, 0), int)
        mesh_v = tri_bary = np.zeros((3, F, P, 0), pc.dtype)
        mesh_factor = np.zeros((F, P, 0), pc.dtype)
    v = np.concatenate([cap_v, sph_v, mesh_v], axis=-1)
    x = pc - v
    dist = np.sqrt(_dot(v, v))
    factor = np.concatenate([cap_factor, np.ones((F, P, S), pc.dtype), mesh_factor], axis=-1)
    # Surface coordinates in the bone frames: what re-poses the projection on another body.
    return _Proj(x, v, dist, factor, t, _apply_t(rc, d), _apply_t(src, sd), sel, tri_bary)


def project(points: np.ndarray, surface: PosedSurface, penetration_tolerance: float = PENETRATION_TOLERANCE
            ) -> Projections:
    """Project (F, P, 3) points on every element of `surface` (Delahaye 2023, appendix C, Figure 12)."""
    return _project(_floating(points), surface, penetration_tolerance).public(surface)


def _triangle_factor(v, normal, tol):
    """max(0, cos(v, n)) (Delahaye 2023, appendix C, raw contributions), components first. Decision:
    the angle is taken from the triangle plane shifted `tol` into the body, so a target that sinks
    a few millimetres into the crude mesh (calibration noise) keeps its contact weight instead of
    dropping to zero; at v = 0 the factor is 1 (a target on the surface)."""
    w = v + tol * normal
    wn = np.sqrt(_dot(w, w))
    cos = np.divide(_dot(w, normal), wn, out=np.ones_like(wn), where=wn > 1e-12)
    return np.maximum(cos, 0.0)


def _triangle_frames(tri, normal):
    """(F, T, 3, 3) frames of triangles: columns first edge, normal x edge, normal."""
    e1 = tri[:, :, 1] - tri[:, :, 0]
    e1 = e1 / np.maximum(np.linalg.norm(e1, axis=-1, keepdims=True), 1e-15)
    return np.stack([e1, np.cross(normal, e1), normal], axis=-1)


def _repose(pr: _Proj, user: PosedSurface, avatar: PosedSurface, turn_v: bool = False):
    """(x', v'): x' re-posed on the avatar (see `repose`); v' = v, or with `turn_v` the user's v
    carried by each element's local frame onto the avatar's (bone frame for capsules and spheres,
    triangle frame for meshes), so it keeps its angle to the avatar's surface."""
    F, P = pr.v.shape[1:3]
    C, S, M = avatar.counts
    a = _comp(avatar.caps_head)[:, :, None, :]
    ab = _comp(avatar.caps_tail)[:, :, None, :] - a
    t = pr.cap_t
    r = avatar.caps_radius[:, 0] + t * (avatar.caps_radius[:, 1] - avatar.caps_radius[:, 0])
    # The same direction in the avatar's bone frame.
    cap_rot, sph_rot = _rot_comp(avatar.caps_rot), _rot_comp(avatar.sph_rot)
    cap = a + t * ab + r * _apply(cap_rot, pr.cap_dir)
    sph = _comp(avatar.sph_center)[:, :, None, :] + avatar.sph_radius * _apply(sph_rot, pr.sph_dir)
    v_parts = None
    if turn_v:  # v turned by R' R^T
        v_parts = [_apply(cap_rot, _apply_t(_rot_comp(user.caps_rot), pr.v[..., :C])),
                   _apply(sph_rot, _apply_t(_rot_comp(user.sph_rot), pr.v[..., C:C + S]))]
    if M:
        same = np.array([(ue - us) == (ae - as_) for (us, ue), (as_, ae) in zip(user.mesh_slices,
                                                                                 avatar.mesh_slices)])
        # The user's triangle index -> the avatar's (same position inside the element).
        offset = np.array([as_ - us for (us, _), (as_, _) in zip(user.mesh_slices, avatar.mesh_slices)])
        idx = np.where(same, pr.tri_index + offset, avatar.mesh_slices[0][0])
        fi = np.arange(F)[:, None, None]
        mesh = np.zeros((3, F, P, M), pr.v.dtype)
        for k in range(3):
            corner = _comp(avatar.tri[:, :, k])
            for i in range(3):
                mesh[i] += pr.tri_bary[k] * corner[i][fi, idx]
        if turn_v:
            to_avatar = np.concatenate([np.arange(us, ue) + (as_ - us) if ok else np.full(ue - us, as_)
                                        for (us, ue), (as_, _), ok in zip(user.mesh_slices, avatar.mesh_slices, same)])
            rel = (_triangle_frames(avatar.tri, avatar.tri_normal)[:, to_avatar]
                   @ np.swapaxes(_triangle_frames(user.tri, user.tri_normal), -1, -2))  # (F, T, 3, 3)
            rel = np.ascontiguousarray(rel.transpose(2, 3, 0, 1))[:, :, fi, pr.tri_index]  # (3, 3, F, P, M)
            mesh_v = _apply(rel, pr.v[..., C + S:])
        if not same.all():
            # Different triangles (e.g. palms with other point counts): the element bone's frame,
            # scaled by the bone length ratio.
            bad = np.flatnonzero(~same)
            xm = pr.x[:, :, :, C + S + bad]
            local = _apply_t(_rot_comp(user.mesh_rot[:, bad]), xm - _comp(user.mesh_head[:, bad])[:, :, None, :])
            scale = avatar.mesh_scale[bad] / np.maximum(user.mesh_scale[bad], 1e-9)
            bone_rel = _rot_comp(avatar.mesh_rot[:, bad] @ np.swapaxes(user.mesh_rot[:, bad], -1, -2))
            mesh[:, :, :, bad] = (_comp(avatar.mesh_head[:, bad])[:, :, None, :]
                                  + _apply(_rot_comp(avatar.mesh_rot[:, bad]), local * scale))
            if turn_v:
                mesh_v[:, :, :, bad] = _apply(bone_rel, pr.v[..., C + S + bad])
        if turn_v:
            v_parts.append(mesh_v)
    else:
        mesh = np.zeros((3, F, P, 0), pr.v.dtype)
        if turn_v:
            v_parts.append(np.zeros((3, F, P, 0), pr.v.dtype))
    x = np.concatenate([cap, sph, mesh], axis=-1)
    return x, (np.concatenate(v_parts, axis=-1) if turn_v else pr.v)


def repose(proj: Projections, user: PosedSurface, avatar: PosedSurface) -> np.ndarray:
    """x'_ij: the user's projections re-posed on the avatar's elements from their surface
    coordinates (capsule: axial fraction + direction in the bone frame; sphere: direction;
    triangle: barycentric). A mesh whose triangles differ between user and avatar falls back to
    the element bone's frame, scaled by the bone length ratio. Returns (F, P, E, 3)."""
    m = np.moveaxis
    pr = _Proj(m(proj.x, -1, 0), m(proj.v, -1, 0), proj.dist, proj.factor, proj.cap_t, m(proj.cap_dir, -1, 0),
               m(proj.sph_dir, -1, 0), proj.tri_index, m(proj.tri_bary, -1, 0))
    return m(_repose(pr, user, avatar)[0], 0, -1)


# --- weights -----------------------------------------------------------------------------------

def raw_weights(proj: Projections, heights: np.ndarray, exclude: np.ndarray | None = None,
                falloff: float = 2.0):
    """Raw contributions Λ (Delahaye 2023, appendix C): factor / |v|^2 per element, 1 / h^2 for the
    floor, distances floored at MIN_DISTANCE. `exclude` (P, E) bool zeroes own-chain elements.
    `falloff` is the exponent (the paper's 2; larger favours the closest element more).
    Returns (Λ (F, P, E), Λ_floor (F, P))."""
    if falloff == 2.0:
        lam = proj.factor / np.maximum(proj.dist * proj.dist, MIN_DISTANCE ** 2)
        floor = 1.0 / np.maximum(heights * heights, MIN_DISTANCE ** 2)
    else:
        lam = proj.factor / np.maximum(proj.dist, MIN_DISTANCE) ** falloff
        floor = 1.0 / np.maximum(np.abs(heights), MIN_DISTANCE) ** falloff
    if exclude is not None:
        lam = np.where(exclude, 0.0, lam)
    return lam, floor


def normalise(lam: np.ndarray, lam_floor: np.ndarray):
    """The two normalisations of eq. 1: λ over the elements without the floor, λg with it.
    Returns (λ (F, P, E), λg (F, P, E), λg_floor (F, P)); λ is 0 where no element has weight."""
    s = lam.sum(-1)
    sg = s + lam_floor
    lam_n = np.divide(lam, s[..., None], out=np.zeros_like(lam), where=s[..., None] > 0)
    return lam_n, lam / sg[..., None], lam_floor / sg


# --- retro-projection ----------------------------------------------------------------------------

ZERO_BONE = len(GRAPH_BONES)  # a zero vector: the one entry of an empty path


@dataclass
class _Plan:
    exclude: np.ndarray  # (P, E)
    chain_pe: np.ndarray  # (N,) flat (target, element) index p * E + e of each chain, ascending
    dense: bool  # every pair has a chain (chain_pe is 0..P*E-1: no gather needed)
    chain_root: np.ndarray  # (N,) index into GRAPH_NODES of the element's root
    # Paths by position: with the chains in `order` (longest path first), the chains that have a
    # j-th bone are a prefix, and slot_bones[j] lists those j-th bones: a sum over every chain's
    # bones is a few prefix additions, with no gather of v̂ per bone.
    order: np.ndarray  # (N,)
    unorder: np.ndarray  # (N,) its inverse
    slot_bones: list[np.ndarray]
    entry_bone: np.ndarray  # every GRAPH_BONES index used (for the joint check)
    floor_bone: list[np.ndarray]  # per side: entries of the paths ankle_s -> target
    floor_starts: list[np.ndarray]  # per side: (P,)


def _entries(paths):
    bones, starts = [], []
    for path in paths:
        starts.append(len(bones))
        bones += list(path) or [ZERO_BONE]
    return np.array(bones, int), np.array(starts, int)


@lru_cache(maxsize=64)
def _plan(target_names: tuple[str, ...], element_ids: tuple[str, ...], roots: tuple[str, ...]) -> _Plan:
    """Everything frame-independent: exclusions and kinematic paths as index arrays (Delahaye 2023,
    appendix C: "chains are pre-computed and stored so that the tree search is not performed in
    every frame"). Excluded (own-chain) pairs have no chain at all: their weight is zero."""
    P, E = len(target_names), len(element_ids)
    exclude = np.zeros((P, E), bool)
    pe, cr, paths = [], [], []
    for p, name in enumerate(target_names):
        own = own_chain_elements(name)
        for e, eid in enumerate(element_ids):
            if eid in own:
                exclude[p, e] = True
                continue
            paths.append(kinematic_path(roots[e], name))
            pe.append(p * E + e)
            cr.append(GRAPH_NODES.index(roots[e]))
    order = np.array(sorted(range(len(paths)), key=lambda i: -len(paths[i])), int)
    longest = len(paths[order[0]]) if paths else 0
    slots = [np.array([paths[i][j] for i in order if len(paths[i]) > j], int) for j in range(longest)]
    used = np.array(sorted({b for path in paths for b in path}), int)
    floor_bone, floor_starts = [], []
    for s in sk.SIDES:
        b, st = _entries([kinematic_path(f"ankle_{s}", name) for name in target_names])
        floor_bone.append(b)
        floor_starts.append(st)
    return _Plan(exclude, np.array(pe, int), len(pe) == P * E, np.array(cr, int), order, np.argsort(order), slots,
                 used, floor_bone, floor_starts)


def _bone_vectors(surface: PosedSurface, bones: dict[str, np.ndarray] | None, F: int, dtype=float) -> np.ndarray:
    """(3, F, NB + 1) vectors of GRAPH_BONES (from `bones` if given, else from the surface's
    joints), plus the zero bone."""
    out = np.zeros((3, F, len(GRAPH_BONES) + 1), dtype)
    for i, name in enumerate(GRAPH_BONES):
        if bones is not None and name in bones:
            out[:, :, i] = np.asarray(bones[name], float).T
            continue
        b = sk.BONE_BY_NAME[name]
        if b.head in surface.joints and b.tail in surface.joints:
            out[:, :, i] = (surface.joints[b.tail] - surface.joints[b.head]).T
    return out


def _node_positions(surface: PosedSurface, F: int, dtype=float) -> np.ndarray:
    out = np.zeros((3, F, len(GRAPH_NODES)), dtype)
    for i, name in enumerate(GRAPH_NODES):
        if name in surface.joints:
            out[:, :, i] = surface.joints[name].T
    return out


def _check_joints(surface: PosedSurface, plan: _Plan, target_names, who: str):
    need = {GRAPH_NODES[i] for i in np.unique(plan.chain_root)} | {"ankle_l", "ankle_r"}
    for idx in np.unique(np.concatenate([plan.entry_bone, *plan.floor_bone])):
        if idx == ZERO_BONE:
            continue
        b = sk.BONE_BY_NAME[GRAPH_BONES[idx]]
        need |= {b.head, b.tail}
    missing = sorted(need - set(surface.joints))
    if missing:
        raise BodyCalError(f"the {who} pose lacks joints needed by the egocentric mapping: {', '.join(missing[:6])}",
                           hint="pose every joint of the kinematic paths (pose_surface joints)")


def retarget_points(user_pts: np.ndarray, target_names: list[str], user_surface: PosedSurface,
                    avatar_surface: PosedSurface, user_bones: dict[str, np.ndarray] | None = None,
                    avatar_bones: dict[str, np.ndarray] | None = None, *, floor: bool = True, falloff: float = 2.0,
                    turn_v: bool = False, chunk: int | None = None,
                    penetration_tolerance: float = PENETRATION_TOLERANCE, details: dict | None = None,
                    dtype=np.float64) -> np.ndarray:
    """Retro-project the user's targets onto the avatar (Delahaye 2023, appendix C, eq. 1 and 2).

    user_pts: (F, P, 3) the user's target positions, one column per name of `target_names`
    (canonical joints on the kinematic tree: wrists, elbows, ankles, knees, fingertips, skull base).
    user_surface / avatar_surface: the two bodies posed for the same F frames with the same
    element_ids (the avatar posed by FK from the user's bone rotations, DESIGN.md §1 step 2).
    user_bones / avatar_bones: optional bone -> (F, 3) vectors (tail - head) overriding the ones
    derived from the posed joints; only the user's directions and the avatar's lengths are used
    (τ' = the avatar's bone lengths along the user's current bone directions).
    floor: include the floor contribution (the vertical singularity handled as eq. 1).
    falloff: exponent of the raw weights' distance law (paper: 2); the invariants hold for any.
    turn_v: carry each v_ij by its element's local frame (bone / triangle frame) onto the avatar's
    instead of adding it as a world vector (eq. 1 as printed); see _repose.
    details: if a dict is given, it receives the weights of every frame ("lam", "lam_g",
    "lam_g_floor", "ratio" = τ'/τ, each (F, P, E) or (F, P)) for inspection.
    chunk: frames per block (default: sized so a block's temporaries stay in the CPU caches).
    dtype: float64, or float32 (see prepare_targets); the result has this dtype.

    Returns (F, P, 3): the avatar's targets p'_j. Equivalent to
    `prepare_targets(...).map(avatar_surface, ...)`, which maps the same user targets onto
    several avatar poses without projecting them on the user again."""
    prepared = prepare_targets(user_pts, target_names, user_surface, user_bones, floor=floor, falloff=falloff,
                               chunk=chunk, penetration_tolerance=penetration_tolerance, dtype=dtype)
    return prepared.map(avatar_surface, avatar_bones, turn_v=turn_v, details=details)


BLOCK_PAIRS = 20_000  # frames x targets x elements per block: its temporaries stay in the L2 cache


@dataclass
class _UserBlock:
    """The user's side of one block of frames of one target group (see PreparedTargets)."""

    start: int
    stop: int
    p: np.ndarray  # (F, P, 3) the targets
    us: PosedSurface  # the user's surface for these frames and the group's elements
    pr: _Proj
    lam: np.ndarray  # (F, P, E) λ
    lam_g: np.ndarray  # (F, P, E) λg
    lam_gf: np.ndarray  # (F, P) λg of the floor
    vhat: np.ndarray  # (3, F, N) unit v of each chain
    tau: np.ndarray  # (F, N) τ
    dots: list  # per path slot (_Plan.slot_bones), (n, F) |v̂·b_k| (τ' weighs them by the bone length ratios)


@dataclass
class _Group:
    """Targets that exclude the same elements (own_chain_elements), mapped on the others only:
    an excluded pair has no weight, so projecting on it is wasted work."""

    targets: np.ndarray  # indices into the target names
    names: tuple[str, ...]
    elements: np.ndarray | None  # indices of the elements kept (None: all)
    plan: _Plan
    blocks: list[_UserBlock]


class PreparedTargets:
    """The user's side of the egocentric mapping (Delahaye 2023, appendix C) of F frames of targets:
    their projections on the user's surface, the weights of eq. 1 and the user's τ of eq. 2,
    which do not depend on the avatar. `map` finishes the mapping against an avatar pose; the
    pipeline maps the arms twice (against the arms where the first pass put them) and pays for
    the user's side once. Built by `prepare_targets`."""

    def __init__(self, pts, names, user_surface, ub, floor, groups):
        self.pts, self.names, self.user_surface, self.floor, self.groups = pts, names, user_surface, floor, groups
        self.ulen = np.sqrt(_dot(ub, ub))  # (F, NB + 1)
        self.ubt = np.ascontiguousarray(ub.transpose(0, 2, 1))  # (3, NB + 1, F): bones first for the gathers
        self._bone_tau_a = None  # (length ratios, {(group, block): τ' over the bones}) of the last map

    @property
    def frames(self) -> int:
        return self.pts.shape[0]

    def map(self, avatar_surface: PosedSurface, avatar_bones: dict[str, np.ndarray] | None = None, *,
            turn_v: bool = False, details: dict | None = None) -> np.ndarray:
        """The avatar's targets (F, P, 3) for the avatar posed as `avatar_surface` (same frames and
        element_ids as the user's surface); see retarget_points."""
        us = self.user_surface
        if us.element_ids != avatar_surface.element_ids:
            raise BodyCalError("user and avatar surfaces have different elements",
                               hint="pose both with element_ids=common_elements(user_model, avatar_model)")
        F = self.frames
        if avatar_surface.frames != F:
            raise BodyCalError(f"targets have {F} frames, avatar surface {avatar_surface.frames}")
        for g in self.groups:
            _check_joints(avatar_surface, g.plan, g.names, "avatar")
        dtype = self.pts.dtype
        ab = _bone_vectors(avatar_surface, avatar_bones, F, dtype)
        lratio = np.divide(np.sqrt(_dot(ab, ab)), self.ulen, out=np.ones_like(self.ulen), where=self.ulen > 1e-12)
        lrt = np.ascontiguousarray(lratio.T)
        # τ' over the bones depends on the avatar's bone lengths only: the same for poses that
        # differ by rotations (the pipeline's arm passes), so it is kept for the next call.
        cached = self._bone_tau_a if self._bone_tau_a is not None and np.allclose(
            self._bone_tau_a[0], lrt, rtol=1e-12, atol=0.0) else None
        bone_tau_a = (lrt, cached[1] if cached else {})
        self._bone_tau_a = bone_tau_a
        nodes_a = _node_positions(avatar_surface, F, dtype)
        avatar_surface = avatar_surface.astype(dtype)
        out = np.empty_like(self.pts)
        if details is not None:
            E = len(us.element_ids)
            P = len(self.names)
            details.update(lam=np.zeros((F, P, E)), lam_g=np.zeros((F, P, E)), lam_g_floor=np.zeros((F, P)),
                           ratio=np.ones((F, P, E)))
        for gi, g in enumerate(self.groups):
            av = avatar_surface if g.elements is None else avatar_surface.select(g.elements)
            for bi, b in enumerate(g.blocks):
                s, e = b.start, b.stop
                if (gi, bi) not in bone_tau_a[1]:
                    bone_tau_a[1][gi, bi] = _bone_tau(b, g.plan, lrt[:, s:e])
                res, ratio = _map_block(b, g.plan, av.take(s, e), self.ubt[:, :, s:e], lrt[:, s:e],
                                        bone_tau_a[1][gi, bi], nodes_a[:, s:e], self.floor, turn_v)
                out[s:e, g.targets] = res
                if details is not None:
                    cols = slice(None) if g.elements is None else g.elements
                    rows = np.ix_(np.arange(s, e), g.targets, np.arange(E)[cols])
                    details["lam"][rows] = b.lam
                    details["lam_g"][rows] = b.lam_g
                    details["ratio"][rows] = ratio
                    details["lam_g_floor"][np.ix_(np.arange(s, e), g.targets)] = b.lam_gf
        return out


def prepare_targets(user_pts: np.ndarray, target_names: list[str], user_surface: PosedSurface,
                    user_bones: dict[str, np.ndarray] | None = None, *, floor: bool = True, falloff: float = 2.0,
                    chunk: int | None = None, penetration_tolerance: float = PENETRATION_TOLERANCE,
                    dtype=np.float64) -> PreparedTargets:
    """The user's side of `retarget_points` (same arguments), to `map` onto avatar poses.
    `dtype` float32 maps in single precision (about twice as fast; positions agree with float64
    to a few micrometres, the pipeline's choice)."""
    dtype = np.dtype(dtype)
    if dtype not in (np.float32, np.float64):
        raise BodyCalError(f"the mapping computes in float32 or float64, not {dtype}")
    pts = np.asarray(user_pts, dtype)
    if pts.ndim != 3 or pts.shape[2] != 3 or pts.shape[1] != len(target_names):
        raise BodyCalError(f"targets must be (F, {len(target_names)}, 3), got {pts.shape}")
    F = pts.shape[0]
    if user_surface.frames != F:
        raise BodyCalError(f"targets have {F} frames, user surface {user_surface.frames}")
    ub = _bone_vectors(user_surface, user_bones, F, dtype)
    ubt = np.ascontiguousarray(ub.transpose(0, 2, 1))
    nodes_u = _node_positions(user_surface, F, dtype)
    user_surface = user_surface.astype(dtype)
    ids = user_surface.element_ids
    rows: dict[frozenset, list[int]] = {}
    for i, name in enumerate(target_names):
        rows.setdefault(own_chain_elements(name) & set(ids), []).append(i)
    groups = []
    for excluded, members in rows.items():
        keep = np.array([k for k, eid in enumerate(ids) if eid not in excluded], int)
        # Decision: a target with every element excluded keeps them all (all weights zero: the
        # user's horizontal position, the floor's vertical one, as before grouping).
        sub = user_surface if not excluded or not len(keep) else user_surface.select(keep)
        names = tuple(target_names[i] for i in members)
        plan = _plan(names, tuple(sub.element_ids), tuple(sub.element_roots))
        _check_joints(sub, plan, names, "user")
        step = int(chunk) if chunk else max(32, BLOCK_PAIRS // max(1, len(members) * len(sub.element_ids)))
        step = max(1, step)
        blocks = []
        for s in range(0, F, step):
            e = min(F, s + step)
            blocks.append(_prepare_block(s, e, pts[s:e, members], plan, sub.take(s, e), ubt[:, :, s:e],
                                         nodes_u[:, s:e], floor, penetration_tolerance, falloff))
        groups.append(_Group(np.array(members, int), names, None if sub is user_surface else keep, plan, blocks))
    return PreparedTargets(pts, list(target_names), user_surface, ub, floor, groups)


def _prepare_block(start, stop, p, plan: _Plan, us: PosedSurface, ub, nodes_u, floor, tol, falloff) -> _UserBlock:
    F, P = p.shape[:2]
    pr = _project(p, us, tol)
    lam_raw, floor_raw = raw_weights(pr, p[..., 2], plan.exclude, falloff)
    if not floor:
        floor_raw = np.zeros_like(floor_raw)
    lam, lam_g, lam_gf = normalise(lam_raw, floor_raw)
    # Kinematic normalisation (eq. 2, DESIGN.md Decision: absolute values), the user's τ for
    # every chain: τ = Σ_k |v̂·b_k| + |v̂·(x - r)|.
    vhat, _ = _normalised(_chains(pr.v, plan), 0.0)  # (3, F, N)
    vt = np.ascontiguousarray(np.take(vhat, plan.order, axis=2).transpose(0, 2, 1))  # (3, N, F), longest first
    tau = np.zeros(vt.shape[1:], vt.dtype)
    dots = []
    for bones in plan.slot_bones:
        n = len(bones)
        dots.append(np.abs(_dot(vt[:, :n], np.take(ub, bones, axis=1))))
        tau[:n] += dots[-1]
    tau = np.take(tau, plan.unorder, axis=0).T
    tau += np.abs(_dot(vhat, _chains(pr.x, plan) - np.take(nodes_u, plan.chain_root, axis=2)))
    pr.dist = pr.factor = None  # spent on the weights
    return _UserBlock(start, stop, p, us, pr, lam, lam_g, lam_gf, vhat, tau, dots)


def _chains(a, plan: _Plan):
    """(3, F, P, E) -> (3, F, N): the pairs that have a chain (a view when all do)."""
    flat = a.reshape(a.shape[:2] + (-1,))
    return flat if plan.dense else np.take(flat, plan.chain_pe, axis=2)


def _bone_tau(b: _UserBlock, plan: _Plan, lratio) -> np.ndarray:
    """(F, N) Σ_k |v̂·b_k| L'_k/L_k over each chain's bones: τ' without its extremity term."""
    out = np.zeros(b.tau.shape[::-1], b.tau.dtype)
    for bones, d in zip(plan.slot_bones, b.dots):
        out[:len(bones)] += d * np.take(lratio, bones, axis=0)
    return np.take(out, plan.unorder, axis=0).T


def _map_block(b: _UserBlock, plan: _Plan, av: PosedSurface, ub, lratio, bone_tau_a, nodes_a, floor, turn_v):
    """One block of frames against the avatar: eq. 1 with τ'/τ of eq. 2 (`bone_tau_a`: `_bone_tau`).
    Returns ((F, P, 3), ratio)."""
    p, us, pr = b.p, b.us, b.pr
    F, P = p.shape[:2]
    E = pr.v.shape[-1]
    x_av, v_av = _repose(pr, us, av, turn_v)  # (3, F, P, E)
    # τ' = Σ_k |v̂·b_k| L'_k/L_k + |v̂·(x' - r')|
    tau_a = bone_tau_a + np.abs(_dot(b.vhat, _chains(x_av, plan) - np.take(nodes_a, plan.chain_root, axis=2)))
    chain_ratio = np.divide(tau_a, b.tau, out=np.ones_like(b.tau), where=b.tau > 1e-12)
    if plan.dense:
        ratio = chain_ratio.reshape(F, P, E)
    else:
        ratio = np.ones((F, P * E), chain_ratio.dtype)
        ratio[:, plan.chain_pe] = chain_ratio
        ratio = ratio.reshape(F, P, E)

    est = x_av + v_av * ratio  # (3, F, P, E)
    lam = b.lam
    horizontal = np.stack([(est[i] * lam).sum(-1) for i in range(2)], axis=-1)
    # No element with weight (all excluded): keep the user's horizontal position.
    none = lam.sum(-1) <= 0
    if none.any():
        horizontal = np.where(none[..., None], p[..., :2], horizontal)
    vertical = (est[2] * b.lam_g).sum(-1)
    if floor:
        # h'_j = h_j τ'/τ along the path from the supporting (lower) ankle, v̂ = up (DESIGN.md §5).
        ratios = []
        for side, name in enumerate(sk.SIDES):
            ent, st = plan.floor_bone[side], plan.floor_starts[side]
            uz = np.abs(np.take(ub[2], ent, axis=0))  # (K, F)
            tf = np.add.reduceat(uz, st, axis=0).T + np.abs(us.joints[f"ankle_{name}"][:, 2])[:, None]
            tfa = np.add.reduceat(uz * np.take(lratio, ent, axis=0), st, axis=0).T
            tfa += np.abs(av.joints[f"ankle_{name}"][:, 2])[:, None]
            ratios.append(np.divide(tfa, tf, out=np.ones_like(tf), where=tf > 1e-12))
        # Decision: the two feet's ratios blended by which ankle is lower (SUPPORT_BLEND): with
        # both feet on the floor, picking the lower ankle flips with millimetres of noise, and
        # each flip moved every target's height by h (τ'_l/τ_l - τ'_r/τ_r), up to a few mm.
        w_left = 0.5 + 0.5 * np.tanh((us.joints["ankle_r"][:, 2] - us.joints["ankle_l"][:, 2]) / SUPPORT_BLEND)
        fratio = ratios[1] + w_left[:, None] * (ratios[0] - ratios[1])
        vertical = vertical + p[..., 2] * fratio * b.lam_gf
    return np.concatenate([horizontal, vertical[..., None]], axis=-1), ratio
