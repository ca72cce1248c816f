"""Keys per second of three ways to bake the same 60-bone animation (DESIGN.md §1, step 5).

- BodyCal's writer (`keyframe_points.add` + `foreach_set`), 5,000 frames;
- per-key `keyframe_insert`, 500 frames (it is far too slow for 5,000: BLENDER_NOTES.md);
- `nla.bake` of a constraint-driven rig (what other retargeting add-ons do), 500 frames.
Rates are keys per second; the ratios compare them within this one run. Prints one JSON line.
"""

import json
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="bodycal-bench-"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import bpy  # noqa: E402
import numpy as np  # noqa: E402

from bodycal_addon.blender.bake import bake_animation  # noqa: E402
from bodycal_addon.blender.fcurves import object_fcurves  # noqa: E402
from bodycal_addon.body.animation import AvatarAnimation  # noqa: E402
from bodycal_addon.core import transforms as tf  # noqa: E402

BONES = 60
FRAMES = 5000
SLOW_FRAMES = 500


def make_armature(name):
    arm = bpy.data.objects.new(name, bpy.data.armatures.new(name))
    bpy.context.scene.collection.objects.link(arm)
    bpy.context.view_layer.objects.active = arm
    bpy.ops.object.mode_set(mode="EDIT")
    names = []
    for i in range(BONES):
        eb = arm.data.edit_bones.new(f"b{i:02d}")
        eb.head = (0.1 * (i % 6), 0.0, 0.2 * (i // 6))
        eb.tail = (0.1 * (i % 6), 0.1, 0.2 * (i // 6))
        if i >= 6:
            eb.parent = arm.data.edit_bones[f"b{i - 6:02d}"]
        names.append(eb.name)
    bpy.ops.object.mode_set(mode="OBJECT")
    return arm, names


def animation(names, frames, seed=0):
    rng = np.random.default_rng(seed)
    # Smooth random rotations: a random walk, normalised.
    q = np.cumsum(rng.normal(scale=0.02, size=(frames, len(names), 4)), axis=0) + np.array([1.0, 0, 0, 0])
    return AvatarAnimation("bench", names, tf.quat_normalize(q), names[0],
                           np.cumsum(rng.normal(scale=1e-3, size=(frames, 3)), axis=0), np.arange(frames) / 30.0)


def bench_bodycal(anim, arm):
    t0 = time.perf_counter()
    result = bake_animation(anim, arm, action_name="bench_bodycal", frame_start=1)
    return result.keys, time.perf_counter() - t0


def bench_keyframe_insert(anim, arm):
    ad = arm.animation_data_create()
    ad.action = bpy.data.actions.new("bench_insert")
    pbs = [arm.pose.bones[n] for n in anim.bone_names]
    for pb in pbs:
        pb.rotation_mode = "QUATERNION"
    root = arm.pose.bones[anim.root_bone]
    keys = 0
    t0 = time.perf_counter()
    for f in range(SLOW_FRAMES):
        for b, pb in enumerate(pbs):
            pb.rotation_quaternion = anim.rotations[f, b]
            pb.keyframe_insert("rotation_quaternion", frame=f + 1)
            keys += 4
        root.location = anim.root_location[f]
        root.keyframe_insert("location", frame=f + 1)
        keys += 3
    return keys, time.perf_counter() - t0


def bench_nla_bake(source, names):
    """A second rig follows the first through Copy Transforms constraints; nla.bake keys it."""
    rig, _ = make_armature("constraint_rig")
    for n in names:
        c = rig.pose.bones[n].constraints.new("COPY_TRANSFORMS")
        c.target = source
        c.subtarget = n
        rig.pose.bones[n].rotation_mode = "QUATERNION"
    bpy.ops.object.select_all(action="DESELECT")
    rig.select_set(True)
    bpy.context.view_layer.objects.active = rig
    bpy.ops.object.mode_set(mode="POSE")
    bpy.ops.pose.select_all(action="SELECT")
    t0 = time.perf_counter()
    # Rotations only, like BodyCal's bake (which adds one root location): the same channels.
    bpy.ops.nla.bake(frame_start=1, frame_end=SLOW_FRAMES, only_selected=True, visual_keying=True,
                     clear_constraints=False, bake_types={"POSE"}, channel_types={"ROTATION"})
    elapsed = time.perf_counter() - t0
    bpy.ops.object.mode_set(mode="OBJECT")
    keys = sum(len(fc.keyframe_points) for fc in object_fcurves(rig).values())
    return keys, elapsed


def main():
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.context.scene.render.fps = 30
    fast_arm, names = make_armature("bodycal_rig")
    anim = animation(names, FRAMES)
    fast_keys, fast_s = bench_bodycal(anim, fast_arm)
    slow_arm, _ = make_armature("insert_rig")
    ins_keys, ins_s = bench_keyframe_insert(anim, slow_arm)
    nla_keys, nla_s = bench_nla_bake(fast_arm, names)
    fast_rate, ins_rate, nla_rate = fast_keys / fast_s, ins_keys / ins_s, nla_keys / nla_s
    print(json.dumps({
        "benchmark": "bake", "bones": BONES, "frames": FRAMES, "slow_frames": SLOW_FRAMES,
        "bodycal_keys": fast_keys, "bodycal_s": round(fast_s, 3), "bodycal_keys_per_s": round(fast_rate),
        "keyframe_insert_keys_per_s": round(ins_rate), "nla_bake_keys_per_s": round(nla_rate),
        "ratio_vs_keyframe_insert": round(fast_rate / ins_rate, 1),
        "ratio_vs_nla_bake": round(fast_rate / nla_rate, 1),
        "targets_met": fast_rate / ins_rate >= 100 and fast_rate / nla_rate >= 20,
    }))


if __name__ == "__main__":
    main()
    from bodycal_addon.blender.process import exit_now

    exit_now(0)
