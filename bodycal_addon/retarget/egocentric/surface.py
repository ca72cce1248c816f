"""The posed surface: every surface element of a body model placed per frame from the canonical joint
positions and bone frames (Delahaye 2023, appendix C)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from functools import lru_cache

import numpy as np

from ...body import skeleton as sk
from ...body.skeleton import BONE_INDEX as BI
from ...body.skeleton import JOINT_INDEX as JI
from ...body.skeleton import JOINTS
from ...core.errors import BodyCalError
from ...core.transforms import cross, frame_from_axes, stacks_mul
from .graph import element_root


class JointTable(Mapping):
    """Every canonical joint of F frames as one (F, J, 3) array (`skeleton.JOINTS` order), read like
    the dict of (F, 3) arrays `pose_surface` takes (`table[name]`): what `SurfacePoser` gives, so
    the mapping gathers its joints by index instead of by name."""

    def __init__(self, array: np.ndarray):
        self.array = array

    def __getitem__(self, name: str) -> np.ndarray:
        return self.array[:, JI[name]]

    def __contains__(self, name) -> bool:
        return name in JI

    def __iter__(self):
        return iter(JOINTS)

    def __len__(self) -> int:
        return len(JOINTS)

    def take(self, s: slice) -> JointTable:
        return JointTable(self.array[s])


def _take_joints(joints, s: slice):
    return joints.take(s) if isinstance(joints, JointTable) else {k: v[s] for k, v in joints.items()}


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
    tri_normal: np.ndarray | None  # (F, T, 3) unit outward normals (None: not posed, SurfacePoser.pose)
    tri_elem: np.ndarray  # (T,) element index (into element_ids) of each triangle
    mesh_slices: list[tuple[int, int]]  # per mesh element, its triangle range in `tri`
    mesh_head: np.ndarray  # (F, M, 3) head joint of each mesh element's bone
    mesh_rot: np.ndarray  # (F, M, 3, 3) frame of each mesh element's bone
    mesh_scale: np.ndarray  # (M,) length of each mesh element's bone (re-posing fallback)
    joints: dict[str, np.ndarray]  # canonical joint -> (F, 3)
    notes: list[str] = field(default_factory=list)
    # dtype -> (caps_radius, sph_radius, mesh_scale) in it: the frame-independent fields converted
    # once for every pose of a SurfacePoser (shared between its poses; None: converted each time)
    constants: dict | None = None

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
                            self.sph_radius, self.tri[s], None if self.tri_normal is None else self.tri_normal[s],
                            self.tri_elem, self.mesh_slices, self.mesh_head[s], self.mesh_rot[s], self.mesh_scale,
                            _take_joints(self.joints, s), self.notes, self.constants)

    def astype(self, dtype, normals: bool = True) -> PosedSurface:
        """The surface with its placed geometry in `dtype` (itself if already; joints unchanged).
        `normals` False leaves the triangles' normals as they are (a caller that reads none)."""
        if self.caps_head.dtype == dtype:
            return self
        if self.constants is not None and dtype in self.constants:
            caps_radius, sph_radius, mesh_scale = self.constants[dtype]
        else:
            caps_radius, sph_radius, mesh_scale = (np.asarray(a, dtype) for a in (self.caps_radius, self.sph_radius,
                                                                                 self.mesh_scale))
            if self.constants is not None:
                self.constants[dtype] = (caps_radius, sph_radius, mesh_scale)
        normal = np.asarray(self.tri_normal, dtype) if normals and self.tri_normal is not None else self.tri_normal
        return PosedSurface(self.element_ids, self.element_bones, self.element_roots, np.asarray(self.caps_head, dtype),
                            np.asarray(self.caps_tail, dtype), np.asarray(self.caps_rot, dtype), caps_radius,
                            np.asarray(self.sph_center, dtype), np.asarray(self.sph_rot, dtype), sph_radius,
                            np.asarray(self.tri, dtype), normal, self.tri_elem, self.mesh_slices,
                            np.asarray(self.mesh_head, dtype), np.asarray(self.mesh_rot, dtype), mesh_scale,
                            self.joints, self.notes, self.constants)

    def select(self, keep) -> PosedSurface:
        """The elements at indices `keep` (ascending: capsules, spheres, meshes stay in order)."""
        ci, si, mi, rows, elem, slices = _selection(tuple(int(k) for k in keep), self.counts,
                                                    tuple(self.mesh_slices))

        def cols(a, idx):  # np.take along an inner axis is ~2x faster than fancy indexing
            return a.take(idx, axis=1)

        return PosedSurface([self.element_ids[k] for k in keep], [self.element_bones[k] for k in keep],
                            [self.element_roots[k] for k in keep], cols(self.caps_head, ci), cols(self.caps_tail, ci),
                            cols(self.caps_rot, ci), self.caps_radius[ci], cols(self.sph_center, si),
                            cols(self.sph_rot, si), self.sph_radius[si], cols(self.tri, rows),
                            None if self.tri_normal is None else cols(self.tri_normal, rows), elem, slices,
                            cols(self.mesh_head, mi), cols(self.mesh_rot, mi), self.mesh_scale[mi], self.joints,
                            self.notes)


