"""Contact gap against the avatar's EVALUATED mesh (DESIGN.md §7): the armature is posed from an
`AvatarAnimation` (pose-bone `rotation_quaternion` = the animation's rotations, the root bone's
`location`), the depsgraph is updated, the skinned mesh is evaluated, and each effector point's
nearest point on the touched body part is found with `mathutils.bvhtree.BVHTree.find_nearest`,
signed by the face normal (negative inside).

The touched body part is the set of faces whose vertices are all dominated (largest vertex-group
weight) by the avatar bones of the target element's segments (torso -> pelvis and spine bones,
skull/jaw -> head and neck, capsule:<bone> -> that limb bone, palm -> hand and fingers), so the
effector's own hand never counts as the surface it touches.

The armature's pose and action are restored afterwards.
"""

from __future__ import annotations

import contextlib

import bpy
import numpy as np
from mathutils.bvhtree import BVHTree

from ..body import naming
from ..body import skeleton as sk
from ..body.animation import AvatarAnimation
from ..body.bodymodel import BodyModel
from ..core.errors import BodyCalError
from ..output import metrics
from ..retarget.avatar_pose import AvatarRig
from . import avatar_rig, rig_output


def world_vertices(obj, depsgraph) -> np.ndarray:
    """(V, 3) world positions of the mesh object's evaluated (deformed) vertices."""
    ev = obj.evaluated_get(depsgraph)
    me = ev.to_mesh()
    co = np.empty(len(me.vertices) * 3)
    me.vertices.foreach_get("co", co)
    ev.to_mesh_clear()
    m = np.array(obj.matrix_world)
    return co.reshape(-1, 3) @ m[:3, :3].T + m[:3, 3]


def target_segments(target: str) -> list[str]:
    """Canonical segments whose skin is the touched element `target` ("mesh:torso/belly_c2",
    "capsule:thigh_l", "sphere:skull", "mesh:palm_r/palm_2_r", ...)."""
    element = target.split("/", 1)[0]
    kind, _, name = element.partition(":")
    if name == "torso":
        return ["pelvis", "spine", "breast_l", "breast_r"]
    if name in ("skull", "jaw"):
        return ["head", "neck"]
    if name.startswith(("palm_", "sole_")):
        side = name[-1]
        if name.startswith("palm_"):
            return [f"hand_{side}"] + [f"{f}_{i}_{side}" for f in sk.FINGERS for i in (1, 2, 3)]
        return [f"foot_{side}", f"toe_{side}"]
    if kind == "capsule":
        return [name]
    raise BodyCalError(f"unknown contact target '{target}'", field="target")


def effector_segments(effector: str) -> list[str]:
    """The effector's own arm (or leg): skin it always touches, left out of its contact gap."""
    side = effector[-1]
    if effector.startswith(("ankle_", "toe_", "sole_")):
        return [f"thigh_{side}", f"shin_{side}", f"foot_{side}", f"toe_{side}"]
    return [f"upperarm_{side}", f"forearm_{side}", f"hand_{side}"] + [
        f"{f}_{i}_{side}" for f in sk.FINGERS for i in (1, 2, 3)] + [f"metacarpal_{f}_{side}" for f in sk.FINGERS]


def target_bones(avatar: BodyModel, target: str) -> set[str]:
    """The avatar's bones whose skin is the touched element `target` (`target_segments`)."""
    bm = naming.BoneMap.from_dict(avatar.extra["rig"].get("bone_map", {}))
    return _segment_bones(bm, target_segments(target))


def _segment_bones(bone_map: naming.BoneMap, segments) -> set[str]:
    out = set()
    for seg in segments:
        if seg in bone_map.chains:
            out |= set(bone_map.chains[seg])
        elif seg in bone_map.bones:
            out.add(bone_map.bones[seg])
    return out


def effector_points(avatar: BodyModel, rig: AvatarRig, anim: AvatarAnimation, effector: str):
    """(F, 3) world points of the avatar's effector in a baked animation and its skin offset (m):
    `output.metrics.effector_points` on the animation's pose and joints."""
    pose = rig.fk(anim.rotations, anim.root_location) if effector.startswith("palm_") else None
    return metrics.effector_points(avatar, rig, pose, effector, anim.joints_world)


