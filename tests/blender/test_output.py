"""Production-size output (FORMATS.md §4.2). Blender plays the reduced keys within the tolerance,
--fps resamples with the timing kept, every .blend is compressed, and each export format re-imports
with the joints where the .blend has them."""

import json
import subprocess
import sys
from pathlib import Path

import bpy
import numpy as np
import pytest
from repo_paths import REPO

from bodycal_addon.blender.bake import bake_animation
from bodycal_addon.core import paths
from bodycal_addon.core.transforms import continuous_quaternions
from bodycal_addon.output import keyreduce
from bodycal_addon.retarget import pipeline as pl
from bodycal_dev import retarget_fixtures as rt
from bodycal_dev import synthetic

rigs = paths.sample_rigs()
ZSTD_MAGIC = b"\x28\xb5\x2f\xfd"


@pytest.fixture(scope="module")
def take(tmp_path_factory):
    folder = tmp_path_factory.mktemp("take")
    perf = synthetic.make_performer(seed=11)
    rec, truth = synthetic.record_session(perf, motions=("clap", "walk_in_place"), calibration=["tpose"], seed=11)
    rec.name = "clapwalk"
    rec_path, _truth = synthetic.write_session(folder, "clapwalk", rec, truth)
    user = truth.body_model()
    user_path = user.save(folder / "performer.body.json")
    bpy.ops.wm.read_homefile(use_empty=True)
    rigs.build_procedural_avatar()
    blend = folder / "avatar.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    bpy.ops.wm.read_homefile(use_empty=True)
    return {"folder": folder, "rec": rec, "user": user, "rec_path": rec_path, "user_path": user_path, "blend": blend}


def _the_armature():
    (arm,) = [o for o in bpy.data.objects if o.type == "ARMATURE"]
    return arm


def _run(*args):
    return subprocess.run([sys.executable, "-m", "bodycal_addon", *map(str, args)], cwd=REPO, capture_output=True,
                          text=True, timeout=600)


@pytest.mark.parametrize("tol_deg", [0.1, 1.0])
def test_blender_plays_the_reduced_keys_within_the_tolerance(take, tol_deg):
    """Evaluated by Blender (not the numpy model of it) at every 7th frame: every bone within the
    angle, the root within the distance, and far fewer keys at the looser tolerance."""
    bpy.ops.wm.read_homefile(use_empty=True)
    arm, _mesh, spec = rigs.build_procedural_avatar()
    anim = pl.retarget(take["rec"], take["user"], rt.procedural_avatar(spec), "rotations")
    anim.armature = arm.name
    result = bake_animation(anim, arm, fps=take["rec"].fps, frame_start=1.0, tolerance_deg=tol_deg,
                            location_tolerance_mm=1.0)
    assert 0 < result.keys < result.samples
    q = continuous_quaternions(anim.rotations)
    scene = bpy.context.scene
    worst_rot = worst_loc = 0.0
    for f in range(0, anim.frame_count, 7):
        scene.frame_set(f + 1)
        got = np.array([tuple(arm.pose.bones[b].rotation_quaternion) for b in anim.bone_names])
        worst_rot = max(worst_rot, float(keyreduce.rotation_error(q[f], got).max()))
        loc = np.array(arm.pose.bones[anim.root_bone].location)
        worst_loc = max(worst_loc, float(np.linalg.norm(loc - anim.root_location[f])))
    # float32 keys: a few micro-degrees on top of the bound
    assert np.degrees(worst_rot) <= tol_deg + 1e-3, np.degrees(worst_rot)
    assert worst_loc <= 1e-3 + 1e-6, worst_loc
    assert worst_rot > 0.0  # really reduced: not every sample kept


