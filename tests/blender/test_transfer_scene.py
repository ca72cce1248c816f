"""Animation transfer in Blender (DESIGN.md §8): a real CMU BVH (a bare skeleton: its body
estimated) onto the shared avatars, the action read from its F-Curves against Blender's own pose, a
skinned character's action onto another avatar, and `bodycal transfer` on the command line."""

from __future__ import annotations

import subprocess
import sys

import bpy
import numpy as np
import pytest
from repo_paths import REPO

from bodycal_addon.avatar.estimate import estimate_surface
from bodycal_addon.blender import avatar_rig, avatar_storage, blendfile, mesh_metrics
from bodycal_addon.blender import character_source as ts
from bodycal_addon.blender.avatar_calibration import avatar_model_for
from bodycal_addon.body.skeleton import JOINT_INDEX as JI
from bodycal_addon.core import paths
from bodycal_addon.core.errors import BodyCalError
from bodycal_addon.retarget import avatar_pose as ap
from bodycal_addon.retarget import feet
from bodycal_addon.retarget.pose_source import AnimationSource

WALK = "02_01_walk.bvh"


def _bvh(data_dir):
    return data_dir / "motion" / "cmu_bvh" / WALK


def test_the_action_read_from_its_fcurves_poses_as_blender_does(data_dir):
    ts.open_source(_bvh(data_dir))
    arm = blendfile.find_armature(None, WALK)
    src = ts.read_source(arm)
    assert src.fps == pytest.approx(120.0, rel=1e-3) and len(src.time) == 343
    # Blender's own pose at a few frames against the engine's FK of the arrays read (before the
    # bare skeleton is stood on its floor: compare the rest as the file has it).
    model = estimate_surface(avatar_rig.read_rig(arm), arm.name)
    rig = ap.AvatarRig.from_model(model)
    frames = np.array([1.0, 77.0, 200.0, 343.0])
    basis, locations = ts.read_action(arm, arm.animation_data.action, rig.names, frames)
    pose = rig.fk(basis, locations[:, rig.root], locations=locations)
    for k, f in enumerate(frames):
        bpy.context.scene.frame_set(int(f))
        for i, name in enumerate(rig.names):
            pb = arm.pose.bones[name]
            np.testing.assert_allclose(pose.heads[k, i], np.array(pb.head), atol=1e-5, err_msg=name)
            np.testing.assert_allclose(pose.rotations[k, i], np.array(pb.matrix.to_3x3()), atol=1e-5, err_msg=name)
    # An action that keys none of its bones is one error, not a still character.
    with pytest.raises(BodyCalError, match="animates none of the armature's bones"):
        ts.read_source(arm, bpy.data.actions.new("empty"))
    assert arm.animation_data.action.name == "02_01_walk"


def test_every_rotation_mode_is_read_as_blender_poses_it():
    """Hand-keyed rigs use any rotation mode: each Euler order and axis-angle (with an unnormalised
    axis, and a zero axis, which Blender reads as no turn) give the rotation Blender poses."""
    from bodycal_addon.blender.fcurves import new_fcurve, write_keys

    bpy.ops.wm.read_homefile(use_empty=True)
    arm, _mesh, _spec = paths.sample_rigs().build_procedural_avatar()
    modes = ["XYZ", "XZY", "YXZ", "YZX", "ZXY", "ZYX", "AXIS_ANGLE", "AXIS_ANGLE"]
    names = [b.name for b in arm.pose.bones][1:1 + len(modes)]
    rng = np.random.default_rng(4)
    action = bpy.data.actions.new("modes")
    arm.animation_data_create().action = action
    frames = np.array([1.0, 2.0, 3.0], np.float32)
    for k, (name, mode) in enumerate(zip(names, modes)):
        arm.pose.bones[name].rotation_mode = mode
        esc = bpy.utils.escape_identifier(name)
        if mode == "AXIS_ANGLE":
            values = np.column_stack([rng.uniform(-3, 3, 3), 2.5 * rng.normal(size=(3, 3))])
            if k == len(modes) - 1:
                values[1, 1:] = 0.0  # a zero axis with a turn of its own
            path = f'pose.bones["{esc}"].rotation_axis_angle'
        else:
            values = rng.uniform(-3, 3, (3, 3))
            path = f'pose.bones["{esc}"].rotation_euler'
        for c in range(values.shape[1]):
            write_keys(new_fcurve(action, arm, path, c, name), frames, values[:, c])
    basis, _locations = ts.read_action(arm, action, names, frames.astype(float))
    for f, frame in enumerate(frames):
        bpy.context.scene.frame_set(int(frame))
        for i, name in enumerate(names):
            want = np.array(arm.pose.bones[name].matrix_basis.to_quaternion())
            got = basis[f, i]
            assert min(np.abs(got - want).max(), np.abs(got + want).max()) < 1e-5, (name, modes[i], got, want)