class EvaluatedMesh:
    """The skinned meshes of an armature and the rigid parts riding on its bones (a game robot's
    head, torso and feet: parented to a bone, every vertex that bone's), with the dominant bone of
    every triangle."""

    def __init__(self, arm, meshes=None):
        self.arm = arm
        if meshes is None:
            meshes = [o for o in bpy.data.objects if o.type == "MESH" and (any(
                m.type == "ARMATURE" and m.object == arm for m in o.modifiers) or _rides_on_bone(o, arm))]
        if not meshes:
            raise BodyCalError("no mesh is skinned to this armature", source=arm.name)
        self.meshes = meshes
        self.tri_bone = {}
        self.dominant = {}  # mesh name -> (V,) each vertex's dominant bone
        for obj in meshes:
            me = obj.data
            me.calc_loop_triangles()
            tris = np.empty(len(me.loop_triangles) * 3, np.int32)
            me.loop_triangles.foreach_get("vertices", tris)
            tris = tris.reshape(-1, 3)
            self.dominant[obj.name] = dom = _dominant(obj)
            self.tri_bone[obj.name] = (tris, dom[tris])

    def triangles_without(self, bones: set[str]):
        """{mesh name: triangles (T, 3)} with at least one vertex NOT dominated by `bones`."""
        out = {}
        for name, (tris, owners) in self.tri_bone.items():
            keep = ~np.isin(owners, list(bones)).all(axis=1)
            if keep.any():
                out[name] = tris[keep]
        return out

    def triangles_of(self, bones: set[str]):
        """{mesh name: triangle indices (T, 3)} whose three vertices belong to `bones`."""
        out = {}
        for name, (tris, owners) in self.tri_bone.items():
            keep = np.isin(owners, list(bones)).all(axis=1)
            if keep.any():
                out[name] = tris[keep]
        return out


@contextlib.contextmanager
def posed(arm, anim: AvatarAnimation, meshes):
    """A function `frame -> {mesh name: (V, 3) world vertices}` of the skinned `meshes` with the
    armature posed at that frame of `anim` (its action detached meanwhile); the armature's pose
    and action are put back afterwards. Limb bones beside the limb (a game rig's IK feet) are posed
    in the armature's space as the bake keys them (rig_output.with_armature_space)."""
    anim = rig_output.with_armature_space(anim, arm, avatar_rig.bone_map_for(arm))
    pbs = [arm.pose.bones[n] for n in anim.bone_names]
    root = arm.pose.bones[anim.root_bone]
    saved = [(pb.rotation_mode, tuple(pb.rotation_quaternion), tuple(pb.location)) for pb in arm.pose.bones]
    ad = arm.animation_data
    saved_action = ad.action if ad is not None else None
    if ad is not None:
        ad.action = None
    view_layer = bpy.context.view_layer
    located = [(arm.pose.bones[n], loc) for n, loc in anim.bone_locations.items()]

    def at(f: int) -> dict[str, np.ndarray]:
        for b, pb in enumerate(pbs):
            pb.rotation_quaternion = anim.rotations[f, b]
        root.location = anim.root_location[f]
        for pb, loc in located:
            pb.location = loc[f]
        view_layer.update()
        dg = bpy.context.evaluated_depsgraph_get()
        return {obj.name: world_vertices(obj, dg) for obj in meshes}

    try:
        for pb in pbs:
            pb.rotation_mode = "QUATERNION"
        # A detached action leaves its last pose: a root bone keyed with root motion would stay moved.
        for pb in arm.pose.bones:
            pb.location = (0.0, 0.0, 0.0)
        yield at
    finally:
        for pb, (mode, q, loc) in zip(arm.pose.bones, saved):
            pb.rotation_quaternion = q
            pb.location = loc
            pb.rotation_mode = mode
        if ad is not None:
            ad.action = saved_action
        view_layer.update()


def signed_gaps(arm, anim: AvatarAnimation, queries: list[tuple[np.ndarray, dict, np.ndarray]],
                mesh: EvaluatedMesh | None = None) -> list[np.ndarray]:
    """Pose the armature at frames and measure signed distances (m) to selected skin.

    queries: [(frame indices (n,), {mesh name: triangles}, points (n, 3) world)]; returns one (n,)
    array per query. Frames shared by several queries are posed once."""
    mesh = mesh or EvaluatedMesh(arm)
    by_frame: dict[int, list[tuple[int, int]]] = {}
    for qi, (frames, _, _) in enumerate(queries):
        for k, f in enumerate(np.asarray(frames, int)):
            by_frame.setdefault(int(f), []).append((qi, k))
    out = [np.full(len(q[0]), np.nan) for q in queries]
    with posed(arm, anim, mesh.meshes) as at:
        for f, items in sorted(by_frame.items()):
            world_verts = at(f)
            for qi, k in items:
                _, tris_by_mesh, points = queries[qi]
                out[qi][k] = gap_to_skin(world_verts, tris_by_mesh, points[k])
    return out