@lru_cache(maxsize=256)
def _selection(keep: tuple, counts: tuple, mesh_slices: tuple):
    """PosedSurface.select's index arrays for elements `keep`, once per element set."""
    keep = np.asarray(keep, int)
    C, S, _ = counts
    ci, si, mi = keep[keep < C], keep[(keep >= C) & (keep < C + S)] - C, keep[keep >= C + S] - C - S
    rows, elem, slices = [], [], []
    for k, m in enumerate(mi):
        a, b = mesh_slices[m]
        slices.append((len(rows), len(rows) + b - a))
        rows += range(a, b)
        elem += [len(ci) + len(si) + k] * (b - a)
    return ci, si, mi, np.array(rows, int), np.array(elem, int), slices


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
    posing = _Posing(model, {k: np.asarray(v, float) for k, v in joints.items()}, bone_rotations, frames)
    wanted = element_ids if element_ids is not None else [e.id for e in model.surface]
    caps, sphs, meshes, notes = _posable_elements(posing, wanted)
    capsules = _pose_capsules(posing, caps)
    spheres = _pose_spheres(posing, sphs)
    mesh_bones, mesh_fields = _pose_meshes(posing, meshes, first=len(caps) + len(sphs))
    ordered, bones = caps + sphs + meshes, [e.bone for e in caps + sphs] + mesh_bones
    return PosedSurface(
        element_ids=[e.id for e in ordered], element_bones=bones,
        element_roots=[element_root(e.id, b) for e, b in zip(ordered, bones)],
        **capsules, **spheres, **mesh_fields, joints=posing.joints, notes=notes)


@dataclass
class _Posing:
    """What the passes of `pose_surface` share: the model, the joints (F, 3) as floats, the bone
    frames given, the frame count, and the bone frames the mesh pass made (made once a bone)."""

    model: object
    joints: dict[str, np.ndarray]
    bone_rotations: dict[str, np.ndarray]
    frames: int
    rot_cache: dict[str, np.ndarray] = field(default_factory=dict)

    def rotation(self, bone: str) -> np.ndarray:
        """(F, 3, 3) frame of `bone`: given, else from its joints and rest right (`_rotation`)."""
        return _rotation(bone, self.joints, self.bone_rotations, self.model, self.frames)

    def cached_rotation(self, bone: str) -> np.ndarray:
        if bone not in self.rot_cache:
            self.rot_cache[bone] = self.rotation(bone)
        return self.rot_cache[bone]

    def head(self, bone: str) -> np.ndarray:
        """(F, 3) position of `bone`'s head joint."""
        return self.joints[_head_of(bone, self.model)]

    def stack(self, arrs: list[np.ndarray], shape: tuple) -> np.ndarray:
        """Per-element (F, *shape) arrays as (F, E, *shape); (F, 0, *shape) for none."""
        return np.stack(arrs, axis=1) if arrs else np.zeros((self.frames, 0) + shape)


def _posable_elements(posing: _Posing, wanted: list[str]) -> tuple[list, list, list, list[str]]:
    """Sorting pass: the `wanted` elements as (capsules, spheres, meshes, notes), each list in the
    order wanted; an element whose joints, radii or points are missing is left out and named in
    the notes. Raises for an id the model does not have."""
    model, joints = posing.model, posing.joints
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
    return caps, sphs, meshes, notes


def _pose_capsules(posing: _Posing, caps: list) -> dict[str, np.ndarray]:
    """Capsules pass: PosedSurface's `caps_*` fields. A capsule runs from its bone's head joint to
    its tail joint, moved by the element's axis offsets in the bone's frame."""
    joints, model = posing.joints, posing.model
    caps_rot = posing.stack([posing.rotation(e.bone) for e in caps], (3, 3))
    caps_off = np.array([e.axis_offsets() for e in caps], float).reshape(-1, 2, 3)
    caps_head = posing.stack([joints[sk.BONE_BY_NAME[e.bone].head] for e in caps], (3,))
    caps_tail = posing.stack([joints[sk.BONE_BY_NAME[e.bone].tail] for e in caps], (3,))
    if np.any(caps_off):  # axes off the bone line (bodymodel: axis_head / axis_tail)
        caps_head = caps_head + np.einsum("fcij,cj->fci", caps_rot, caps_off[:, 0])
        caps_tail = caps_tail + np.einsum("fcij,cj->fci", caps_rot, caps_off[:, 1])
    caps_radius = np.array([[model.bones[e.bone].radius_head, model.bones[e.bone].radius_tail] for e in caps],
                           float).reshape(-1, 2)
    return {"caps_head": caps_head, "caps_tail": caps_tail, "caps_rot": caps_rot, "caps_radius": caps_radius}