def test_bezier_keys_have_auto_clamped_handles_and_blender_plays_them_within_the_tolerance(take):
    """`interpolation="bezier"` (FORMATS.md §4.2): Bézier keys with Auto Clamped handles (smoothing
    None) computed by Blender, where output/bezier.py puts them; evaluated by Blender at every
    sample frame, every bone within the angle of the every-frame (linear) bake, the root within
    the distance; the keys are the linear bake's plus a few."""
    from bodycal_addon.blender.fcurves import object_fcurves
    from bodycal_addon.output import bezier

    bpy.ops.wm.read_homefile(use_empty=True)
    arm, _mesh, spec = rigs.build_procedural_avatar()
    anim = pl.retarget(take["rec"], take["user"], rt.procedural_avatar(spec), "rotations")
    anim.armature = arm.name
    linear = bake_animation(anim, arm, fps=take["rec"].fps, frame_start=1.0, tolerance_deg=0.1,
                            location_tolerance_mm=1.0, action_name="linear")
    result = bake_animation(anim, arm, fps=take["rec"].fps, frame_start=1.0, tolerance_deg=0.1,
                            location_tolerance_mm=1.0, action_name="bezier", interpolation="bezier")
    assert linear.keys < result.keys < 1.2 * linear.keys
    curves = object_fcurves(arm)
    for fc in curves.values():
        points = fc.keyframe_points
        assert fc.auto_smoothing == "NONE"
        assert {(k.interpolation, k.handle_left_type, k.handle_right_type) for k in points} == \
            {("BEZIER", "AUTO_CLAMPED", "AUTO_CLAMPED")}
        co, left, right = (np.empty(2 * len(points), np.float32) for _ in range(3))
        points.foreach_get("co", co)
        points.foreach_get("handle_left", left)
        points.foreach_get("handle_right", right)
        ends = np.zeros(len(points), bool)
        model = bezier.auto_clamped_handles(co[0::2], co[1::2, None], np.r_[True, ends[1:]], np.r_[ends[:-1], True])
        scale = max(1.0, float(np.abs(co[1::2]).max()))  # Blender computes in float32
        np.testing.assert_allclose(left[0::2], model[0], atol=1e-3)
        np.testing.assert_allclose(left[1::2], model[1][:, 0], atol=2e-5 * scale)
        np.testing.assert_allclose(right[1::2], model[3][:, 0], atol=2e-5 * scale)
    q = continuous_quaternions(anim.rotations)
    frames = 1.0 + np.arange(anim.frame_count)
    got = np.stack([[[curves[(f'pose.bones["{b}"].rotation_quaternion', i)].evaluate(f) for i in range(4)]
                     for b in anim.bone_names] for f in frames])
    worst = np.degrees(keyreduce.rotation_error(q, got).max())
    assert 0.01 < worst <= 0.1 + 1e-3, worst  # really reduced; float32 keys: micro-degrees on top of the bound
    root = np.stack([[curves[(f'pose.bones["{anim.root_bone}"].location', i)].evaluate(f) for i in range(3)]
                     for f in frames])
    assert np.linalg.norm(root - anim.root_location, axis=1).max() <= 1e-3 + 1e-6


def test_the_bound_holds_in_armature_units_on_a_scaled_armature(take):
    """The location tolerance is in world millimetres: on an armature scaled x0.01 (FBX-style, data
    in centimetres) the root keys stay within 1 mm in the world, not 1 mm of armature units."""
    bpy.ops.wm.read_homefile(use_empty=True)
    arm, _mesh, spec = rigs.build_procedural_avatar()
    anim = pl.retarget(take["rec"], take["user"], rt.procedural_avatar(spec), "rotations")
    anim.root_location = anim.root_location * 100.0  # the same motion in centimetre armature units
    arm.scale = (0.01, 0.01, 0.01)
    bake_animation(anim, arm, fps=take["rec"].fps, frame_start=1.0, tolerance_deg=0.1, location_tolerance_mm=1.0)
    loc = anim.root_location.astype(np.float32)  # as the bake keys it
    keep, values = keyreduce.location_keys(loc, 1e-3 * 100.0)
    approx = keyreduce.interpolate(np.arange(len(loc), dtype=float), keep, values.astype(float))
    assert np.linalg.norm(approx - loc, axis=1).max() * 0.01 <= 1e-3 + 1e-9
    fc_keys = [len(fc.keyframe_points) for fc in _fcurves(arm) if fc.data_path.endswith(".location")]
    assert fc_keys == [int(keep.sum())] * 3


def _fcurves(arm):
    from bodycal_addon.blender.fcurves import object_fcurves

    return list(object_fcurves(arm).values())


def test_fps_resamples_with_the_timing_kept_and_the_blend_is_compressed(take, tmp_path):
    out = tmp_path / "at30.blend"
    res = _run("retarget", take["rec_path"], "--user", take["user_path"], "--avatar", take["blend"], "--fps", "30",
               "-o", out)
    assert res.returncode == 0, res.stderr[-2000:]
    assert out.read_bytes()[:4] == ZSTD_MAGIC
    bpy.ops.wm.open_mainfile(filepath=str(out), load_ui=False)
    scene = bpy.context.scene
    assert (scene.render.fps, scene.render.fps_base) == (30, 1.0)
    rec = take["rec"]
    duration = rec.time[-1] - rec.time[0]
    assert scene.frame_end - scene.frame_start == int(np.floor(duration * 30 + 1e-6))
    keyed = {tuple(fc.keyframe_points[i].co)[0] for fc in _fcurves(_the_armature())
             for i in (0, len(fc.keyframe_points) - 1)}
    assert min(keyed) == scene.frame_start and max(keyed) == scene.frame_end
    assert all(float(k).is_integer() for k in keyed)


