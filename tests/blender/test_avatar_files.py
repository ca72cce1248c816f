"""Avatars from the files users bring (FORMATS.md §4.3), .blend, .fbx, .glb / .gltf and .vrm, read
by Blender's own importers into an empty scene (blendfile.open_avatar), on the command line, in
batch jobs and in the sidebar; what an importer brings besides the avatar is ignored, and a file it
cannot read is one line."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import addon_utils
import bpy
import numpy as np
import pytest
from repo_paths import REPO

from bodycal_addon.blender import avatar_storage, blendfile
from bodycal_addon.body.bodymodel import BodyModel
from bodycal_addon.core import paths
from bodycal_dev import synthetic

rigs = paths.sample_rigs()


def bodycal(*args, cwd=REPO) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "bodycal_addon", *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=600)


def export_mixamo_like_fbx(glb: Path, out: Path) -> Path:
    """The glTF avatar as a Mixamo file is: Y-up data in centimetres under untransformed nodes, so
    Blender's FBX importer gives the armature a 90-degree turn about X and a 0.01 scale. Built by
    putting the avatar in that state (data turned to Y-up and scaled to cm, the object turned and
    scaled back: the same world body) and exporting it with Blender's FBX exporter."""
    bpy.ops.wm.read_homefile(use_empty=True)
    arm, mesh = rigs.load_glb_avatar(glb)
    bpy.ops.object.select_all(action="DESELECT")
    for obj in (arm, mesh):
        obj.select_set(True)
    bpy.context.view_layer.objects.active = arm
    arm.rotation_mode = "XYZ"
    arm.rotation_euler, arm.scale = (-math.pi / 2, 0.0, 0.0), (100.0, 100.0, 100.0)
    bpy.context.view_layer.update()
    bpy.ops.object.transform_apply(location=False, rotation=True, scale=True)
    arm.rotation_euler, arm.scale = (math.pi / 2, 0.0, 0.0), (0.01, 0.01, 0.01)
    bpy.context.view_layer.update()
    bpy.ops.export_scene.fbx(filepath=str(out), object_types={"ARMATURE", "MESH"}, add_leaf_bones=False)
    bpy.ops.wm.read_homefile(use_empty=True)
    return out


@pytest.fixture(scope="module")
def glb(avatar_files) -> Path:
    return next(p for p in avatar_files if p.stem == "adult_male")


@pytest.fixture(scope="module")
def files(glb, tmp_path_factory) -> dict[str, Path]:
    """The one avatar as a .glb, as a .blend (the sample loader: stray icosphere removed) and as a
    Mixamo-like .fbx; a short session (a hand on the belly, then walking in place) and its user."""
    folder = tmp_path_factory.mktemp("avatar_files")
    bpy.ops.wm.read_homefile(use_empty=True)
    rigs.load_glb_avatar(glb)
    blend = folder / "adult_male.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    fbx = export_mixamo_like_fbx(glb, folder / "adult_male_mixamo.fbx")
    perf = synthetic.make_performer(seed=6)
    rec, truth = synthetic.record_session(perf, motions=("hand_on_belly", "walk_in_place"), calibration=False,
                                          seed=6)
    rec.name = "take"
    rec_path, _ = synthetic.write_session(folder, "take", rec, truth)
    user = truth.body_model().save(folder / "performer.body.json")
    bpy.ops.wm.read_homefile(use_empty=True)
    return {"glb": glb, "blend": blend, "fbx": fbx, "recording": rec_path, "user": user, "folder": folder}


def _same_body(a: BodyModel, b: BodyModel, atol: float) -> None:
    """Two avatar models of the same world body: joints, bone radii and surface points."""
    assert set(a.joints) == set(b.joints) and [e.id for e in a.surface] == [e.id for e in b.surface]
    for j in a.joints:
        np.testing.assert_allclose(a.joints[j].world, b.joints[j].world, atol=atol, err_msg=j)
    for n, bone in a.bones.items():
        for end in ("radius_head", "radius_tail"):
            if getattr(bone, end) is not None:
                assert abs(getattr(bone, end) - getattr(b.bones[n], end)) <= atol, (n, end)
    for e in a.surface:
        other = b.element(e.id)
        for p, point in e.points.items():
            np.testing.assert_allclose(point.local, other.points[p].local, atol=atol, err_msg=f"{e.id}/{p}")


