"""Placement in Blender (DESIGN.md §1, "Placement"): an armature object anywhere, turned and scaled,
plays the same body's performance relative to where it stands (retarget/placement.py), measured on
the baked, evaluated armature and mesh; the performer placement; the warnings a doubtful object
transform gets; two avatars in one file."""

from __future__ import annotations

import math

import bpy
import numpy as np
import pytest
from mathutils import Matrix

from bodycal_addon.avatar.estimate import sole_depth
from bodycal_addon.blender import avatar_storage, calibration_scene, mesh_metrics, recording_scene
from bodycal_addon.blender import session as bake_session
from bodycal_addon.blender.avatar_calibration import calibrate_avatar
from bodycal_addon.core import paths
from bodycal_addon.output import metrics
from bodycal_addon.retarget import avatar_pose as ap
from bodycal_addon.retarget import feet
from bodycal_addon.retarget.takes import RecordingTake
from bodycal_dev import synthetic

rigs = paths.sample_rigs()
MOVED = Matrix.Translation((2.0, -3.0, 0.0)) @ Matrix.Rotation(0.7, 4, "Z")


@pytest.fixture(scope="module")
def session():
    """Standing with a hand on the belly, then walking in place: contacts and planted feet."""
    perf = synthetic.make_performer(seed=5)
    rec, truth = synthetic.record_session(perf, motions=("hand_on_belly", "walk_in_place"), calibration=False,
                                          seed=5)
    rec.name = "belly_walk"
    return rec, truth, truth.body_model()


def _avatar(matrix=None, body_scale=1.0):
    arm, _mesh, _spec = rigs.build_procedural_avatar(scale=body_scale)
    if matrix is not None:
        arm.matrix_world = matrix
    bpy.context.view_layer.update()
    return arm


def _bake(arm, recorded, placement="object"):
    rec, _truth, user = recorded
    take, target = RecordingTake(rec, user), bake_session.prepare_target(arm)
    computed = bake_session.compute(take, target, bake_session.Settings("egocentric", placement=placement))
    bake_session.bake(take, target, computed, set_scene_rate=True)
    return target, computed.animation


def _posed_heads(arm, frames, bones=("pelvis", "hand_l", "foot_r", "head")) -> np.ndarray:
    """World positions of pose-bone heads of the baked armature, as Blender evaluates them."""
    out = []
    for f in frames:
        bpy.context.scene.frame_set(int(bpy.context.scene.frame_start + f))
        out.append([np.array(arm.matrix_world @ arm.pose.bones[b].head) for b in bones])
    return np.array(out)


def _figures(arm, target, anim, truth, floor_z: float) -> dict[str, float]:
    """Median contact gap per contact (mm, the evaluated mesh) and the planted soles' height above
    the avatar's floor (median and worst, mm)."""
    gaps = mesh_metrics.contact_gaps(arm, target.avatar, anim, truth.contacts, max_frames=6)
    out = {f"gap {c['effector']}>{c['target']}": float(np.median(g)) * 1000
           for c, g in zip(truth.contacts, gaps) if len(g)}
    low = []
    for s in ("l", "r"):
        # what the feet stand on: the skin's contact points (DESIGN.md §6 "Planted feet")
        soles = mesh_metrics.contact_points(target.avatar, anim, s)["support"]
        low.append(metrics.floor_error(soles - [0.0, 0.0, floor_z], truth.planted[f"foot_{s}"]))
    low = np.concatenate(low) * 1000
    out["floor median"] = float(np.nanmedian(low))
    out["sole depth"] = sole_depth(target.avatar, "l")  # m
    out["floor worst"] = float(np.nanmax(np.abs(low)))
    return out


