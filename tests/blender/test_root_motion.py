"""Root motion (DESIGN.md §1, FORMATS.md §4.4): on a rig with a root bone above the pelvis (the
MakeHuman game-engine sample, Unreal names: Root -> pelvis) the travel of a walk goes on the root
bone, on the floor under the pelvis and turned with its heading; the pelvis is keyed relative to it,
so every bone lands where the pelvis-only bake puts it. In place keeps the pelvis on its spot."""

from __future__ import annotations

import subprocess
import sys

import bpy
import numpy as np
import pytest
from repo_paths import REPO

from bodycal_addon.app.batch import load_jobs
from bodycal_addon.blender import avatar_calibration as ac
from bodycal_addon.blender import avatar_rig, bake, rig_output
from bodycal_addon.calibration import calibrate_user
from bodycal_addon.core import paths
from bodycal_addon.core.errors import BodyCalError
from bodycal_addon.recording import io as recording_io
from bodycal_addon.retarget.pipeline import retarget
from evaluation import bvh, capture, performer, session

rigs = paths.sample_rigs()


@pytest.fixture(scope="module")
def walk(data_dir, tmp_path_factory):
    """CMU 02_01: a few steps forward and a turn, as an outside tool records it."""
    perf = performer.Performer(bvh.read(data_dir / "motion" / "cmu_bvh" / "02_01_walk.bvh").resampled(90.0))
    sess = session.build_session(perf, seed=0)
    cap = capture.capture(sess, perf, "full", seed=0)
    path = cap.write(tmp_path_factory.mktemp("walk") / "walk.bcrec.json")
    rec = recording_io.load_recording(path)
    return rec, calibrate_user(rec), path


@pytest.fixture(scope="module")
def walked(walk, avatar_files):
    """The engine's animation of the walk on the adult male (computed once; each test re-imports
    the avatar since the scene is reset)."""
    rec, user, _path = walk
    path = next(p for p in avatar_files if p.stem == "adult_male")
    arm, _mesh = rigs.load_glb_avatar(path)
    return path, retarget(rec, user, ac.calibrate_avatar(arm), "egocentric")


def _world_heads(arm, frames) -> np.ndarray:
    """(len(frames), bones, 3) every bone's evaluated world head, in Blender's own pose evaluation."""
    out = []
    mw = np.array(arm.matrix_world)
    for f in frames:
        bpy.context.scene.frame_set(int(f))
        out.append([(mw @ np.append(np.array(pb.head), 1.0))[:3] for pb in arm.pose.bones])
    return np.array(out)


def _bake(arm, anim, mode):
    keyed = rig_output.with_root_motion(anim, arm, avatar_rig.bone_map_for(arm), mode)
    res = bake.bake_animation(keyed, arm, action_name=mode, frame_start=1, tolerance_deg=0.0,
                              location_tolerance_mm=0.0)
    return keyed, res


def test_the_root_carries_the_walk_and_every_bone_stays_where_it_was(walked):
    path, anim = walked
    arm, _mesh = rigs.load_glb_avatar(path)
    assert rig_output.root_bone_of(arm, anim.root_bone, avatar_rig.bone_map_for(arm)) == "Root"
    frames = np.linspace(1, anim.frame_count, 7).round()
    _bake(arm, anim, "pelvis")
    ref = _world_heads(arm, frames)
    keyed, _ = _bake(arm, anim, "root")
    assert "Root" in keyed.bone_locations
    got = _world_heads(arm, frames)
    names = [pb.name for pb in arm.pose.bones]
    body = [i for i, pb in enumerate(arm.pose.bones) if pb.name == "pelvis" or "pelvis" in
            [p.name for p in pb.parent_recursive]]
    assert len(body) > 50
    assert np.abs(got[:, body] - ref[:, body]).max() < 1e-3  # <= 1 mm on every bone of the body
    root, pelvis = got[:, names.index("Root")], got[:, names.index("pelvis")]
    assert np.linalg.norm(root[-1, :2] - root[0, :2]) > 1.0  # the walk travels, and the root with it
    assert np.linalg.norm(root[:, :2] - pelvis[:, :2], axis=-1).max() < 0.01  # under the pelvis
    rest_z = (np.array(arm.matrix_world) @ np.append(np.array(arm.data.bones["Root"].head_local), 1.0))[2]
    assert np.abs(root[:, 2] - rest_z).max() < 1e-5  # on the floor, at its rest height
    # turned with the pelvis: the root's heading follows the hip line's
    bpy.context.scene.frame_set(int(frames[-1]))
    mw = np.array(arm.matrix_world)[:3, :3]
    hip = (mw @ (np.array(arm.pose.bones["thigh_l"].head) - np.array(arm.pose.bones["thigh_r"].head)))[:2]
    bones = arm.data.bones
    rest_hip = (mw @ (np.array(bones["thigh_l"].head_local) - np.array(bones["thigh_r"].head_local)))[:2]
    turn = np.array(arm.pose.bones["Root"].matrix)[:3, :3] @ np.array(arm.data.bones["Root"].matrix_local)[:3, :3].T
    moved = (mw @ turn @ np.linalg.solve(mw, np.append(rest_hip, 0.0)))[:2]
    ang = np.degrees(np.arctan2(hip[1], hip[0]) - np.arctan2(moved[1], moved[0]))
    assert abs((ang + 180) % 360 - 180) < 0.5