def gap_to_skin(world_verts: dict[str, np.ndarray], tris_by_mesh: dict[str, np.ndarray], point) -> float:
    """Signed distance (m, negative inside) of a world point to the skin made of `tris_by_mesh`
    ({mesh name: triangles}) of the evaluated meshes `world_verts` ({mesh name: (V, 3)}); NaN when
    there is no such skin."""
    verts, tris, off = [], [], 0
    for name, tri in tris_by_mesh.items():
        v = world_verts[name]
        verts.append(v)
        tris.append(tri + off)
        off += len(v)
    if not verts:
        return float("nan")
    tree = BVHTree.FromPolygons(np.concatenate(verts).tolist(), np.concatenate(tris).tolist())
    p = np.asarray(point, float)
    loc, normal, _, dist = tree.find_nearest(p.tolist())
    if loc is None:
        return float("nan")
    return (1.0 if np.dot(p - np.asarray(loc), np.asarray(normal)) >= 0 else -1.0) * dist


def contact_gaps(arm, avatar: BodyModel, anim: AvatarAnimation, contacts: list[dict], max_frames: int = 12,
                 mesh: EvaluatedMesh | None = None, against: str = "body",
                 posed: AvatarAnimation | None = None) -> list[np.ndarray]:
    """Signed contact gap (m, negative inside) per contact of the synthetic ground truth
    (`{"effector", "target", "frames" (F,) bool}`), measured on up to `max_frames` evenly spaced
    contact frames each: distance from the avatar's effector skin to the evaluated skin of the
    body without the effector's own arm (`against="body"`, DESIGN.md §7), or of the touched body
    part only (`against="target"`). `posed` is what the bake keys when it is not the engine's
    animation (root motion, a Rigify rig's controls: `rig_output.for_bake`); the mesh is posed by it."""
    rig = AvatarRig.from_model(avatar)
    bm = naming.BoneMap.from_dict(avatar.extra["rig"].get("bone_map", {}))
    mesh = mesh or EvaluatedMesh(arm)
    queries, offsets = [], []
    for c in contacts:
        idx = np.flatnonzero(np.asarray(c["frames"], bool)[:anim.frame_count])
        if len(idx) == 0:
            queries.append((idx, {}, np.zeros((0, 3))))
            offsets.append(0.0)
            continue
        idx = idx[np.linspace(0, len(idx) - 1, min(max_frames, len(idx))).astype(int)]
        pts, off = effector_points(avatar, rig, anim, c["effector"])
        if against == "target":
            tris = mesh.triangles_of(_segment_bones(bm, target_segments(c["target"])))
        else:  # the whole skin but the effector's own arm
            tris = mesh.triangles_without(_segment_bones(bm, effector_segments(c["effector"])))
        queries.append((idx, tris, pts[idx]))
        offsets.append(off)
    gaps = signed_gaps(arm, posed if posed is not None else anim, queries, mesh)
    return [g - o for g, o in zip(gaps, offsets)]


def _foot_points(avatar: BodyModel, anim: AvatarAnimation, side: str) -> dict[str, np.ndarray]:
    rig = AvatarRig.from_model(avatar)
    return metrics.foot_points(avatar, rig, rig.fk(anim.rotations, anim.root_location), side)


def sole_points(avatar: BodyModel, anim: AvatarAnimation, side: str) -> np.ndarray:
    """World positions (F, N, 3) of the avatar's sole outline (`mesh:sole_<side>`) in the baked
    pose: the floor-error measurement of DESIGN.md §7 (`metrics.foot_points`)."""
    return _foot_points(avatar, anim, side)["outline"]


def contact_points(avatar: BodyModel, anim: AvatarAnimation, side: str) -> dict[str, np.ndarray]:
    """World positions of the avatar's sole contact points in the baked pose: "heel", "ball" (F, 3)
    and "support" (F, K, 3) (`metrics.foot_points`)."""
    points = _foot_points(avatar, anim, side)
    return {k: points[k] for k in ("heel", "ball", "support")}


