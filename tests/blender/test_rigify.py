"""A generated Rigify rig (DESIGN.md §1, "Rigify"): ~410 bones, DEF-/ORG-/MCH- and FK/IK controls,
built from Rigify's human metarig fitted onto the procedural avatar (sample_rigs/rigify_rig.py,
generated once per session in a subprocess: Rigify hangs Blender 4.5 at exit). It is detected with
no manual step, calibrated on its DEF- bones, and the retargeted motion is keyed on its FK controls
(the animator's rig, IK switched to FK) or on its DEF- bones (export); either way Blender's own
evaluation of the DEF- bones and of the deformed mesh shows the engine's pose."""

from __future__ import annotations

import subprocess
import sys

import bpy
import numpy as np
import pytest
from repo_paths import REPO

from bodycal_addon.blender import avatar_calibration as ac
from bodycal_addon.blender import avatar_rig, bake, rig_output
from bodycal_addon.blender.fcurves import object_fcurves
from bodycal_addon.retarget.pipeline import retarget
from bodycal_dev import synthetic

# Bones whose whole pose the FK controls set: every DEF- bone but Rigify's own in-betweens (the
# second twist segment of each limb bone, the neck's middle, the palm fan), which its constraints
# share out between the controls as the rig was built to.
IN_BETWEEN = (".001", "DEF-spine.005", "DEF-palm.", "DEF-breast.", "DEF-pelvis.")


@pytest.fixture(scope="module")
def belly():
    performer = synthetic.make_performer(seed=5)
    rec, truth = synthetic.record_session(performer, profile="full", motions=("hand_on_belly",),
                                          calibration=["tpose"], seed=5, motion_seconds=1.5)
    return rec, truth.body_model()


def _open(path):
    bpy.ops.wm.open_mainfile(filepath=str(path))
    arm = bpy.data.objects["rigify_avatar"]
    mesh = next(o for o in bpy.data.objects if o.type == "MESH")
    return arm, mesh


def _bake(anim, arm, target):
    keyed = rig_output.for_bake(anim, arm, avatar_rig.bone_map_for(arm), "root", target)
    fps = (anim.frame_count - 1) / (anim.time[-1] - anim.time[0])  # key f lands on frame 1 + f
    res = bake.bake_animation(keyed, arm, action_name=target, frame_start=1, fps=fps, tolerance_deg=0.0,
                              location_tolerance_mm=0.0)
    return keyed, res


def _evaluate(arm, mesh, frames, bones):
    """Blender's own evaluation: DEF- bone heads and tails (armature space) and the deformed mesh."""
    ends, verts = [], []
    for f in frames:
        bpy.context.scene.frame_set(int(1 + f))
        dg = bpy.context.evaluated_depsgraph_get()
        m = [np.array(arm.pose.bones[n].matrix) for n in bones]
        ends.append([(x[:3, 3], x[:3, 3] + x[:3, 1] * arm.data.bones[n].length) for x, n in zip(m, bones)])
        ev = mesh.evaluated_get(dg)
        me = ev.to_mesh()
        co = np.empty(len(me.vertices) * 3)
        me.vertices.foreach_get("co", co)
        ev.to_mesh_clear()
        verts.append(co.reshape(-1, 3))
    return np.array(ends), np.array(verts)


def test_a_generated_rig_is_detected_and_calibrated_on_its_def_bones(rigify_blend):
    arm, _mesh = _open(rigify_blend)
    assert 350 < len(arm.data.bones) < 450 and arm.data.get("rig_id")
    assert avatar_rig.is_rigify_generated(arm)
    bm = avatar_rig.bone_map_for(arm)
    assert bm.scheme == "rigify" and bm.missing(with_fingers=True) == []
    assert bm.bones["upperarm_l"] == "DEF-upper_arm.L" and bm.bones["root"] == "root"
    parents = avatar_rig.deform_parents(arm)
    assert parents["DEF-thigh.L"] == "DEF-spine" and parents["DEF-upper_arm.L"] == "DEF-shoulder.L"
    assert parents["DEF-f_index.01.L"] == "DEF-palm.01.L" and parents["DEF-spine"] == "root"
    model = ac.calibrate_avatar(arm)
    assert set(model.extra["rig"]["bones"]) == set(parents)
    assert all(j.frame.startswith("DEF-") for j in model.joints.values() if j.frame)


@pytest.mark.slow
def test_fk_controls_and_def_bones_both_play_the_engine_pose(rigify_blend, belly, monkeypatch):
    monkeypatch.setattr(rig_output, "CHUNK_FRAMES", 100)  # the take in chunks, as a long one is
    rec, user = belly
    arm, mesh = _open(rigify_blend)
    anim = retarget(rec, user, ac.calibrate_avatar(arm), "egocentric")
    poses, _rest = rig_output.rigify_deform_pose(anim, arm)
    bones = sorted(n for n in poses if n.startswith("DEF-"))
    frames = np.linspace(0, anim.frame_count - 1, 5).round().astype(int)
    want = np.array([[(poses[n][f][:3, 3], poses[n][f][:3, 3] + poses[n][f][:3, 1] * arm.data.bones[n].length)
                      for n in bones] for f in frames])

    keyed, _ = _bake(anim, arm, "def")
    assert set(keyed.bone_names) == set(bones)
    got, def_mesh = _evaluate(arm, mesh, frames, bones)
    assert np.abs(got - want).max() < 1e-5  # the DEF- bake is the engine's pose, to float32

    keyed, _ = _bake(anim, arm, "fk")
    assert not any(n.startswith(("DEF-", "ORG-", "MCH-")) for n in keyed.bone_names)
    controls = {"torso", "upper_arm_fk.L", "forearm_fk.R", "thigh_fk.L", "foot_fk.R", "f_index.02.L"}
    assert controls <= set(keyed.bone_names)
    got, fk_mesh = _evaluate(arm, mesh, frames, bones)
    assert arm.pose.bones["upper_arm_parent.L"]["IK_FK"] == 1.0 and arm.pose.bones["thigh_parent.R"]["IK_FK"] == 1.0
    assert keyed.constant_keys['pose.bones["thigh_parent.R"]["IK_FK"]'] == 1.0
    err = np.linalg.norm(got - want, axis=-1).max(axis=(0, 2))  # per bone, head and tail, mm
    main = [i for i, n in enumerate(bones) if not any(k in n for k in IN_BETWEEN)]
    worst = {bones[i]: round(float(err[i]) * 1000, 2) for i in main if err[i] > 1e-3}
    assert not worst, worst  # every controlled DEF- bone within 1 mm
    assert err.max() < 3e-3  # the in-betweens too, within 3 mm
    d = np.linalg.norm(fk_mesh - def_mesh, axis=-1)
    assert np.percentile(d, 95) < 1e-3 and d.max() < 0.015, (np.percentile(d, 95), d.max())