def test_the_fbx_is_mixamo_like(files):
    """What the test's FBX gives on import: the armature turned 90 degrees about X, scaled 0.01,
    its bones in centimetres, Y up; the same world body as the glTF."""
    blendfile.open_avatar(files["fbx"])
    arm = blendfile.find_armature(None, "fbx")
    np.testing.assert_allclose(arm.matrix_world.to_euler(), (math.pi / 2, 0.0, 0.0), atol=1e-5)
    np.testing.assert_allclose(arm.matrix_world.to_scale(), (0.01, 0.01, 0.01), atol=1e-7)
    pelvis = arm.data.bones["pelvis"].head_local
    assert pelvis.y > 80.0 and abs(pelvis.z) < 5.0  # 92 cm up along +Y
    np.testing.assert_allclose(arm.matrix_world @ pelvis, (0.0, -0.003, 0.924), atol=1e-3)


@pytest.mark.slow
def test_calibrate_avatar_reads_glb_and_fbx_as_the_blend(files):
    """calibrate-avatar on the .glb (its glTF icosphere bone shape still in the scene, neither an
    avatar nor raycast) and on the Mixamo-like .fbx measures the body the .blend gives."""
    models = {}
    for kind in ("blend", "glb", "fbx"):
        out = files["folder"] / f"cal_{kind}.body.json"
        run = bodycal("calibrate-avatar", files[kind], "-o", out, "--overwrite")
        assert run.returncode == 0 and run.stderr == "", run.stderr[-2000:]
        models[kind] = BodyModel.load(out)
    _same_body(models["glb"], models["blend"], atol=1e-6)
    _same_body(models["fbx"], models["blend"], atol=5e-5)  # the FBX keeps single-precision centimetres
    assert models["glb"].extra["rig"]["armature"] == "adult_male_rig"  # as the file names it
    np.testing.assert_allclose(np.array(models["fbx"].extra["rig"]["matrix_world"])[:3, :3],
                               0.01 * np.array([[1, 0, 0], [0, 0, -1], [0, 1, 0]]), atol=1e-8)


def _posed(out_blend: Path, frames, bones=("pelvis", "hand_r", "foot_l", "head")) -> np.ndarray:
    """World heads of pose bones of the armature in a retarget output, at frames (from the start)."""
    bpy.ops.wm.open_mainfile(filepath=str(out_blend))
    (arm,) = [o for o in bpy.data.objects if o.type == "ARMATURE"]
    assert arm.animation_data.action is not None and avatar_storage.has_model(arm)
    scene = bpy.context.scene
    heads = []
    for f in frames:
        scene.frame_set(scene.frame_start + int(f))
        heads.append([np.array(arm.matrix_world @ arm.pose.bones[b].head) for b in bones])
    return np.array(heads)


@pytest.mark.slow
def test_retarget_onto_glb_and_fbx_bakes_the_imported_avatar(files):
    """retarget --avatar X.glb / X.fbx: the output .blend holds the imported avatar with the baked
    action, posed in the world exactly as the .blend's (<= 1 mm), the FBX's armature in its own
    centimetres under its turned, scaled object."""
    frames = [0, 300, 700, 1000]
    posed = {}
    for kind in ("blend", "glb", "fbx"):
        out = files["folder"] / f"out_{kind}.blend"
        run = bodycal("retarget", files["recording"], "--user", files["user"], "--avatar", files[kind], "-o", out,
                      "--overwrite")
        assert run.returncode == 0 and run.stderr == "", run.stderr[-2000:]
        assert "Baked 'take|" in run.stdout
        posed[kind] = _posed(out, frames)
        # the file's own objects in the output (the FBX was written from the sample loader's names)
        imported = {"glb": {"adult_male_rig", "adult_male", "Icosphere"}, "fbx": {"adult_male", "adult_male_mesh"}}
        assert imported.get(kind, set()) <= {o.name for o in bpy.data.objects}, kind
    np.testing.assert_allclose(posed["glb"], posed["blend"], atol=1e-3)
    np.testing.assert_allclose(posed["fbx"], posed["blend"], atol=1e-3)