@pytest.mark.parametrize("avatar", ["adult_male", "child_10y"])
def test_a_bvh_transfers_with_no_nan_and_the_feet_on_the_floor(data_dir, avatar):
    ts.open_source(_bvh(data_dir))
    src = ts.read_source(blendfile.find_armature(None, WALK))
    assert src.estimated and any("estimated from its bone lengths" in n for n in src.notes)
    walker = AnimationSource(src.model, src.basis, src.locations, src.time)
    rest = {s: float(src.model.joints[f"ankle_{s}"].world[2]) for s in "lr"}
    stance = {s: feet.detect(walker.ankle(s), src.time, rest[s]).weight >= 1.0 for s in "lr"}
    assert all(0.2 < v.mean() < 0.8 for v in stance.values())  # a walk: each foot down part of the time
    blendfile.open_avatar(data_dir / "avatars" / "mpfb2_variants" / f"{avatar}.glb")
    arm = blendfile.find_armature(None, avatar)
    model, _ = avatar_model_for(arm)
    # The feet roll (DESIGN.md §6 "Planted feet"): what stays put is the heel while the source's
    # heel is down and the ball while its ball is, both measured on the avatar's skin at calibration.
    src_pose = walker.pose(0, walker.frame_count)
    k = ap.AvatarRig.from_model(model).leg_length() / ap.AvatarRig.from_model(src.model).leg_length()
    for method in ("egocentric", "rotations"):
        anim = src.animate(model, method)
        assert np.isfinite(anim.rotations).all() and np.isfinite(anim.root_location).all()
        assert any("estimated" in n for n in anim.notes)
        points = {s: mesh_metrics.contact_points(model, anim, s) for s in "lr"}
        for s in "lr":
            low = points[s]["support"][..., 2].min(axis=1)[stance[s]]
            assert np.percentile(np.abs(low), 95) < 0.005, (method, s)
            for part, joint in (("heel", "ankle"), ("ball", "toe")):
                source = src_pose.joints[:, JI[f"{joint}_{s}"]]
                down = measure_contact(source, src.fps)
                both = down[1:] & down[:-1]
                mine = np.percentile(np.linalg.norm(np.diff(points[s][part][:, :2], axis=0), axis=1)[both], 95)
                theirs = np.percentile(np.linalg.norm(np.diff(source[:, :2], axis=0), axis=1)[both], 95) * k
                assert mine <= max(1.5 * theirs, 1e-3), (method, s, part, mine, theirs)
        # the walk goes somewhere: the avatar's pelvis travels as far as its legs scale the source's
        assert np.ptp(anim.joints_world["pelvis"][:, :2], axis=0).max() > 1.0


def measure_contact(point: np.ndarray, fps: float) -> np.ndarray:
    """(F,) bool: the source's point on the ground (metrics.ground_contact: slower than 0.15 m/s
    and within 3 cm of its lowest 5 %)."""
    from bodycal_addon.output import metrics

    return metrics.ground_contact(point, fps)