def test_fps_0_is_the_takes_rate_and_the_frame_range_limits_the_bake(take, tmp_path):
    """`--fps 0` keys the recording's samples at its rate (as the sidebar's 0); `--frame-range`
    bakes only those frames of the take (its first sample is frame 1), and the output's scene
    range is theirs."""
    out = tmp_path / "shot.blend"
    res = _run("retarget", take["rec_path"], "--user", take["user_path"], "--avatar", take["blend"], "--fps", "0",
               "--frame-range", "11", "40", "--tolerance", "0", "--location-tolerance", "0", "-o", out)
    assert res.returncode == 0, res.stderr[-2000:]
    assert "30 frames (11-40)" in res.stdout
    bpy.ops.wm.open_mainfile(filepath=str(out), load_ui=False)
    scene = bpy.context.scene
    assert scene.render.fps / scene.render.fps_base == pytest.approx(take["rec"].fps, rel=1e-6)
    keyed = np.unique(np.concatenate([[k.co[0] for k in fc.keyframe_points] for fc in _fcurves(_the_armature())]))
    np.testing.assert_array_equal(keyed, np.arange(11, 41))
    assert (scene.frame_start, scene.frame_end) == (11, 40)


@pytest.mark.parametrize("bad, words", [
    (("--tolerance", "-1"), ("tolerance", ">= 0")),
    (("--tolerance", "nan"), ("tolerance", ">= 0")),
    (("--fps", "-1"), ("frame rate", "1 to 1000")),
    (("--frame-range", "40", "11"), ("--frame-range", "FIRST <= LAST")),
    (("--frame-range", "5000", "5100"), ("frame range", "holds none of the take's frames")),
    (("-o", "OUT.obj"), ("cannot write a '.obj' file", ".fbx")),
])
def test_bad_output_options_are_one_line(take, tmp_path, bad, words):
    args = ["retarget", take["rec_path"], "--user", take["user_path"], "--avatar", take["blend"]]
    if bad[0] == "-o":
        args += ["-o", tmp_path / bad[1]]
    else:
        args += [*bad, "-o", tmp_path / "x.blend"]
    res = _run(*args)
    assert res.returncode == 2
    assert "Traceback" not in res.stderr
    (line,) = res.stderr.strip().splitlines()
    for w in words:
        assert w in line, line
    assert not list(tmp_path.iterdir())


def _heads(arm, bones, frames) -> np.ndarray:
    scene = bpy.context.scene
    out = []
    for f in frames:
        scene.frame_set(int(f))
        bpy.context.view_layer.update()
        m = np.array(arm.matrix_world)
        out.append([(m @ np.append(np.array(arm.pose.bones[b].head), 1.0))[:3] for b in bones])
    return np.array(out)


def _import(path: Path, fps: int):
    """Into an empty scene at the export's rate (glTF stores seconds; the importer keys them at the
    scene's rate)."""
    bpy.ops.wm.read_homefile(use_empty=True)
    bpy.context.scene.render.fps = fps
    suffix = path.suffix.lower()
    if suffix == ".fbx":
        bpy.ops.import_scene.fbx(filepath=str(path), anim_offset=0.0)
    elif suffix in (".glb", ".gltf"):
        bpy.ops.import_scene.gltf(filepath=str(path))
    else:
        # Blender's BVH exporter writes the armature's own axes (Z up here): read them as they are.
        bpy.ops.import_anim.bvh(filepath=str(path), frame_start=1, use_fps_scale=False, update_scene_fps=True,
                                update_scene_duration=True, axis_forward="Y", axis_up="Z")
    return _the_armature()