def _pose_spheres(posing: _Posing, sphs: list) -> dict[str, np.ndarray]:
    """Spheres pass: PosedSurface's `sph_*` fields; a centre is local to its bone's frame."""
    sph_rot = posing.stack([posing.rotation(e.bone) for e in sphs], (3, 3))
    sph_origin = posing.stack([posing.head(e.bone) for e in sphs], (3,))
    sph_local = np.array([e.center for e in sphs], float).reshape(-1, 3)
    sph_center = sph_origin + np.einsum("fsij,sj->fsi", sph_rot, sph_local)
    sph_radius = np.array([e.radius for e in sphs], float)
    return {"sph_center": sph_center, "sph_rot": sph_rot, "sph_radius": sph_radius}


def _pose_meshes(posing: _Posing, meshes: list, first: int) -> tuple[list[str], dict]:
    """Meshes pass: (each mesh's bone, PosedSurface's `tri*`, `mesh_*` fields). Mesh points are
    local to their bones; the triangles are gathered from them (`_mesh_triangles`). `first` is the
    element index of the first mesh (after the capsules and spheres)."""
    tri, tri_elem, slices = _mesh_triangles(posing, meshes, first)
    n = cross(tri[:, :, 1] - tri[:, :, 0], tri[:, :, 2] - tri[:, :, 0])
    nn = np.linalg.norm(n, axis=-1, keepdims=True)
    tri_normal = np.divide(n, nn, out=np.zeros_like(n), where=nn > 1e-15)

    # A mesh's own bone (its frame is the re-posing fallback); an element that names no single
    # bone (e.g. "spine_*") takes its first point's.
    model = posing.model
    mesh_bones = [e.bone if e.bone in model.bones or e.bone in sk.BONE_BY_NAME else next(iter(e.points.values())).bone
                  for e in meshes]
    mesh_head = posing.stack([posing.head(b) for b in mesh_bones], (3,))
    mesh_rot = posing.stack([posing.cached_rotation(b) for b in mesh_bones], (3, 3))
    mesh_scale = np.array([model.bones[b].length if b in model.bones else 1.0 for b in mesh_bones], float)
    return mesh_bones, {"tri": tri, "tri_normal": tri_normal, "tri_elem": np.array(tri_elem, int),
                        "mesh_slices": slices, "mesh_head": mesh_head, "mesh_rot": mesh_rot, "mesh_scale": mesh_scale}


def _mesh_rows(meshes: list, first: int) -> tuple[list, list, list, list, list[tuple[int, int]]]:
    """Every mesh's points in one list (their bones, their local positions), each triangle as rows
    of that list, the element index of each triangle (`first` for the first mesh) and each mesh's
    triangle range."""
    point_bones, point_local, tri_rows, tri_elem, slices = [], [], [], [], []
    for m, e in enumerate(meshes):
        names = list(e.points)
        base = len(point_bones)
        point_bones += [e.points[n].bone for n in names]
        point_local += [e.points[n].local for n in names]
        start = len(tri_rows)
        tri_rows += [[base + names.index(n) for n in t] for t in e.triangles]
        tri_elem += [first + m] * len(e.triangles)
        slices.append((start, len(tri_rows)))
    return point_bones, point_local, tri_rows, tri_elem, slices


def _mesh_triangles(posing: _Posing, meshes: list, first: int) -> tuple[np.ndarray, list[int], list[tuple[int, int]]]:
    """(triangle corners (F, T, 3, 3), element index of each triangle, each mesh's triangle range):
    every point of every mesh placed in one gather, per bone."""
    frames, joints = posing.frames, posing.joints
    point_bones, point_local, tri_rows, tri_elem, slices = _mesh_rows(meshes, first)
    if not point_bones:
        return np.zeros((frames, 0, 3, 3)), tri_elem, slices
    # Per bone, its points in one BLAS call (frames stay the outer axis: C order throughout).
    world = np.empty((frames, len(point_bones), 3))
    local = np.array(point_local, float)
    for b in dict.fromkeys(point_bones):
        rows = np.array([i for i, pb in enumerate(point_bones) if pb == b])
        rot = np.ascontiguousarray(posing.cached_rotation(b))
        world[:, rows] = joints[_head_of(b, posing.model)][:, None, :] + (
            rot.reshape(-1, 3) @ local[rows].T).reshape(frames, 3, len(rows)).swapaxes(1, 2)
    return world.take(np.array(tri_rows), axis=1), tri_elem, slices  # (F, T, 3, 3), C order


