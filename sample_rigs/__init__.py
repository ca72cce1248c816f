"""Sample avatars for tests, benchmarks and the demo.

- `load_glb_avatar`: imports one of the MakeHuman sample avatars (sample_data/avatars) into
  the scene: an armature and its skinned mesh, in a collection named after the file.
- `build_procedural_avatar`: builds the procedural avatar of `procedural.py`, whose true surface
  dimensions are known exactly.

Self-contained (numpy + bpy) so it loads the same way from the repository and from the extension.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from . import procedural


class SampleRigError(Exception):
    pass


def _collection(name: str):
    import bpy

    coll = bpy.data.collections.new(name)
    bpy.context.scene.collection.children.link(coll)
    return coll


def load_glb_avatar(path, name: str | None = None):
    """Import a glb avatar; returns (armature object, mesh object). Anything else the file holds
    (the MakeHuman exports carry a stray icosphere) is removed."""
    import bpy

    path = Path(path)
    if not path.is_file():
        raise SampleRigError(f"{path}: no such avatar file")
    name = name or path.name.split(".")[0]
    before = set(bpy.data.objects)
    result = bpy.ops.import_scene.gltf(filepath=str(path))
    if "FINISHED" not in result:
        raise SampleRigError(f"{path}: the glTF importer failed")
    new = [o for o in bpy.data.objects if o not in before]
    armatures = [o for o in new if o.type == "ARMATURE"]
    if len(armatures) != 1:
        raise SampleRigError(f"{path}: expected one armature, found {len(armatures)}")
    arm = armatures[0]
    meshes = [o for o in new if o.type == "MESH" and any(
        m.type == "ARMATURE" and m.object == arm for m in o.modifiers)]
    if len(meshes) != 1:
        raise SampleRigError(f"{path}: expected one mesh skinned to {arm.name}, found {len(meshes)}")
    mesh = meshes[0]
    coll = _collection(name)
    for obj in new:
        if obj in (arm, mesh):
            for c in list(obj.users_collection):
                c.objects.unlink(obj)
            coll.objects.link(obj)
        else:
            data = obj.data
            bpy.data.objects.remove(obj)
            if data is not None and data.users == 0 and isinstance(data, bpy.types.Mesh):
                bpy.data.meshes.remove(data)
    mesh.name = f"{name}_mesh"  # first: the file names its mesh object after itself
    arm.name = name
    arm.data.name = name
    return arm, mesh


def build_procedural_avatar(spec: procedural.ProceduralAvatar | None = None, **spec_kwargs):
    """Build the procedural avatar in the scene; returns (armature, mesh, spec)."""
    import bpy

    spec = spec or procedural.build_spec(**spec_kwargs)
    coll = _collection(spec.name)
    arm_data = bpy.data.armatures.new(spec.name)
    arm = bpy.data.objects.new(spec.name, arm_data)
    coll.objects.link(arm)
    view_layer = bpy.context.view_layer
    previous_active = view_layer.objects.active
    view_layer.objects.active = arm
    bpy.ops.object.mode_set(mode="EDIT")
    try:
        for bone_name, b in spec.bones.items():
            eb = arm_data.edit_bones.new(bone_name)
            eb.head, eb.tail = b.head.tolist(), b.tail.tolist()
            eb.align_roll(b.z_axis.tolist())
        for bone_name, b in spec.bones.items():
            if b.parent:
                eb = arm_data.edit_bones[bone_name]
                eb.parent = arm_data.edit_bones[b.parent]
                eb.use_connect = bool(np.allclose(eb.parent.tail, eb.head, atol=1e-6))
    finally:
        bpy.ops.object.mode_set(mode="OBJECT")
        view_layer.objects.active = previous_active

    verts, faces, owners = [], [], []
    offset = 0
    for part in spec.parts:
        verts.append(part.vertices)
        faces += [[int(i) + offset for i in f] for f in part.faces]
        owners.append((part.bone, offset, len(part.vertices)))
        offset += len(part.vertices)
    me = bpy.data.meshes.new(f"{spec.name}_mesh")
    me.from_pydata(np.concatenate(verts).tolist(), [], faces)
    me.update()
    mesh = bpy.data.objects.new(f"{spec.name}_mesh", me)
    coll.objects.link(mesh)
    for bone_name, start, count in owners:
        vg = mesh.vertex_groups.get(bone_name) or mesh.vertex_groups.new(name=bone_name)
        vg.add(list(range(start, start + count)), 1.0, "REPLACE")
    mesh.parent = arm
    mod = mesh.modifiers.new("Armature", "ARMATURE")
    mod.object = arm
    return arm, mesh, spec