def test_a_skinned_characters_action_transfers_onto_another_avatar(data_dir, tmp_path):
    """A character with a mesh is measured by the raycasts (not estimated): bake a BVH walk onto the
    adult avatar, save it, and transfer that action from the .blend onto the child."""
    out = tmp_path / "male_walk.blend"
    fbx = tmp_path / "male_walk.fbx"
    done = _run("transfer", str(_bvh(data_dir)), "--avatar",
                str(data_dir / "avatars" / "mpfb2_variants" / "adult_male.glb"), "-o", str(out), "-o", str(fbx))
    assert done.returncode == 0, done.stderr
    assert "estimated from its bone lengths" in done.stdout and "saved" in done.stdout
    # stdout carries BodyCal's lines only: not the BVH reader's, the glTF importer's nor Blender's
    # reports (FORMATS.md §4); the same run with --verbose shows them.
    for chatter in ("parsing bvh", "INFO:", "Info: Saved"):
        assert chatter not in done.stdout, done.stdout
    assert done.stderr == ""
    # The same character as an FBX (Blender's importer: its own object transform and action).
    done = _run("transfer", str(fbx), "--avatar", str(data_dir / "avatars" / "mpfb2_variants" / "child_10y.glb"),
                "-o", str(tmp_path / "child_from_fbx.blend"))
    assert done.returncode == 0 and "estimated" not in done.stdout, done.stderr
    child = tmp_path / "child_walk.glb"
    done = _run("transfer", str(out), "--avatar", str(data_dir / "avatars" / "mpfb2_variants" / "child_10y.glb"),
                "--method", "rotations", "-o", str(child))
    assert done.returncode == 0, done.stderr
    assert "estimated" not in done.stdout and child.stat().st_size > 10_000
    blendfile.open_blend(out)
    action = bpy.data.actions["02_01_walk|adult_male_rig|egocentric"]
    assert action.frame_range[1] - action.frame_range[0] == pytest.approx(342, abs=1)
    # Without the model the bake stored, the animated character is measured in its rest pose.
    arm = blendfile.find_armature(None, "male_walk")
    stored = avatar_storage.load_model(arm)
    avatar_storage.clear_model(arm)
    bpy.context.scene.frame_set(120)
    src = ts.read_source(arm)
    assert not src.estimated and arm.data.pose_position == "POSE"
    assert src.model.bones["thigh_l"].radius_head == pytest.approx(stored.bones["thigh_l"].radius_head, abs=1e-4)


def _run(*args):
    return subprocess.run([sys.executable, "-m", "bodycal_addon", *args], cwd=REPO, capture_output=True, text=True,
                          timeout=300)


def test_smoothing_the_source_calms_the_transferred_motion(data_dir):
    """`transfer --filter` (the sidebar's Smooth Source): the One Euro filter on the source's pose
    (each bone's rotation, the root's location in metres) before transferring. On the CMU walk
    (a capture at 120 fps, its jitter in it) the avatar's wrists and ankles accelerate less (p95, by
    a third or more), the source's own arrays are not changed, and the animation's notes say so."""
    from dataclasses import replace

    from bodycal_addon.recording.filters import OneEuro

    ts.open_source(_bvh(data_dir))
    src = ts.read_source(blendfile.find_armature(None, WALK))
    basis, locations = src.basis.copy(), src.locations.copy()
    blendfile.open_avatar(data_dir / "avatars" / "mpfb2_variants" / "adult_male.glb")
    model, _ = avatar_model_for(blendfile.find_armature(None, "adult_male"))
    for method in ("egocentric", "rotations"):
        raw = src.animate(model, method)
        calm = replace(src, filter=OneEuro()).animate(model, method)
        for joint in ("wrist_l", "wrist_r", "ankle_l", "ankle_r"):
            fast, slow = (np.percentile(np.linalg.norm(np.diff(a.joints_world[joint], 2, axis=0), axis=1), 95)
                          for a in (raw, calm))
            assert slow < 0.8 * fast, (method, joint, slow, fast)
        assert "One Euro filter on 02_01_walk's pose: position 3 Hz" in calm.notes[-1]
        assert not any("One Euro" in n for n in raw.notes)
    np.testing.assert_array_equal(src.basis, basis)
    np.testing.assert_array_equal(src.locations, locations)


def test_transfer_filter_and_progress_on_the_command_line(data_dir, tmp_path):
    """`transfer --filter 2,4` says how it smoothed the source; run at a terminal, its progress line
    goes through the run's stages (the method's share counted by the engine's chunks) and is erased,
    leaving BodyCal's lines."""
    from terminal import lines_left, run_in_terminal

    argv = [sys.executable, "-m", "bodycal_addon", "transfer", str(_bvh(data_dir)), "--avatar",
            str(data_dir / "avatars" / "mpfb2_variants" / "child_10y.glb"), "--method", "rotations",
            "--filter", "2,4", "--frame-range", "1", "60", "-o", str(tmp_path / "calm.blend")]
    code, received, err = run_in_terminal(argv, cwd=REPO, timeout=300)
    assert code == 0 and err == "", err
    shown = received.decode(errors="replace")
    for stage in ("reading", "opening the avatar", "measuring the avatar", "rotations", "baking", "saving"):
        assert f"\rbodycal transfer: {stage} " in shown, (stage, shown[-3000:])
    lines = lines_left(received)
    assert ("One Euro filter on 02_01_walk's pose: position 2 Hz + 4 Hz per m/s, rotation 4 Hz + 1 Hz per rad/s, "
            "forward and backward") in lines, lines
    assert lines[-1] == f"saved {tmp_path / 'calm.blend'}" and not any("%|" in line for line in lines)


