"""A generated Rigify rig around the procedural avatar (tests and benchmarks; never imported by the
engine). Rigify's human metarig is fitted bone by bone onto the procedural avatar's skeleton (its
face removed), generated (`bpy.ops.pose.rigify_generate`), and the procedural body's mesh is bound
to the generated rig's DEF- bones with the same rigid weights, so it is the same body as the plain
Unreal-style procedural avatar.

Run `build(path)` in a subprocess of its own (`python -m sample_rigs.rigify_rig OUT.blend`): after
enabling Rigify, Blender 4.5 hangs at exit, so the process ends with `exit_now` (os._exit).
"""

from __future__ import annotations

import sys

import numpy as np

# metarig bone -> procedural (Unreal-style) bone; {s}: L/R in the metarig, l/r in the procedural
FIT = {"spine": "pelvis", "spine.001": "spine_01", "spine.002": "spine_02", "spine.003": "spine_03",
       "spine.006": "head", "shoulder.{S}": "clavicle_{s}", "upper_arm.{S}": "upperarm_{s}",
       "forearm.{S}": "lowerarm_{s}", "hand.{S}": "hand_{s}", "thigh.{S}": "thigh_{s}", "shin.{S}": "calf_{s}",
       "foot.{S}": "foot_{s}", "toe.{S}": "ball_{s}"}
for _f, _m in (("thumb", "thumb"), ("index", "f_index"), ("middle", "f_middle"), ("ring", "f_ring"),
               ("pinky", "f_pinky")):
    for _i in (1, 2, 3):
        FIT[f"{_m}.0{_i}.{{S}}"] = f"{_f}_0{_i}_{{s}}"
PALMS = {"palm.01.{S}": "index", "palm.02.{S}": "middle", "palm.03.{S}": "ring", "palm.04.{S}": "pinky"}
KEEP = {"spine.004", "spine.005", "heel.02.{S}", "breast.{S}", "pelvis.{S}", *FIT, *PALMS}
# procedural vertex group -> the generated rig's DEF- bone
WEIGHTS = {"pelvis": "DEF-spine", "spine_01": "DEF-spine.001", "spine_02": "DEF-spine.002",
           "spine_03": "DEF-spine.003", "neck_01": "DEF-spine.004", "head": "DEF-spine.006"}
for _meta, _proc in FIT.items():
    if "{S}" in _meta:
        for _S, _s in (("L", "l"), ("R", "r")):
            WEIGHTS[_proc.replace("{s}", _s)] = "DEF-" + _meta.replace("{S}", _S)


def _sided(name: str):
    return [(name.replace("{S}", S), s) for S, s in (("L", "l"), ("R", "r"))] if "{S}" in name else [(name, None)]


def bent_spec(bend: float = 0.01):
    """The procedural avatar with its elbows `bend` m back and its knees `bend` m forward: Rigify
    finds a limb's bend plane from the chain's bend and refuses a straight one. The mesh is the
    procedural one (made before the bend); build the plain avatar from this spec too to compare."""
    from . import procedural

    spec = procedural.build_spec()
    for s in ("l", "r"):
        for upper, lower, shift in (("upperarm", "lowerarm", (0.0, bend, 0.0)), ("thigh", "calf", (0.0, -bend, 0.0))):
            joint = spec.bones[f"{upper}_{s}"].tail + np.array(shift)
            spec.bones[f"{upper}_{s}"].tail = joint
            spec.bones[f"{lower}_{s}"].head = joint.copy()
    return spec


def build(out_path) -> None:
    import bpy  # noqa: I001  (first: addon_utils imports only after it)
    import addon_utils

    from . import build_procedural_avatar

    bpy.ops.wm.read_homefile(use_empty=True)
    addon_utils.enable("rigify", default_set=True)
    spec = bent_spec()
    plain, mesh, _spec = build_procedural_avatar(spec)
    bpy.ops.object.armature_human_metarig_add()
    meta = bpy.context.active_object
    keep = {n for k in KEEP for n, _ in _sided(k)}
    bpy.ops.object.mode_set(mode="EDIT")
    ebs = meta.data.edit_bones
    for eb in list(ebs):
        if eb.name not in keep:
            ebs.remove(eb)
    connected = {eb.name for eb in ebs if eb.use_connect}
    for eb in ebs:  # set heads and tails free first: connected bones share them
        eb.use_connect = False

    def put(name, head, tail, z_axis):
        eb = ebs[name]
        eb.head, eb.tail = list(head), list(tail)
        eb.align_roll(list(z_axis))

    for meta_t, proc_t in FIT.items():
        for name, s in _sided(meta_t):
            b = spec.bones[proc_t if s is None else proc_t.replace("{s}", s)]
            put(name, b.head, b.tail, b.z_axis)
    neck = spec.bones["neck_01"]
    mid = (neck.head + neck.tail) / 2
    put("spine.004", neck.head, mid, neck.z_axis)
    put("spine.005", mid, neck.tail, neck.z_axis)
    for meta_t, finger in PALMS.items():
        for name, s in _sided(meta_t):
            hand, f1 = spec.bones[f"hand_{s}"], spec.bones[f"{finger}_01_{s}"]
            put(name, hand.head + 0.5 * (f1.head - hand.head), f1.head, spec.bones[f"hand_{s}"].z_axis)
    for name, s in _sided("heel.02.{S}"):
        ankle = spec.bones[f"foot_{s}"].head
        put(name, [ankle[0] - 0.04, ankle[1] + 0.05, 0.0], [ankle[0] + 0.04, ankle[1] + 0.05, 0.0], [0, 0, 1])
    for eb in ebs:  # connected again as the metarig was (the heads are where the parents' tails are)
        if eb.name in connected:
            assert np.allclose(eb.parent.tail, eb.head, atol=1e-6), eb.name
            eb.use_connect = True
    bpy.ops.object.mode_set(mode="OBJECT")
    bpy.ops.pose.rigify_generate()
    rig = next(o for o in bpy.data.objects if o.type == "ARMATURE" and o not in (meta, plain))
    for group in mesh.vertex_groups:
        group.name = WEIGHTS[group.name]
    mesh.parent = rig
    mesh.modifiers["Armature"].object = rig
    for obj in (meta, plain):
        bpy.data.objects.remove(obj)
    rig.name = "rigify_avatar"
    bpy.ops.wm.save_as_mainfile(filepath=str(out_path))


if __name__ == "__main__":
    build(sys.argv[1])
    from bodycal_addon.blender.process import exit_now

    exit_now(0)