FEW_FRAMES = 16  # SurfacePoser.pose: fewer frames than this pose the mesh points in one padded product


class SurfacePoser:
    """`pose_surface` of one body model and element list, prepared once: which joints, bone frames
    and local points each element takes, as index arrays, so posing F frames is a few gathers and
    stacked products (the same values as `pose_surface`, bit for bit; fewer than FEW_FRAMES frames
    to rounding). Every element's bones must be canonical bones; `pose` takes all the canonical
    joints (F, J, 3) and bone frames (F, B, 3, 3)."""

    def __init__(self, model, element_ids: list[str]):
        joints = {j: np.zeros((1, 3)) for j in JOINTS}
        posing = _Posing(model, joints, {}, 1)
        caps, sphs, meshes, self.notes = _posable_elements(posing, element_ids)
        ordered = caps + sphs + meshes
        mesh_bones = [e.bone if e.bone in model.bones or e.bone in sk.BONE_BY_NAME
                      else next(iter(e.points.values())).bone for e in meshes]
        self.element_ids = [e.id for e in ordered]
        self.element_bones = [e.bone for e in caps + sphs] + mesh_bones
        self.element_roots = [element_root(e.id, b) for e, b in zip(ordered, self.element_bones)]
        bones = [e.bone for e in caps + sphs] + mesh_bones + [p.bone for e in meshes for p in e.points.values()]
        if any(b not in BI for b in bones):
            raise BodyCalError("a surface element rides on a bone that is not canonical", source=model.name,
                               hint="pose it with pose_surface")
        self.cap_bone = np.array([BI[e.bone] for e in caps], int)
        self.cap_ends = [np.array([JI[getattr(sk.BONE_BY_NAME[e.bone], end)] for e in caps], int)
                         for end in ("head", "tail")]
        self.cap_off = np.array([e.axis_offsets() for e in caps], float).reshape(-1, 2, 3)
        self.cap_offset = bool(np.any(self.cap_off))
        self.cap_radius = np.array([[model.bones[e.bone].radius_head, model.bones[e.bone].radius_tail] for e in caps],
                                   float).reshape(-1, 2)
        self.sph_bone = np.array([BI[e.bone] for e in sphs], int)
        self.sph_head = np.array([JI[_head_of(e.bone, model)] for e in sphs], int)
        self.sph_local = np.array([e.center for e in sphs], float).reshape(-1, 3)
        self.sph_radius = np.array([e.radius for e in sphs], float)
        self.mesh_bone = np.array([BI[b] for b in mesh_bones], int)
        self.mesh_head = np.array([JI[_head_of(b, model)] for b in mesh_bones], int)
        self.mesh_scale = np.array([model.bones[b].length if b in model.bones else 1.0 for b in mesh_bones], float)
        self.constants: dict = {}  # PosedSurface.constants, shared by every pose
        self._mesh_points(model, meshes, len(caps) + len(sphs))

    def _mesh_points(self, model, meshes: list, first: int) -> None:
        """`_mesh_triangles`' gather, prepared: the mesh points grouped by bone, the bones grouped by
        how many points they carry (one stacked product per group), and the triangles' rows."""
        point_bones, point_local, tri_rows, tri_elem, slices = _mesh_rows(meshes, first)
        local = np.array(point_local, float).reshape(-1, 3)
        by_count: dict[int, list] = {}
        for b in dict.fromkeys(point_bones):
            rows = np.array([i for i, pb in enumerate(point_bones) if pb == b])
            by_count.setdefault(len(rows), []).append((b, rows))
        self.point_count = len(point_bones)
        self.point_groups = [(np.array([BI[b] for b, _ in g], int),
                              np.array([JI[_head_of(b, model)] for b, _ in g], int),
                              np.stack([rows for _, rows in g]), np.stack([local[rows].T for _, rows in g]))
                             for _, g in sorted(by_count.items())]
        self.tri_rows = np.array(tri_rows, int).reshape(-1, 3)
        self.tri_elem = np.array(tri_elem, int)
        self.mesh_slices = slices
        # A few frames: every point bone in one product, its points padded to the most any bone
        # carries (zero columns), and the triangles' corners gathered from that padded table.
        width = max((rows.shape[1] for _, _, rows, _ in self.point_groups), default=0)
        self.pad_bones = np.concatenate([g[0] for g in self.point_groups]) if self.point_groups else np.zeros(0, int)
        self.pad_heads = np.concatenate([g[1] for g in self.point_groups]) if self.point_groups else np.zeros(0, int)
        self.pad_local = np.zeros((len(self.pad_bones), 3, width))
        flat = np.zeros(self.point_count, int)
        g0 = 0
        for _, _, rows, loc in self.point_groups:
            k = rows.shape[1]
            self.pad_local[g0:g0 + len(rows), :, :k] = loc
            flat[rows] = (g0 + np.arange(len(rows)))[:, None] * width + np.arange(k)
            g0 += len(rows)
        self.pad_tri = flat[self.tri_rows] if self.point_count else self.tri_rows

    def placed(self, joints: np.ndarray, frames: np.ndarray) -> tuple:
        """The capsules' heads, tails and frames and the spheres' centres and frames, for joints
        (..., J, 3) and bone frames (..., B, 3, 3): frames first or one frame alone."""
        caps_rot = frames.take(self.cap_bone, axis=-3)
        caps_head, caps_tail = joints.take(self.cap_ends[0], axis=-2), joints.take(self.cap_ends[1], axis=-2)
        if self.cap_offset:  # axes off the bone line (bodymodel: axis_head / axis_tail)
            caps_head = caps_head + np.einsum("...cij,cj->...ci", caps_rot, self.cap_off[:, 0])
            caps_tail = caps_tail + np.einsum("...cij,cj->...ci", caps_rot, self.cap_off[:, 1])
        sph_rot = frames.take(self.sph_bone, axis=-3)
        sph_center = joints.take(self.sph_head, axis=-2) + np.einsum("...sij,sj->...si", sph_rot, self.sph_local)
        return caps_head, caps_tail, caps_rot, sph_center, sph_rot

    def pose(self, joints: np.ndarray, frames: np.ndarray, normals: bool = True) -> PosedSurface:
        """The surface posed by canonical joints (F, J, 3) and bone frames (F, B, 3, 3), world.
        `normals` False leaves the triangles' normals out (None: a caller that reads none, as
        `PreparedTargets.map` without `turn_v`)."""
        nf = joints.shape[0]
        caps_head, caps_tail, caps_rot, sph_center, sph_rot = self.placed(joints, frames)
        if not self.point_count:
            tri = np.zeros((nf, 0, 3, 3))
        elif nf < FEW_FRAMES and len(self.point_groups) > 1:
            # Decision (speed): a few frames (a live frame) pose every point bone in one padded
            # product (a few numpy calls, not a few per group); the products' BLAS kernels differ
            # with the padded width, so points move by rounding (1e-16 m) against the groups'.
            rel = stacks_mul(frames.swapaxes(0, 1), self.pad_local, self.pad_bones)  # (G, F, 3, K)
            pts = joints.take(self.pad_heads, axis=1)[:, :, None, :] + rel.swapaxes(-1, -2).swapaxes(0, 1)
            tri = pts.reshape(nf, -1, 3).take(self.pad_tri, axis=1)
        else:
            world = np.empty((nf, self.point_count, 3))
            for bones, heads, rows, local in self.point_groups:  # per bone, its points (G bones of K points)
                rel = stacks_mul(frames.swapaxes(0, 1), local, bones)  # (G, F, 3, K)
                world[:, rows] = joints[:, heads][:, :, None, :] + rel.swapaxes(-1, -2).swapaxes(0, 1)
            tri = world.take(self.tri_rows, axis=1)
        tri_normal = None
        if normals:
            n = cross(tri[:, :, 1] - tri[:, :, 0], tri[:, :, 2] - tri[:, :, 0])
            nn = np.sqrt(np.add.reduce(n * n, axis=-1, keepdims=True))  # np.linalg.norm's
            tri_normal = np.divide(n, nn, out=np.zeros_like(n), where=nn > 1e-15)
        return PosedSurface(self.element_ids, self.element_bones, self.element_roots, caps_head, caps_tail, caps_rot,
                            self.cap_radius, sph_center, sph_rot, self.sph_radius, tri, tri_normal, self.tri_elem,
                            self.mesh_slices, joints.take(self.mesh_head, axis=1), frames.take(self.mesh_bone, axis=1),
                            self.mesh_scale, JointTable(joints), self.notes, self.constants)
