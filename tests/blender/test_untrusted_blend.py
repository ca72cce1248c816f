"""Nothing inside an avatar .blend runs (FORMATS.md §4). A user's file may carry a text block
registered as a module (run by Blender when a file is loaded with scripts allowed) and Python
drivers (run whenever the scene is evaluated); BodyCal opens every .blend with scripts disabled,
whatever the user's "Auto Run Python Scripts" preference says."""

import subprocess
import sys
import textwrap
from pathlib import Path

import bpy
import pytest
from repo_paths import REPO

from bodycal_addon.blender import blendfile
from bodycal_addon.core import paths
from bodycal_dev import synthetic

rigs = paths.sample_rigs()


def _armed_avatar(folder: Path) -> tuple[Path, list[Path]]:
    """The procedural avatar plus two scripts that each leave a marker file when they run."""
    text_marker, driver_marker = folder / "text_block_ran", folder / "driver_ran"
    bpy.ops.wm.read_homefile(use_empty=True)
    rigs.build_procedural_avatar()
    text = bpy.data.texts.new("on_load.py")
    text.write(f"import pathlib\npathlib.Path({str(text_marker)!r}).write_text('ran')\n")
    text.use_module = True
    trap = bpy.data.objects.new("trap", None)
    bpy.context.scene.collection.objects.link(trap)
    driver = trap.driver_add("location", 0).driver
    driver.type = "SCRIPTED"
    driver.expression = f"__import__('pathlib').Path({str(driver_marker)!r}).write_text('ran') and 0"
    blend = folder / "armed_avatar.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    bpy.ops.wm.read_homefile(use_empty=True)
    for marker in (text_marker, driver_marker):  # in case this session evaluated the driver while building
        marker.unlink(missing_ok=True)
    return blend, [text_marker, driver_marker]


@pytest.fixture
def armed(tmp_path):
    return _armed_avatar(tmp_path)


@pytest.fixture
def auto_run_scripts_on():
    """The preference a user might have turned on; restored so other tests are unaffected."""
    prefs = bpy.context.preferences.filepaths
    before = prefs.use_scripts_auto_execute
    prefs.use_scripts_auto_execute = True
    yield
    prefs.use_scripts_auto_execute = before


_EXIT = "\nfrom bodycal_addon.blender.process import exit_now\nexit_now(code)\n"


def _in_fresh_blender(code: str, tmp_path: Path) -> subprocess.CompletedProcess:
    """Run `code` in a new process with the auto-run preference on; it ends with exit_now
    (Blender as a module can hang at interpreter exit, BLENDER_NOTES.md)."""
    script = tmp_path / "run.py"
    script.write_text(textwrap.dedent("""
        import os, sys
        sys.path.insert(0, {repo!r})
        import bpy
        bpy.context.preferences.filepaths.use_scripts_auto_execute = True
        code = 0
    """).format(repo=str(REPO)) + textwrap.dedent(code) + _EXIT)
    return subprocess.run([sys.executable, str(script)], cwd=REPO, capture_output=True, text=True, timeout=300)


def test_the_armed_file_does_run_its_scripts_when_blender_is_allowed_to(armed, tmp_path):
    """The control: without it, markers that never appear would prove nothing."""
    blend, markers = armed
    out = _in_fresh_blender(f"""
        bpy.ops.wm.open_mainfile(filepath={str(blend)!r}, use_scripts=True)
        bpy.context.view_layer.update()
        bpy.context.scene.frame_set(2)
    """, tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    assert all(m.read_text() == "ran" for m in markers)


def test_the_projects_opener_runs_nothing_even_with_auto_run_on(armed, auto_run_scripts_on):
    blend, markers = armed
    blendfile.open_blend(blend)
    assert bpy.data.texts["on_load.py"].use_module  # the file's scripts are there, only not run
    bpy.context.view_layer.update()
    for frame in (1, 2, 3):
        bpy.context.scene.frame_set(frame)
    assert [m for m in markers if m.exists()] == []


def test_the_commands_run_nothing_from_the_avatar_file(armed, tmp_path):
    blend, markers = armed
    perf = synthetic.make_performer(seed=5)
    rec, truth = synthetic.record_session(perf, motions=("clap",), calibration=["tpose"], seed=5)
    rec_path, _truth = synthetic.write_session(tmp_path, "clap", rec, truth)
    user = truth.body_model().save(tmp_path / "performer.body.json")
    out = _in_fresh_blender(f"""
        from bodycal_addon.app.cli import main
        code = main(["calibrate-avatar", {str(blend)!r}, "-o", {str(tmp_path / "avatar.body.json")!r}])
        if code == 0:
            code = main(["retarget", {str(tmp_path / rec_path.name)!r}, "--user", {str(user)!r},
                         "--avatar", {str(blend)!r}, "-o", {str(tmp_path / "out.blend")!r}])
    """, tmp_path)
    assert out.returncode == 0, out.stderr[-2000:]
    assert (tmp_path / "avatar.body.json").is_file() and (tmp_path / "out.blend").is_file()
    assert [m for m in markers if m.exists()] == []


def test_every_blend_the_project_opens_goes_through_the_scriptless_opener():
    """A new `open_mainfile` or library load elsewhere in the shipped code would bypass it."""
    shipped = [REPO / "__init__.py"]
    for folder in ("bodycal_addon", "operators", "panels", "sample_rigs"):
        shipped += sorted((REPO / folder).rglob("*.py"))
    opens = [(str(path.relative_to(REPO)), needle) for path in shipped
             for needle in ("open_mainfile", "libraries.load", "wm.append", "wm.link", "load_post")
             if needle in path.read_text()]
    assert opens == [("bodycal_addon/blender/blendfile.py", "open_mainfile")]
    source = (REPO / "bodycal_addon/blender/blendfile.py").read_text()
    assert source.count("open_mainfile(") == 1 and "use_scripts=False" in source


def test_blenders_complaints_about_the_file_stay_off_stderr(armed, tmp_path):
    """Blender prints its refusal to run the file's driver ("restricted access disallows name
    '__import__'", "Error in PyDriver", 4 lines) to the process's stderr while the command evaluates
    the scene; stderr keeps BodyCal's lines only: none on success, one on error."""
    blend, markers = armed
    ok = subprocess.run([sys.executable, "-m", "bodycal_addon", "calibrate-avatar", str(blend), "-o",
                         str(tmp_path / "avatar.body.json")], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert ok.returncode == 0, ok.stderr[-2000:]
    assert "PyDriver" not in ok.stdout and ok.stderr == ""  # stdout: BodyCal's lines only (FORMATS.md §4)
    loud = subprocess.run([sys.executable, "-m", "bodycal_addon", "calibrate-avatar", str(blend), "-o",
                           str(tmp_path / "loud.body.json"), "--verbose"], cwd=REPO, capture_output=True, text=True,
                          timeout=300)
    assert loud.returncode == 0 and "PyDriver" in loud.stdout  # Blender did complain: on stdout with --verbose
    assert loud.stderr == ""
    bad = subprocess.run([sys.executable, "-m", "bodycal_addon", "calibrate-avatar", str(blend), "--bone-map",
                          str(tmp_path / "avatar.body.json"), "-o", str(tmp_path / "again.body.json")],
                         cwd=REPO, capture_output=True, text=True, timeout=300)
    assert bad.returncode == 2
    assert len(bad.stderr.splitlines()) == 1 and "error" in bad.stderr
    assert [m for m in markers if m.exists()] == []