def test_in_place_keeps_the_pelvis_on_its_spot(walked):
    path, anim = walked
    arm, _mesh = rigs.load_glb_avatar(path)
    frames = np.linspace(1, anim.frame_count, 9).round()
    _bake(arm, anim, "pelvis")
    ref = _world_heads(arm, frames)
    _bake(arm, anim, "in-place")
    got = _world_heads(arm, frames)
    names = [pb.name for pb in arm.pose.bones]
    p, r = names.index("pelvis"), names.index("Root")
    assert np.linalg.norm(ref[-1, p, :2] - ref[0, p, :2]) > 1.0  # it walked
    assert np.linalg.norm(got[:, p, :2] - got[0, p, :2], axis=-1).max() < 1e-3  # now it stays
    np.testing.assert_allclose(got[:, p, 2], ref[:, p, 2], atol=1e-4)  # at its height
    np.testing.assert_allclose(got[:, r], got[:1, r].repeat(len(frames), 0), atol=1e-6)  # root at rest
    # the body relative to its pelvis is the same motion
    body = [i for i, pb in enumerate(arm.pose.bones) if "pelvis" in [q.name for q in pb.parent_recursive]]
    np.testing.assert_allclose(got[:, body] - got[:, p:p + 1], ref[:, body] - ref[:, p:p + 1], atol=1e-3)


def test_a_rig_without_a_root_bone_keeps_the_travel_on_the_pelvis(walked):
    path, anim = walked
    arm, _mesh = rigs.load_glb_avatar(path)
    # Unparent the pelvis: the Root bone is no longer above it, so nothing carries the travel there.
    bpy.context.view_layer.objects.active = arm
    bpy.ops.object.mode_set(mode="EDIT")
    arm.data.edit_bones["pelvis"].parent = None
    bpy.ops.object.mode_set(mode="OBJECT")
    assert rig_output.root_bone_of(arm, "pelvis", avatar_rig.bone_map_for(arm)) is None
    assert rig_output.with_root_motion(anim, arm, avatar_rig.bone_map_for(arm), "root") is anim


def test_an_unknown_root_motion_is_one_line():
    with pytest.raises(BodyCalError, match="unknown root motion 'feet'.*root, pelvis, in-place"):
        bake.BakeOptions(root_motion="feet")


def test_the_batch_settings_reach_every_job(tmp_path):
    (tmp_path / "jobs.toml").write_text('[defaults]\nroot_motion = "in-place"\nrigify_target = "def"\n'
                                        '[[recordings]]\npath="t.bcrec.json"\nuser="u.body.json"\n'
                                        '[[avatars]]\nfile="a.blend"\n')
    (job,), _settings = load_jobs(tmp_path / "jobs.toml")
    argv = job.argv()
    assert argv[argv.index("--root-motion") + 1] == "in-place" and argv[argv.index("--rigify-target") + 1] == "def"
    (tmp_path / "jobs.toml").write_text('[defaults]\nroot_motion = "feet"\n[[recordings]]\npath="t"\nuser="u"\n'
                                        '[[avatars]]\nfile="a.blend"\n')
    with pytest.raises(BodyCalError, match="defaults.root_motion.*\"root\" or \"pelvis\" or \"in-place\""):
        load_jobs(tmp_path / "jobs.toml")


@pytest.mark.slow
def test_the_command_line_keys_the_root_by_default_and_not_in_place(walk, avatar_files, tmp_path):
    _rec, user, rec_path = walk
    avatar = next(p for p in avatar_files if p.stem == "adult_male")
    user_path = user.save(tmp_path / "performer.body.json")
    for mode in ("root", "in-place"):
        extra = [] if mode == "root" else ["--root-motion", mode]
        out = subprocess.run([sys.executable, "-m", "bodycal_addon", "retarget", str(rec_path), "--user",
                              str(user_path), "--avatar", str(avatar), "-o", str(tmp_path / f"{mode}.blend"), *extra],
                             cwd=REPO, capture_output=True, text=True, timeout=600)
        assert out.returncode == 0, out.stderr[-2000:]
        bpy.ops.wm.open_mainfile(filepath=str(tmp_path / f"{mode}.blend"))
        arm = next(o for o in bpy.data.objects if o.type == "ARMATURE")
        scene = bpy.context.scene
        ends = []
        for f in (scene.frame_start, scene.frame_end):
            scene.frame_set(f)
            ends.append((np.array(arm.pose.bones["Root"].head), np.array(arm.pose.bones["pelvis"].head)))
        root_travel = np.linalg.norm(ends[1][0][:2] - ends[0][0][:2])
        pelvis_travel = np.linalg.norm(ends[1][1][:2] - ends[0][1][:2])
        if mode == "root":
            assert root_travel > 1.0 and pelvis_travel > 1.0
        else:
            assert root_travel < 1e-6 and pelvis_travel < 1e-3
    bad = subprocess.run([sys.executable, "-m", "bodycal_addon", "retarget", str(rec_path), "--user", str(user_path),
                          "--avatar", str(avatar), "-o", str(tmp_path / "x.blend"), "--root-motion", "feet"],
                         cwd=REPO, capture_output=True, text=True, timeout=600)
    assert bad.returncode == 2 and len(bad.stderr.strip().splitlines()) == 1 and "Traceback" not in bad.stderr