@pytest.mark.slow
def test_each_export_reimports_with_the_joints_where_the_blend_has_them(take, tmp_path):
    """Round trip through Blender's own importers: every mapped bone's head within 1 mm of the
    baked .blend's at frames spread over the take."""
    outs = [tmp_path / f"take{s}" for s in (".blend", ".fbx", ".glb", ".gltf", ".bvh")]
    args = ["retarget", take["rec_path"], "--user", take["user_path"], "--avatar", take["blend"], "--fps", "30"]
    for o in outs:
        args += ["-o", o]
    res = _run(*args)
    assert res.returncode == 0, res.stderr[-2000:]
    assert all(o.is_file() for o in outs)
    bpy.ops.wm.open_mainfile(filepath=str(outs[0]), load_ui=False)
    arm = _the_armature()
    bones = [b.name for b in arm.data.bones if not b.name.lower().startswith("root")]
    scene = bpy.context.scene
    frames = np.linspace(scene.frame_start, scene.frame_end, 7).round().astype(int)
    fps = scene.render.fps
    truth = _heads(arm, bones, frames)
    for path in outs[1:]:
        other = _import(path, fps)
        got = _heads(other, bones, frames - (frames[0] - 1 if path.suffix == ".bvh" else 0))
        err = np.linalg.norm(got - truth, axis=-1)
        assert err.max() <= 1e-3, (path.suffix, float(err.max()), bones[int(np.argmax(err.max(0)))])


def test_exported_clips_are_named_after_the_baked_action(tmp_path):
    """A game engine shows the FBX take and the glTF animation by name: each is the baked
    action's (the FBX importer names its action "<object>|<take>"), not the scene's or a fixed
    "Animation", even when another scene already has the action's name; the scenes keep theirs."""
    from bodycal_addon.blender.export import export_avatar
    from bodycal_addon.blender.fcurves import new_fcurve, write_keys

    bpy.ops.wm.read_homefile(use_empty=True)
    arm, _mesh, _spec = rigs.build_procedural_avatar()
    name = "demo_full|procedural|egocentric"
    action = bpy.data.actions.new(name)
    arm.animation_data_create().action = action
    arm.pose.bones["upperarm_l"].rotation_mode = "QUATERNION"
    frames = np.arange(1, 11, dtype=np.float32)
    for i, (a, b) in enumerate(((1.0, 0.9), (0.0, 0.3), (0.0, 0.1), (0.0, 0.0))):
        write_keys(new_fcurve(action, arm, 'pose.bones["upperarm_l"].rotation_quaternion', i, "upperarm_l"), frames,
                   np.linspace(a, b, len(frames), dtype=np.float32))
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 10
    other = bpy.data.scenes.new(name)
    scene_name = scene.name
    outs = [tmp_path / f"clip{s}" for s in (".fbx", ".glb", ".gltf")]
    for out in outs:
        export_avatar(arm, out)
    assert scene.name == scene_name and other.name == name
    imported = _import(outs[0], 30)
    assert imported.animation_data.action.name == f"{imported.name}|{name}"
    # glTF: the animation's name in the file (Blender 4.2's importer appends the object's name to
    # the action it makes of it; 4.5 and 5.0 do not)
    for out in outs[1:]:
        assert _gltf_animation_names(out) == [name], out.suffix


def _gltf_animation_names(path) -> list[str]:
    data = path.read_bytes()
    if path.suffix == ".glb":  # 12-byte header, then the JSON chunk: its length, its type, its bytes
        length = int.from_bytes(data[12:16], "little")
        assert data[16:20] == b"JSON"
        data = data[20:20 + length]
    return [a.get("name") for a in json.loads(data).get("animations", [])]


SAVE_MEMORY_SCRIPT = """
import sys
import bpy
import numpy as np
sys.path.insert(0, sys.argv[-1])
from bodycal_addon.blender.blendfile import save_blend
from bodycal_addon.blender.fcurves import new_fcurve, write_keys

def rss_mb():
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) for line in f if line.startswith("VmRSS:")) / 1024

bpy.ops.wm.read_factory_settings(use_empty=True)
arm = bpy.data.objects.new("A", bpy.data.armatures.new("A"))
bpy.context.scene.collection.objects.link(arm)
arm.animation_data_create()
arm.animation_data.action = act = bpy.data.actions.new("big")
n = 170000
frames = np.arange(n, dtype=np.float32)
values = np.random.default_rng(0).random(n)
for path in ("location", "rotation_euler", "scale", "delta_location"):
    for i in range(3):
        write_keys(new_fcurve(act, arm, path, i), frames, values)
before = rss_mb()
save_blend(sys.argv[-2])
print("GROWTH", rss_mb() - before)
"""