def foot_skin(arm, avatar: BodyModel, anim: AvatarAnimation, frames, mesh: EvaluatedMesh | None = None
              ) -> dict[str, dict[str, np.ndarray]]:
    """What the animator sees of the feet (DESIGN.md §7, "Real motion"), on the evaluated mesh at
    `frames` (n,) of `anim` (the armature posed by it, `posed`): per side, `low` (n,) the lowest
    world height of the foot's skin (the vertices the foot and toe bones dominate), and `heel` /
    `ball` (n, 3) two skin points followed through the motion: the lowest vertex at the back of
    the sole and the lowest one under the ball of the foot (the toe joint), chosen on the mesh as
    it was bound."""
    mesh = mesh or EvaluatedMesh(arm)
    with posed(arm, anim, mesh.meshes) as at:
        return foot_skin_at(arm, avatar, lambda f: at(int(f)), np.asarray(frames, int), mesh)


def foot_skin_at(arm, avatar: BodyModel, at, frames, mesh: EvaluatedMesh) -> dict[str, dict[str, np.ndarray]]:
    """`foot_skin` with the mesh posed by `at(frame) -> {mesh name: (V, 3) world vertices}`: the
    armature posed from an animation (`posed`), or playing its baked action (`played`)."""
    bone_map = naming.BoneMap.from_dict(avatar.extra["rig"]["bone_map"])
    frames = np.asarray(frames)
    picks = {}
    for s in sk.SIDES:
        bones = _segment_bones(bone_map, [f"foot_{s}", f"toe_{s}"])
        ankle, toe = (np.asarray(avatar.joints[f"{j}_{s}"].world, float) for j in ("ankle", "toe"))
        forward = (toe - ankle) * [1.0, 1.0, 0.0]
        forward /= max(np.linalg.norm(forward), 1e-9)
        for obj in mesh.meshes:
            idx = np.flatnonzero(np.isin(mesh.dominant[obj.name], list(bones)))
            if idx.size == 0:
                continue
            m = np.array(obj.matrix_world)
            co = np.empty(len(obj.data.vertices) * 3)
            obj.data.vertices.foreach_get("co", co)
            rest = co.reshape(-1, 3)[idx] @ m[:3, :3].T + m[:3, 3]
            low = rest[:, 2] <= rest[:, 2].min() + 0.01  # the sole: within 1 cm of the lowest skin
            heel = idx[low][np.argmin(rest[low] @ forward)]
            ball = idx[low][np.argmin(np.linalg.norm((rest[low] - toe)[:, :2], axis=1))]
            picks[s] = (obj.name, idx, heel, ball)
            break
    out = {s: {"low": np.full(len(frames), np.nan), "heel": np.full((len(frames), 3), np.nan),
               "ball": np.full((len(frames), 3), np.nan)} for s in picks}
    for k, f in enumerate(frames):
        verts = at(f)
        for s, (name, idx, heel, ball) in picks.items():
            v = verts[name]
            out[s]["low"][k] = v[idx, 2].min()
            out[s]["heel"][k], out[s]["ball"][k] = v[heel], v[ball]
    return out


@contextlib.contextmanager
def played(arm, meshes):
    """A function `scene frame -> {mesh name: (V, 3) world vertices}` of the skinned `meshes` with
    the armature playing what it has (its baked action, constraints and drivers included): what
    the animator sees at that frame. The scene's frame is put back afterwards."""
    scene = bpy.context.scene
    was = scene.frame_current, scene.frame_subframe

    def at(frame: float) -> dict[str, np.ndarray]:
        whole = int(np.floor(frame))
        scene.frame_set(whole, subframe=float(frame) - whole)
        dg = bpy.context.evaluated_depsgraph_get()
        return {obj.name: world_vertices(obj, dg) for obj in meshes}

    try:
        yield at
    finally:
        scene.frame_set(was[0], subframe=was[1])


def _rides_on_bone(obj, arm) -> bool:
    return obj.parent == arm and obj.parent_type == "BONE" and obj.parent_bone in arm.data.bones


def _dominant(obj) -> np.ndarray:
    """(V,) the name of the vertex group with the largest weight on each vertex ("" for none); a
    rigid part parented to a bone without an Armature modifier: that bone's."""
    if obj.parent_type == "BONE" and not any(m.type == "ARMATURE" for m in obj.modifiers):
        return np.full(len(obj.data.vertices), obj.parent_bone, dtype=object)
    groups = {g.index: g.name for g in obj.vertex_groups}
    dom = np.full(len(obj.data.vertices), "", dtype=object)
    for v in obj.data.vertices:
        best = max(v.groups, key=lambda g: g.weight, default=None)
        if best is not None:
            dom[v.index] = groups.get(best.group, "")
    return dom