@pytest.mark.slow
def test_a_scaled_moved_turned_armature_is_the_same_body_at_that_size(session):
    """The object scaled 1.1, moved and turned plays like the same body built 1.1 times larger:
    the same world result moved with the object (<= 1 mm), the same contact gaps and floor error
    (<= 2 mm); and like the unscaled original within 2 mm. A lifted object (z = 0.1) stands on
    its own floor."""
    _rec, truth, _user = session
    frames = np.linspace(0, truth.time.size - 1, 7).astype(int)
    results = {}
    for name, matrix, body in (("original", None, 1.0), ("object x1.1", MOVED @ Matrix.Scale(1.1, 4), 1.0),
                               ("body x1.1", None, 1.1),
                               ("lifted", Matrix.Translation((0.0, 0.0, 0.1)) @ MOVED, 1.0)):
        bpy.ops.wm.read_homefile(use_empty=True)
        arm = _avatar(matrix, body)
        inputs, anim = _bake(arm, session)
        floor = 0.1 if name == "lifted" else 0.0
        results[name] = (_figures(arm, inputs, anim, truth, floor), _posed_heads(arm, frames))
    rigid = np.array(MOVED)
    scaled, built = results["object x1.1"][1], results["body x1.1"][1]
    np.testing.assert_allclose(scaled, built @ rigid[:3, :3].T + rigid[:3, 3], atol=1e-3)
    lifted, original = results["lifted"][1], results["original"][1]
    np.testing.assert_allclose(lifted, original @ rigid[:3, :3].T + rigid[:3, 3] + [0.0, 0.0, 0.1], atol=1e-3)
    base = results["original"][0]
    # a planted contact point stands a quarter of the floor guard's blend above the floor (feet.above:
    # FLOOR_BLEND of the heel's depth under the ankle)
    stand = 1000 * feet.FLOOR_BLEND * base["sole depth"] / 4
    assert abs(base["floor median"] - stand) < 1.0 and base["floor worst"] < 4.0 + stand, base
    for name in ("object x1.1", "body x1.1", "lifted"):
        figures = results[name][0]
        for key, value in base.items():
            assert abs(figures[key] - value) <= 2.0, (name, key, figures[key], value)
    for key, value in results["body x1.1"][0].items():
        assert abs(results["object x1.1"][0][key] - value) <= 2.0, (key, value)


def test_an_avatar_placed_away_plays_there_and_the_performer_placement_keeps_the_room(session):
    """An avatar placed at (2, -3) used to end at the origin. Now it plays on its spot, facing its
    way; with the performer placement it plays where the performer was (here: the origin)."""
    rec, truth, user = session
    arm = _avatar(Matrix.Translation((2.0, -3.0, 0.0)))
    _bake(arm, session)
    start = _posed_heads(arm, [0])[0, 0]
    k = ap.root_scale(user, ap.AvatarRig.from_model(avatar_storage.load_model(arm)
                                                    if avatar_storage.has_model(arm) else calibrate_avatar(arm)))
    pelvis0 = truth.joint_tracks["pelvis"][0]
    # the play area turned half round onto the avatar's heading (-Y), its origin on the object's
    np.testing.assert_allclose(start[:2], [2.0 - k * pelvis0[0], -3.0 - k * pelvis0[1]], atol=0.02)
    _bake(arm, session, placement="performer")
    start = _posed_heads(arm, [0])[0, 0]
    np.testing.assert_allclose(start[:2], pelvis0[:2], atol=0.02)