@pytest.mark.parametrize("suffix, content", [
    (".fbx", b"Kaydara FBX Binary  \x00\x1a\x00" + bytes(range(256)) * 8),
    (".fbx", b"not an fbx at all"),
    (".glb", b"glTF\x02\x00\x00\x00" + b"\x00" * 64),
    (".gltf", b'{"asset": {"version": "2.0"}, "nodes": [{"mesh": 5}], "scenes": [{"nodes": [0]}]}'),
])
def test_a_file_the_importer_cannot_read_is_one_line(tmp_path, files, suffix, content):
    """A corrupt avatar: exit 2, one line on stderr naming the file, no traceback (the importers'
    own tracebacks and messages go to stdout, with Blender's log)."""
    bad = tmp_path / f"broken{suffix}"
    bad.write_bytes(content)
    retarget = ("retarget", files["recording"], "--user", files["user"], "--avatar", bad, "-o", tmp_path / "o.blend")
    for args in (("calibrate-avatar", bad, "-o", tmp_path / "a.body.json"), retarget):
        run = bodycal(*args)
        assert run.returncode == 2, run.stderr
        lines = run.stderr.splitlines()
        assert len(lines) == 1 and str(bad) in lines[0] and "importer cannot read it" in lines[0], run.stderr
        assert not (tmp_path / "o.blend").exists()


def test_a_vrm_needs_a_vrm_importer(tmp_path, files):
    """No VRM add-on enabled: one line saying to install or enable one (Blender has none of its own)."""
    vrm = tmp_path / "avatar.vrm"
    shutil.copy(files["glb"], vrm)
    run = bodycal("calibrate-avatar", vrm, "-o", tmp_path / "a.body.json")
    assert run.returncode == 2
    (line,) = run.stderr.splitlines()
    assert str(vrm) in line and "VRM importer add-on" in line and "install and enable" in line


class IMPORT_SCENE_OT_vrm(bpy.types.Operator):
    """A stand-in VRM importer: VRM 0.x files are glTF binaries, so this one hands the file to the
    glTF importer (the real add-on does much more; here only the dispatch is under test)."""

    bl_idname = "import_scene.vrm"
    bl_label = "Import VRM (test stand-in)"
    filepath: bpy.props.StringProperty()

    def execute(self, context):
        return bpy.ops.import_scene.gltf(filepath=self.filepath)


def test_a_vrm_is_read_by_the_vrm_importer_when_one_is_enabled(tmp_path, files):
    vrm = tmp_path / "avatar.vrm"
    shutil.copy(files["glb"], vrm)
    bpy.utils.register_class(IMPORT_SCENE_OT_vrm)
    try:
        blendfile.open_avatar(vrm)
        arm = blendfile.find_armature(None, str(vrm))
    finally:
        bpy.utils.unregister_class(IMPORT_SCENE_OT_vrm)
    assert arm.name == "adult_male_rig" and blendfile.deformed_meshes(arm)


def test_a_disabled_importer_is_enabled_for_the_import_and_left_as_found(files):
    """Blender's FBX and glTF importers are add-ons a user may have turned off. (FBX here: Blender
    4.2's glTF add-on cannot be enabled again once disabled in a session, BLENDER_NOTES.md.)"""
    addon_utils.disable("io_scene_fbx", default_set=False)
    try:
        assert "fbx" not in dir(bpy.ops.import_scene)
        blendfile.open_avatar(files["fbx"])
        assert blendfile.find_armature(None, "fbx").name == "adult_male"
        assert "fbx" not in dir(bpy.ops.import_scene)  # off again, as the user had it
    finally:
        addon_utils.enable("io_scene_fbx", default_set=False)
    assert "fbx" in dir(bpy.ops.import_scene)