@pytest.mark.parametrize("case", ["suffix", "missing", "action", "method", "output-is-source", "filter"])
def test_bad_input_is_one_line_and_exit_2(data_dir, tmp_path, case):
    avatar = str(data_dir / "avatars" / "mpfb2_variants" / "adult_male.glb")
    bvh = str(_bvh(data_dir))
    args = {
        "suffix": (str(tmp_path / "walk.txt"), "--avatar", avatar, "-o", str(tmp_path / "o.blend")),
        "missing": (str(tmp_path / "none.bvh"), "--avatar", avatar, "-o", str(tmp_path / "o.blend")),
        "action": (bvh, "--avatar", avatar, "--action", "dance", "-o", str(tmp_path / "o.blend")),
        "method": (bvh, "--avatar", avatar, "--method", "offsets", "-o", str(tmp_path / "o.blend")),
        "output-is-source": (bvh, "--avatar", avatar, "-o", bvh, "--overwrite"),
        "filter": (bvh, "--avatar", avatar, "--filter", "1,2,3", "-o", str(tmp_path / "o.blend")),
    }[case]
    (tmp_path / "walk.txt").write_text("not a clip")
    before = _bvh(data_dir).read_bytes()
    done = _run("transfer", *args)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1 and "Traceback" not in done.stderr, done.stderr
    assert {"suffix": "not an animation source", "missing": "no such file", "action": "no action named 'dance'",
            "method": "invalid choice", "output-is-source": "source",
            "filter": "expected 2 or 4 numbers"}[case] in lines[0]
    assert _bvh(data_dir).read_bytes() == before


def test_the_action_picker_lists_the_sources_actions_only():
    """Two armatures with an action each: with one picked as the source, the picker offers its own
    action and not the other's (their bones differ), the property's poll that Blender's search uses."""
    from sample_rigs import build_procedural_avatar

    transfer = __import__("bl_ext.user_default.bodycal.operators.transfer", fromlist=["x"])
    arms = []
    for name, bone in (("walker", "upperarm_l"), ("prop", "Bone")):
        if bone == "Bone":
            bpy.ops.object.armature_add()
            arm = bpy.context.active_object
        else:
            arm = build_procedural_avatar()[0]
        arm.name = name
        arm.pose.bones[bone].rotation_mode = "XYZ"
        arm.pose.bones[bone].keyframe_insert("rotation_euler", frame=1)
        arm.animation_data.action.name = f"{name}_action"
        arms.append(arm)
    settings = bpy.context.scene.bodycal_transfer
    settings.source = arms[0]
    poll = transfer.BODYCAL_PG_transfer_settings.__annotations__["action"].keywords["poll"]
    assert poll(settings, bpy.data.actions["walker_action"])
    assert not poll(settings, bpy.data.actions["prop_action"])
    settings.source = None
    assert poll(settings, bpy.data.actions["prop_action"])  # no source yet: every action


def test_the_panels_operator_transfers_onto_the_selected_avatars(data_dir):
    """The sidebar flow: a BVH and two avatars in one scene, the source picked, the targets
    selected; one new action on each target, none on the source."""
    from sample_rigs import load_glb_avatar

    bpy.ops.import_anim.bvh(filepath=str(_bvh(data_dir)), global_scale=ts.BVH_UNITS["cmu"], update_scene_fps=True)
    source = bpy.context.active_object
    settings = bpy.context.scene.bodycal_transfer
    settings.source = source
    assert not bpy.ops.bodycal.transfer_animation.poll()  # no target yet (the source alone is selected)
    targets = [load_glb_avatar(data_dir / "avatars" / "mpfb2_variants" / f"{n}.glb")[0]
               for n in ("adult_female", "heavy_belly_male")]
    bpy.ops.object.select_all(action="DESELECT")
    for arm in targets:
        arm.select_set(True)
    bpy.context.view_layer.objects.active = targets[0]
    before = set(bpy.data.actions)
    assert bpy.ops.bodycal.transfer_animation() == {"FINISHED"}
    new = set(bpy.data.actions) - before
    assert {a.name for a in new} == {f"02_01_walk|{t.name}|egocentric" for t in targets}
    assert all(t.animation_data.action in new for t in targets)
    assert source.animation_data.action.name == "02_01_walk"
    assert settings.last_result.count("Baked") == 2


