"""The extension as users get it: built with Blender's tool, installed from the zip, enabled
and disabled through Blender's extension machinery."""

import importlib
import json
import subprocess
import sys
import tomllib
import zipfile

import bpy
import pytest
from repo_paths import REPO

EXPECTED_OPERATORS = {"add_procedural_avatar", "load_sample_avatars", "import_recording", "calibrate_user",
                      "calibrate_avatar", "retarget_bake"}


def test_symlinked_extension_registers_sidebar_tab_and_operators():
    assert "bl_ext.user_default.bodycal" in bpy.context.preferences.addons
    ops = {name for name in dir(bpy.ops.bodycal) if not name.startswith("_")}
    assert EXPECTED_OPERATORS <= ops
    assert bpy.types.BODYCAL_PT_main.bl_category == "BodyCal"
    assert bpy.types.BODYCAL_PT_main.bl_region_type == "UI"


def test_operators_undo_and_explain_poll():
    for name in EXPECTED_OPERATORS:
        cls = bpy.types.Operator.bl_rna_get_subclass_py(f"BODYCAL_OT_{name}")
        assert cls.bl_idname == f"bodycal.{name}"
        assert {"REGISTER", "UNDO"} <= set(cls.bl_options)


def test_add_procedural_avatar_operator_adds_armature_and_mesh():
    assert bpy.ops.bodycal.add_procedural_avatar(scale=0.5) == {"FINISHED"}
    arm = bpy.data.objects["procedural"]
    mesh = bpy.data.objects["procedural_mesh"]
    assert arm.type == "ARMATURE" and mesh.parent == arm
    # Half scale: the head bone's tail (top of the skull bone) is at half of 1.76 m.
    assert abs(arm.data.bones["head"].tail_local.z - 0.88) < 1e-4


def test_zip_built_by_blender_tool_installs_and_uninstalls_cleanly(tmp_path):
    from bodycal_addon.blender.extension_build import build_zip

    zip_path = build_zip(tmp_path)
    names = zipfile.ZipFile(zip_path).namelist()
    assert "blender_manifest.toml" in names and "__init__.py" in names
    assert any(n.startswith("bodycal_addon/") for n in names)
    # python-osc ships with it (the manifest's wheels): the VMC live source works offline.
    assert "wheels/python_osc-1.10.2-py3-none-any.whl" in names
    assert "docs/SIDEBAR.md" in names  # the panels' help buttons open it
    # Left out of the zip by [build] paths_exclude_pattern.
    assert not any(n.startswith(("tests/", "benchmarks/", ".ci/", ".venv/")) for n in names)
    assert not any(n.endswith(".truth.json") for n in names)  # the synthetic ground truth: development only
    # The wheels the manifest names (tqdm: the command line's progress line) ship in the zip.
    manifest_wheels = tomllib.loads((REPO / "blender_manifest.toml").read_text())["wheels"]
    assert manifest_wheels and all(w.removeprefix("./") in names for w in manifest_wheels)
    # The licence the manifest names ships with it, and the manifest has no placeholder left.

    assert "LICENSE" in names
    licence = zipfile.ZipFile(zip_path).read("LICENSE").decode()
    assert "GNU GENERAL PUBLIC LICENSE" in licence and "Version 3" in licence
    manifest = tomllib.loads(zipfile.ZipFile(zip_path).read("blender_manifest.toml").decode())
    assert manifest["license"] == ["SPDX:GPL-3.0-or-later"] and manifest["copyright"]
    assert ".invalid" not in manifest.get("website", "") and "<" in manifest["maintainer"]

    out = subprocess.run([sys.executable, str(REPO / "tests" / "helpers" / "install_probe.py"), str(zip_path)],
                         capture_output=True, text=True, timeout=300)
    line = next((ln for ln in out.stdout.splitlines() if ln.startswith("REPORT ")), None)
    assert line, out.stdout[-2000:] + out.stderr[-2000:]
    report = json.loads(line[len("REPORT "):])
    assert report["before"]["classes"] == []
    assert report["install_result"] == ["FINISHED"]
    assert report["module_enabled"]
    assert EXPECTED_OPERATORS <= set(report["installed"]["operators"])
    assert report["installed"]["categories"] == ["BodyCal"]
    assert "bodycal_addon" in report["installed_files"]
    assert report["wheel"] == {"installed": True, "on_path": True, "receiver_ran": True}
    assert "tqdm" in report["wheel_packages"]
    # A live follower's worker process runs the installed engine (not the repository's) and solves.
    assert report["worker"] == {"engine_dir": True, "error": "", "poses": 3, "prepared": "ready", "ended": True}
    assert not report["module_enabled_after"]
    assert report["after_disable"]["classes"] == []
    assert report["after_disable"]["operators"] == []


def test_operator_failures_become_one_status_line_and_bugs_still_raise():
    pkg = "bl_ext.user_default.bodycal"
    reporting = importlib.import_module(f"{pkg}.operators.reporting")
    errors = importlib.import_module(f"{pkg}.bodycal_addon.core.errors")

    class Operator:
        def __init__(self):
            self.reports = []

        def report(self, kind, text):
            self.reports.append((kind, text))

    raised = []

    @reporting.reports_errors
    def execute(self, context):
        raise raised[-1]

    for exc, expected in ((errors.BodyCalError("bad\nvalue", source="a.json", field="x"), "a.json: x: bad value"),
                          (FileNotFoundError(2, "No such file or directory", "/nope/a.json"),
                           "/nope/a.json: No such file or directory")):
        op = Operator()
        raised.append(exc)
        assert execute(op, None) == {"CANCELLED"}
        assert op.reports == [({"ERROR"}, expected)]
    raised.append(ZeroDivisionError())
    with pytest.raises(ZeroDivisionError):  # a bug is not dressed up as bad input
        execute(Operator(), None)


def test_a_real_operator_on_a_missing_file_reports_one_line(tmp_path):
    # In background mode Blender raises an operator's ERROR report as a RuntimeError.
    with pytest.raises(RuntimeError, match=r"missing\.body\.json: cannot read") as info:
        bpy.ops.bodycal.load_user_model(filepath=str(tmp_path / "missing.body.json"))
    assert "\n" not in str(info.value).strip()


def test_recordings_can_be_dropped_on_the_viewport():
    handler = bpy.types.FileHandler.bl_rna_get_subclass_py("BODYCAL_FH_recording")
    assert handler.bl_import_operator == "bodycal.import_recording"
    # Blender matches a drop by its last suffix: `.bcrec.json` is claimed as `.json` (FORMATS.md §2.5).
    assert set(handler.bl_file_extensions.split(";")) == {".json", ".csv", ".c3d", ".bsor"}
    assert not handler.poll_drop(bpy.context)  # background mode: no area to drop on