@pytest.mark.slow
def test_the_command_line_bakes_a_rigify_rig_on_its_controls_or_its_def_bones(rigify_blend, tmp_path):
    truth_dir = tmp_path / "in"
    truth_dir.mkdir()
    performer = synthetic.make_performer(seed=5)
    rec, truth = synthetic.record_session(performer, profile="full", motions=("hand_on_belly",),
                                          calibration=["tpose"], seed=5, motion_seconds=1.5)
    rec_path, _ = synthetic.write_session(truth_dir, "belly", rec, truth)
    user_path = truth.body_model().save(truth_dir / "performer.body.json")
    for target in ("fk", "def"):
        out = subprocess.run([sys.executable, "-m", "bodycal_addon", "retarget", str(rec_path), "--user",
                              str(user_path), "--avatar", str(rigify_blend), "--rigify-target", target, "-o",
                              str(tmp_path / f"{target}.blend")], cwd=REPO, capture_output=True, text=True,
                             timeout=600)
        assert out.returncode == 0, out.stderr[-2000:]
        arm, _mesh = _open(tmp_path / f"{target}.blend")
        paths = {p for p, _i in object_fcurves(arm)}
        keyed = {p.split('"')[1] for p in paths if p.startswith("pose.bones")}
        if target == "fk":
            assert {"torso", "hand_fk.L", "thigh_fk.R"} <= keyed and not any(k.startswith("DEF-") for k in keyed)
            assert object_fcurves(arm)[('pose.bones["upper_arm_parent.L"]["IK_FK"]', 0)].evaluate(1) == 1.0
        else:
            assert {"DEF-spine", "DEF-hand.L"} <= keyed and "torso" not in keyed
            assert all(c.mute for c in arm.pose.bones["DEF-hand.L"].constraints)
    assert "Traceback" not in out.stderr


@pytest.mark.slow
@pytest.mark.parametrize("rigify_target", ["fk", "def"])
def test_a_failed_bake_leaves_the_rig_as_it_was(rigify_blend, belly, monkeypatch, rigify_target):
    """Getting a Rigify rig ready for its bake sets its IK/FK switches, mutes or unmutes its DEF-
    constraints, rests its controls and sets the scene's rate. When the bake then fails, all of
    that is put back and the rig's own action stays assigned."""
    from bodycal_addon.blender import session
    from bodycal_addon.retarget.takes import RecordingTake

    rec, user = belly
    arm, _mesh = _open(rigify_blend)
    scene = bpy.context.scene
    take, target = RecordingTake(rec, user), session.prepare_target(arm)
    computed = session.compute(take, target, session.Settings("egocentric"))
    scene.render.fps, scene.render.fps_base = 24, 1.0
    arm.pose.bones["upper_arm_parent.L"]["IK_FK"] = 0.0
    arm.pose.bones["forearm_fk.L"].rotation_quaternion = (0.9, 0.3, 0.2, 0.1)
    arm.pose.bones["torso"].location = (0.1, 0.0, 0.05)
    mine = bpy.data.actions.new("animator's")
    arm.animation_data_create().action = mine

    def state():
        return ({pb.name: (pb.rotation_mode, tuple(pb.location), tuple(pb.rotation_quaternion),
                           tuple(pb.rotation_euler), tuple(pb.scale),
                           {k: pb[k] for k in pb.keys() if isinstance(pb[k], (int, float, str))},
                           [c.mute for c in pb.constraints]) for pb in arm.pose.bones},
                dict(arm.items()), (scene.render.fps, scene.render.fps_base), arm.animation_data.action)

    before = state()
    calls = []

    def failing_write(*args, **kwargs):
        calls.append(1)
        if len(calls) > 40:
            raise RuntimeError("disk full")
        return write_keys(*args, **kwargs)

    from bodycal_addon.blender.fcurves import write_keys

    monkeypatch.setattr(bake, "write_keys", failing_write)
    with pytest.raises(RuntimeError, match="disk full"):
        session.bake(take, target, computed, set_scene_rate=True, options=bake.BakeOptions(rigify_target=rigify_target))
    assert len(calls) > 40  # it failed half way through the keys
    after = state()
    assert after[1:] == before[1:]
    changed = [n for n in before[0] if before[0][n] != after[0][n]]
    assert not changed, changed[:5]
    assert [a.name for a in bpy.data.actions if a.name.startswith(rec.name)] == []  # the half-made action went