def test_helper_objects_are_not_avatars(files):
    """What importers bring besides the avatar (the glTF icosphere bone shape, a bone-shape or prop
    armature no mesh is skinned to, empties, cameras, lights) is no candidate armature."""
    blendfile.open_avatar(files["glb"])
    helper = bpy.data.objects.new("bone_shapes", bpy.data.armatures.new("bone_shapes"))
    bpy.context.scene.collection.objects.link(helper)
    for name, data in (("cam", bpy.data.cameras.new("cam")), ("sun", bpy.data.lights.new("sun", "SUN")),
                       ("empty", None)):
        bpy.context.scene.collection.objects.link(bpy.data.objects.new(name, data))
    assert "Icosphere" in bpy.data.objects
    assert blendfile.find_armature(None, "glb").name == "adult_male_rig"
    from bodycal_addon.blender.avatar_calibration import avatar_meshes

    assert [o.name for o in avatar_meshes(bpy.data.objects["adult_male_rig"])] == ["adult_male"]
    second, _mesh, _spec = rigs.build_procedural_avatar()  # a second skinned armature: the user picks
    with pytest.raises(Exception, match="several armatures"):
        blendfile.find_armature(None, "glb")
    assert blendfile.find_armature(second.name, "glb") == second


def test_every_avatar_suffix_has_a_reader():
    assert set(paths.AVATAR_SUFFIXES) == {".blend", *blendfile.IMPORTERS}


def test_an_unknown_avatar_file_is_one_line(tmp_path):
    obj = tmp_path / "avatar.obj"
    obj.write_text("v 0 0 0\n")
    run = bodycal("calibrate-avatar", obj, "-o", tmp_path / "a.body.json")
    assert run.returncode == 2
    (line,) = run.stderr.splitlines()
    assert ".fbx" in line and ".vrm" in line


@pytest.mark.slow
def test_a_batch_job_takes_a_glb_avatar(files, tmp_path):
    """A jobs file's [[avatars]] may name any avatar file (`file`; `blend` still reads), and
    [defaults] placement is passed to every job."""
    jobs = tmp_path / "jobs.toml"
    jobs.write_text(f'[defaults]\nmethod = "rotations"\nplacement = "performer"\nworkers = 1\n'
                    f'output_dir = "out"\n\n[[recordings]]\npath = "{files["recording"]}"\nuser = "{files["user"]}"\n\n'
                    f'[[avatars]]\nfile = "{files["glb"]}"\n')
    from bodycal_addon.app.batch import load_jobs

    (job,), _settings = load_jobs(jobs)
    assert job.avatar == files["glb"] and "--placement" in job.argv() and "performer" in job.argv()
    run = bodycal("batch", jobs)
    assert run.returncode == 0, run.stderr
    summary = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert summary["ok"] == 1 and summary["results"][0]["job"] == "take__adult_male__rotations"
    bpy.ops.wm.open_mainfile(filepath=summary["results"][0]["output"])
    assert bpy.data.objects["adult_male_rig"].animation_data.action.name == "take|adult_male_rig|rotations"


def test_the_sidebar_imports_an_fbx_avatar_ready_to_calibrate(files, tmp_path):
    """Avatar > Import Avatar: Blender's importer, the armature made active; Calibrate Avatar then
    measures the body the .blend gives. A file the importer cannot read is one ERROR line and
    leaves the scene as it was."""
    assert bpy.ops.bodycal.import_avatar(filepath=str(files["fbx"])) == {"FINISHED"}
    arm = bpy.context.view_layer.objects.active
    assert arm.type == "ARMATURE" and arm.name == "adult_male" and arm.select_get()
    assert bpy.ops.bodycal.calibrate_avatar() == {"FINISHED"}
    blendfile.open_avatar(files["blend"])
    from bodycal_addon.blender.avatar_calibration import calibrate_avatar

    reference = calibrate_avatar(blendfile.find_armature(None, "blend"))
    bpy.ops.wm.read_homefile(use_empty=True)
    assert bpy.ops.bodycal.import_avatar(filepath=str(files["fbx"])) == {"FINISHED"}
    assert bpy.ops.bodycal.calibrate_avatar() == {"FINISHED"}
    _same_body(avatar_storage.load_model(bpy.context.view_layer.objects.active), reference, atol=5e-5)
    bad = tmp_path / "broken.glb"
    bad.write_bytes(b"glTF\x02\x00\x00\x00" + b"\x00" * 64)
    before = set(bpy.data.objects)
    with pytest.raises(RuntimeError) as err:  # an ERROR report makes bpy.ops raise
        bpy.ops.bodycal.import_avatar(filepath=str(bad))
    assert "importer cannot read it" in str(err.value) and "\n" not in str(err.value).strip()
    assert set(bpy.data.objects) == before