def test_the_transfer_keys_the_source_actions_own_frames_within_the_range():
    """A source action keyed on frames 21-60 and a scene that starts at frame 1: the target's
    keys are on the source's frames (the whole action: 21-60; the scene range 1-30: 21-30), and
    the scene's range is left as it was."""
    from bodycal_addon.blender.fcurves import new_fcurve, object_fcurves, read_keys, write_keys
    from bodycal_addon.core import transforms as tf

    bpy.ops.wm.read_homefile(use_empty=True)
    rigs = paths.sample_rigs()
    source, _mesh, _spec = rigs.build_procedural_avatar()
    target, _mesh, _spec = rigs.build_procedural_avatar(scale=0.8)
    action = bpy.data.actions.new("wave")
    source.animation_data_create().action = action
    frames = np.arange(21, 61, dtype=np.float32)
    q = tf.axis_angle_to_quat(np.array([0.0, 1.0, 0.0]), np.linspace(0.0, 1.2, len(frames)))
    source.pose.bones["upperarm_l"].rotation_mode = "QUATERNION"
    for i in range(4):
        write_keys(new_fcurve(action, source, 'pose.bones["upperarm_l"].rotation_quaternion', i, "upperarm_l"),
                   frames, q[:, i].astype(np.float32))
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, 30
    scene.bodycal_transfer.source = source
    bake = scene.bodycal_bake
    bake.armature, bake.tolerance, bake.location_tolerance = target, 0.0, 0.0
    for frame_range, want in (("take", frames), ("scene", frames[frames <= 30])):
        bake.frame_range = frame_range
        assert bpy.ops.bodycal.transfer_animation() == {"FINISHED"}
        keyed = [read_keys(fc)[0] for fc in object_fcurves(target).values()]
        np.testing.assert_array_equal(np.unique(np.concatenate(keyed)), want)
        assert min(k[0] for k in keyed) == want[0]
        assert (scene.frame_start, scene.frame_end) == (1, 30)


def test_batch_jobs_take_animation_sources_beside_recordings(tmp_path):
    from bodycal_addon.app.batch import load_jobs

    (tmp_path / "jobs.toml").write_text('[defaults]\nmethod = ["egocentric", "offsets", "rotations"]\n'
                                        '[[recordings]]\npath="t.bcrec.json"\nuser="u.body.json"\n'
                                        '[[animations]]\npath="clips/walk.bvh"\n'
                                        '[[animations]]\npath="chars.blend"\nsource_armature="Walker"\naction="Run"\n'
                                        '[[avatars]]\nfile="ogre.glb"\n')
    jobs, _ = load_jobs(tmp_path / "jobs.toml")
    names = sorted(j.name for j in jobs)
    assert names == sorted([f"t__ogre__{m}" for m in ("egocentric", "offsets", "rotations")]
                           + [f"walk__ogre__{m}" for m in ("egocentric", "rotations")]
                           + [f"chars-Run__ogre__{m}" for m in ("egocentric", "rotations")])
    run = next(j for j in jobs if j.name == "chars-Run__ogre__rotations")
    assert run.argv() == ["transfer", str(tmp_path / "chars.blend"), "--avatar", str(tmp_path / "ogre.glb"),
                          "--method", "rotations", "--source-armature", "Walker", "--action", "Run",
                          "-o", str(tmp_path / "out" / "batch" / "chars-Run__ogre__rotations.blend")]
    (tmp_path / "jobs.toml").write_text('[defaults]\nmethod = "offsets"\n[[animations]]\npath="walk.bvh"\n'
                                        '[[avatars]]\nfile="ogre.glb"\n')
    with pytest.raises(BodyCalError, match="defaults.method: animations transfer with egocentric or rotations"):
        load_jobs(tmp_path / "jobs.toml")
    (tmp_path / "jobs.toml").write_text('[[animations]]\npath="walk.txt"\n[[avatars]]\nfile="ogre.glb"\n')
    with pytest.raises(BodyCalError, match=r"animations\[0\].path"):
        load_jobs(tmp_path / "jobs.toml")


def test_a_batch_transfers_a_bvh_onto_an_avatar(data_dir, tmp_path):
    import json

    (tmp_path / "jobs.toml").write_text(f'[defaults]\nmethod = "egocentric"\nworkers = 1\noutput_dir = "res"\n'
                                        f'[[animations]]\npath = "{_bvh(data_dir)}"\n'
                                        f'[[avatars]]\nfile = "{data_dir / "avatars/mpfb2_variants/child_10y.glb"}"\n')
    done = _run("batch", str(tmp_path / "jobs.toml"))
    assert done.returncode == 0, done.stderr
    summary = json.loads((tmp_path / "res" / "summary.json").read_text())
    assert summary["ok"] == 1 and (tmp_path / "res" / "02_01_walk__child_10y__egocentric.blend").is_file()