def test_two_avatars_in_one_file_keep_their_own_spots(session):
    """Baked together (the sidebar operator, both selected), each plays on its own spot: each is
    its object's transform times the result of an untransformed avatar."""
    rec, truth, user = session
    frames = [0, truth.time.size // 2, truth.time.size - 1]
    alone = _avatar()
    _bake(alone, session)
    reference = _posed_heads(alone, frames)
    bpy.data.objects.remove(alone)
    spots = {"near": Matrix.Translation((-1.0, 2.0, 0.0)) @ Matrix.Rotation(2.0, 4, "Z"),
             "far": Matrix.Translation((3.0, -4.0, 0.0)) @ Matrix.Rotation(-0.5, 4, "Z")}
    arms = {}
    for name, matrix in spots.items():
        arms[name] = _avatar(matrix)
    recording_scene.import_recording_to_scene(rec, bpy.context.scene)
    calibration_scene.store_user_model(bpy.context.scene, user)
    bpy.context.scene.bodycal_bake.armature = None
    for arm in arms.values():
        arm.select_set(True)
    bpy.context.view_layer.objects.active = arms["near"]
    assert bpy.ops.bodycal.retarget_bake() == {"FINISHED"}
    for name, arm in arms.items():
        m = np.array(spots[name])
        np.testing.assert_allclose(_posed_heads(arm, frames), reference @ m[:3, :3].T + m[:3, 3], atol=1e-3,
                                   err_msg=name)
    apart = _posed_heads(arms["near"], [0])[0, 0] - _posed_heads(arms["far"], [0])[0, 0]
    assert np.linalg.norm(apart[:2]) > 6.0


def test_a_stored_model_follows_its_object(session):
    """Calibrated where it stood, then scaled, moved and turned: the stored model is brought to
    where the object stands, so the bake is that of a fresh calibration there (<= 1 mm)."""
    frames = [0, session[1].time.size // 2]
    arm = _avatar()
    avatar_storage.store_model(arm, calibrate_avatar(arm))
    arm.matrix_world = MOVED @ Matrix.Scale(1.2, 4)
    bpy.context.view_layer.update()
    _bake(arm, session)
    stored = _posed_heads(arm, frames)
    fresh = _avatar(MOVED @ Matrix.Scale(1.2, 4))  # calibrated where it stands
    _bake(fresh, session)
    np.testing.assert_allclose(stored, _posed_heads(fresh, frames), atol=1e-3)
    arm.scale = (1.2, 1.2, 1.5)  # unevenly, since its model was calibrated
    bpy.context.view_layer.update()
    with pytest.raises(Exception, match="scaled unevenly"):
        _bake(arm, session)


def test_a_doubtful_object_transform_is_one_warning_line_in_the_ui(session, capfd):
    """A non-uniform scale and an implausible height are warnings (the calibration and the bake
    still run), one line each in the operators' reports (printed as "Warning:" in background)."""
    rec, _truth, user = session
    arm = _avatar(Matrix.Diagonal((1.0, 1.0, 1.25, 1.0)))
    bpy.context.view_layer.objects.active = arm
    capfd.readouterr()
    assert bpy.ops.bodycal.calibrate_avatar() == {"FINISHED"}
    assert avatar_storage.has_model(arm)
    recording_scene.import_recording_to_scene(rec, bpy.context.scene)
    calibration_scene.store_user_model(bpy.context.scene, user)
    bpy.context.scene.bodycal_bake.armature = arm
    assert bpy.ops.bodycal.retarget_bake() == {"FINISHED"}
    out = capfd.readouterr().out
    warnings = [ln for ln in out.splitlines() if ln.startswith("Warning:")]
    assert len(warnings) == 2 and all("not uniform" in w for w in warnings), out[-2000:]
    assert arm.animation_data.action is not None
    tiny = _avatar(Matrix.Scale(0.1, 4))
    from bodycal_addon.retarget.placement import avatar_warnings

    (line,) = avatar_warnings(calibrate_avatar(tiny))
    assert "tall" in line and math.isclose(float(line.split(" is ")[1].split()[0]), 0.17, abs_tol=0.02)


@pytest.mark.slow
def test_the_command_line_warns_in_one_line_and_takes_the_placement(session, tmp_path):
    """calibrate-avatar and retarget on a .blend whose armature is scaled unevenly: exit 0, one
    `warning:` line each on stderr; --placement performer plays it where the performer was."""
    import subprocess
    import sys

    from repo_paths import REPO

    rec, truth, user = session
    rec_path, _ = synthetic.write_session(tmp_path, "take", rec, truth)
    user_path = user.save(tmp_path / "performer.body.json")
    _avatar(Matrix.Translation((2.0, -3.0, 0.0)) @ Matrix.Diagonal((1.0, 1.0, 1.25, 1.0)))
    blend = tmp_path / "stretched.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)

    def bodycal(*args):
        return subprocess.run([sys.executable, "-m", "bodycal_addon", *map(str, args)], cwd=REPO,
                              capture_output=True, text=True, timeout=600)

    for command, args in (("calibrate-avatar", (blend, "-o", tmp_path / "a.body.json")),
                          ("retarget", (rec_path, "--user", user_path, "--avatar", blend, "--placement", "performer",
                                        "-o", tmp_path / "out.blend"))):
        run = bodycal(command, *args)
        assert run.returncode == 0, run.stderr
        (line,) = run.stderr.splitlines()
        assert line.startswith(f"bodycal {command}: warning: procedural: ") and "not uniform" in line, line
    bpy.ops.wm.open_mainfile(filepath=str(tmp_path / "out.blend"))
    arm = bpy.data.objects["procedural"]
    start = _posed_heads(arm, [0])[0, 0]
    np.testing.assert_allclose(start[:2], truth.joint_tracks["pelvis"][0][:2], atol=0.03)