def test_saving_does_not_copy_the_baked_action(tmp_path):
    """The bake's memory (BLENDER_NOTES.md): `bpy.ops` updates the view layer around every call, and
    that copies each action into the depsgraph (2 M keys: ~140 MB; a 10-minute bake: +650 MB at the
    command's peak). save_blend writes the file without that copy."""
    script = tmp_path / "save_memory.py"
    script.write_text(SAVE_MEMORY_SCRIPT)
    out = tmp_path / "big.blend"
    proc = subprocess.run([sys.executable, str(script), str(out), str(REPO)], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    growth = float(proc.stdout.split("GROWTH")[-1])
    assert growth < 40.0, f"saving grew the process by {growth:.0f} MB"
    assert out.stat().st_size > 0


def test_a_released_animation_bakes_the_same_keys(take):
    """The command gives its animation away (release): it is keyed from float32 rotations, Blender's
    own precision, and the action is the one the kept animation bakes, key for key."""
    from bodycal_addon.blender import session
    from bodycal_addon.blender.fcurves import object_fcurves, read_keys
    from bodycal_addon.retarget.takes import RecordingTake

    actions = []
    for release in (False, True):
        bpy.ops.wm.read_homefile(use_empty=True)
        arm, _mesh, _spec = rigs.build_procedural_avatar()
        target = session.prepare_target(arm)
        recording_take = RecordingTake(take["rec"], take["user"])
        computed = session.compute(recording_take, target, session.Settings("egocentric"))
        anim = computed.animation
        summary = session.bake(recording_take, target, computed, release=release)
        assert (anim.rotations.dtype == np.float32) == release
        curves = object_fcurves(arm)
        actions.append((summary.keys, {k: np.stack(read_keys(fc)) for k, fc in curves.items()}))
    (keys_kept, kept), (keys_released, released) = actions
    assert keys_kept == keys_released and kept.keys() == released.keys()
    for k in kept:
        np.testing.assert_array_equal(kept[k], released[k], err_msg=str(k))


def test_the_bones_the_reduction_cannot_thin_are_named_in_the_summary():
    """A bone whose rotation jitters by more than the tolerance keeps nearly every frame: the
    summary line names it, and only it (the smooth bones are thinned), with what helps for the
    kind of take; a tolerance of 0 asks for every frame, so nothing is named."""
    from bodycal_addon.blender.bake import DENSE_FRACTION
    from bodycal_addon.blender.session import Summary
    from bodycal_addon.body.animation import AvatarAnimation
    from bodycal_addon.core import transforms as tf

    bones = ["upperarm_l", "lowerarm_l", "thigh_r", "spine_02", "head"]
    frames = 300
    t = np.arange(frames) / 90.0
    swing = tf.axis_angle_to_quat(np.array([0.0, 0.6, 0.8]), 0.5 * np.sin(2.0 * t))
    q = np.repeat(swing[:, None], len(bones), axis=1)
    rng = np.random.default_rng(5)
    jitter = tf.axis_angle_to_quat(tf.normalize(rng.normal(size=(frames, 3))), np.full(frames, np.radians(0.5)))
    q[:, 3] = tf.quat_mul(q[:, 3], jitter)  # spine_02: 0.5 deg of jitter against a 0.1 deg tolerance
    anim = AvatarAnimation("procedural", bones, q, "pelvis", np.zeros((frames, 3)), t, method="egocentric")
    for tol, named in ((0.1, ("spine_02",)), (0.0, ())):
        bpy.ops.wm.read_homefile(use_empty=True)
        arm, _mesh, _spec = rigs.build_procedural_avatar()
        result = bake_animation(anim, arm, fps=90.0, frame_start=1.0, tolerance_deg=tol)
        assert result.dense_bones == named
        line = Summary(result.action.name, "egocentric", frames, result.keys, 0.0, 0.0, 90.0,
                       samples=result.samples, dense_bones=result.dense_bones).line()
        assert (f"1 bone kept over {DENSE_FRACTION:.0%} of the frames (spine_02)" in line) == bool(named), line
        # A transfer's take has no devices to smooth: its note says to smooth the source instead.
        moved = Summary(result.action.name, "egocentric", frames, result.keys, 0.0, 0.0, 90.0,
                        samples=result.samples, dense_bones=result.dense_bones, kind="animation").line()
        assert ("smoothing the devices" in line and "--filter" in line) == bool(named), line
        assert "device" not in moved, moved
        assert ("smoothing the source (Smooth Source, --filter) or a larger tolerance keeps fewer keys"
                in moved) == bool(named), moved
