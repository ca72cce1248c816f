"""A bake's review in Blender and on the command line (docs/FORMATS.md §4.5, DESIGN.md §7 "Review"):
`retarget --review` writes the sheet (the Workbench render of the frames that matter, matplotlib's
plots) and its record; `bodycal review` reviews an existing output; `batch --review` writes the
batch's review.html, which a real headless Chromium opens from the disk with every sheet loaded;
the sidebar keeps the flags and jumps the timeline to their frames."""

from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
import struct
import subprocess
import sys
from pathlib import Path

import bpy
import numpy as np
import pytest
from repo_paths import REPO
from rig_edits import constrain_forearm_to_an_unkeyed_control

from bodycal_addon.blender import calibration_scene, recording_scene, review, review_plots, session
from bodycal_addon.blender.bake import BakeOptions
from bodycal_addon.body.bodymodel import BodyModel
from bodycal_addon.core import paths
from bodycal_addon.output import metrics
from bodycal_addon.output import review as engine
from bodycal_addon.output.review_page import PAGE_NAME, rows
from bodycal_addon.recording.io import load_recording
from bodycal_addon.retarget.takes import RecordingTake
from bodycal_dev import synthetic

rigs = paths.sample_rigs()
CHROMIUM = next((shutil.which(n) for n in ("chromium", "chromium-browser", "google-chrome") if shutil.which(n)), None)


def _bodycal(*args, timeout=600):
    return subprocess.run([sys.executable, "-m", "bodycal_addon", *map(str, args)], cwd=REPO, capture_output=True,
                          text=True, timeout=timeout)


def _png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()[:24]
    assert data[:8] == b"\x89PNG\r\n\x1a\n", f"{path} is not a PNG"
    return struct.unpack(">II", data[16:24])


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """A take of the contact motions (clap, hand on belly, on the head) and a walk, its performer's
    body model, the procedural avatar and the same avatar whose bake fails its check."""
    d = tmp_path_factory.mktemp("review")
    perf = synthetic.make_performer(seed=5)
    rec, truth = synthetic.record_session(perf, motions=("clap", "hand_on_belly", "walk_in_place"),
                                          calibration=["tpose"], seed=5)
    rec.name = "touches"
    synthetic.write_session(d / "takes", "touches", rec, truth)
    truth.body_model().save(d / "takes" / "performer.body.json")
    bpy.ops.wm.read_homefile(use_empty=True)
    arm, _mesh, _spec = rigs.build_procedural_avatar()
    bpy.ops.wm.save_as_mainfile(filepath=str(d / "procedural.blend"))
    constrain_forearm_to_an_unkeyed_control(arm)
    bpy.ops.wm.save_as_mainfile(filepath=str(d / "controlled.blend"))
    bpy.ops.wm.read_homefile(use_empty=True)
    return d


@pytest.fixture(scope="module")
def reviewed(inputs):
    """`retarget --review` onto the procedural avatar, as a person would type it."""
    takes = inputs / "takes"
    out = _bodycal("retarget", takes / "touches.bcrec.json", "--user", takes / "performer.body.json",
                   "--avatar", inputs / "procedural.blend", "-o", inputs / "out" / "touches.blend", "--review")
    return inputs / "out", out


def test_retarget_review_writes_the_sheet_and_its_record(reviewed):
    folder, out = reviewed
    assert out.returncode == 0 and out.stderr == "", out.stderr
    sheet, record = folder / "touches.review.png", folder / "touches.review.json"
    assert f"saved {sheet}" in out.stdout and f"saved {record}" in out.stdout
    width, height = _png_size(sheet)
    assert width == len(engine.SHEET_FRAMES) * review.CELL_PX[0]
    assert height == review.CELL_PX[1] + review.PLOTS_PX  # the plots under the frames (matplotlib is here)
    data = json.loads(record.read_text())
    assert (data["format"], data["status"], data["verified"], data["sheet"]) == \
        ("bodycal-review", "ok", True, sheet.name)
    names = {f["name"] for f in data["flags"]}
    assert {"contact gap", "foot skin", "foot slide", "wrist acceleration", "ankle acceleration"} <= names
    for flag in data["flags"]:
        assert flag["over"] == (f"review: OVER {flag['text']}" in out.stdout)
        assert flag["frame"] is None or data["frame_range"][0] <= flag["frame"] <= data["frame_range"][1]
    assert [f["title"] for f in data["sheet_frames"]] == list(engine.SHEET_FRAMES)
    # egocentric on its own performer's take: the contacts hold (bench_retarget_quality's limit)
    gap = next(f for f in data["flags"] if f["name"] == "contact gap")
    assert gap["value"] <= metrics.CONTACT_GAP_P95_MM and not gap["over"]
    assert data["seconds"]["sheet"] > 0 and data["seconds"]["review"] > 0


def _cells(path: Path, cells: int) -> list[float]:
    """The share of each frame cell's pixels that are not the background (the avatar, the source)."""
    image = bpy.data.images.load(str(path))
    try:
        w, h = image.size
        px = np.empty(w * h * image.channels, np.float32)
        image.pixels.foreach_get(px)
        px = px.reshape(h, w, image.channels)[..., :3]
    finally:
        bpy.data.images.remove(image)
    top = px[-review.CELL_PX[1]:]  # Blender's images start at the bottom row
    width = w // cells
    return [float((np.abs(top[:, k * width:(k + 1) * width] - 0.96).max(axis=-1) > 0.1).mean()) for k in range(cells)]


def test_without_matplotlib_the_sheet_is_its_frames_and_says_so(inputs, tmp_path, monkeypatch):
    """Blender's own Python has no matplotlib: the sheet is the rendered frames alone, each showing
    the avatar and the source, and the record says why the plots are missing."""
    monkeypatch.setattr(review_plots, "available", lambda: False)
    lines = []
    session.retarget_files(inputs / "takes" / "touches.bcrec.json", inputs / "takes" / "performer.body.json",
                           inputs / "procedural.blend", [tmp_path / "plain.blend"], review=True, log=lines.append)
    sheet = tmp_path / "plain.review.png"
    assert _png_size(sheet) == (len(engine.SHEET_FRAMES) * review.CELL_PX[0], review.CELL_PX[1])
    assert any("matplotlib" in ln for ln in lines)
    assert any("matplotlib" in n for n in json.loads((tmp_path / "plain.review.json").read_text())["notes"])
    shares = _cells(sheet, len(engine.SHEET_FRAMES))
    assert all(0.03 < s < 0.6 for s in shares), shares  # each cell drew a body, none is empty or all floor
    assert "BodyCal Review" not in bpy.data.scenes and not [o for o in bpy.data.objects if o.name.startswith("review.")]


def test_played_animation_reads_back_the_engines_pose(inputs):
    """`bodycal review` reads an output's motion back from Blender's evaluated pose (the rig's FK
    inverted): a bake keyed at every frame reads back as the engine's joints, root motion included."""
    take = RecordingTake(load_recording(inputs / "takes" / "touches.bcrec.json"),
                         BodyModel.load(inputs / "takes" / "performer.body.json"))
    bpy.ops.wm.open_mainfile(filepath=str(inputs / "procedural.blend"))
    arm = next(o for o in bpy.data.objects if o.type == "ARMATURE")
    target = session.prepare_target(arm)
    computed = session.compute(take, target, session.Settings())
    engine_joints = {j: np.array(v) for j, v in computed.animation.joints_world.items()}
    session.bake(take, target, computed, options=BakeOptions(tolerance_deg=0.0, location_tolerance_mm=0.0))
    back = review.played_animation(arm, target.avatar)
    assert back.frame_count == computed.animation.frame_count
    for j in ("pelvis", "wrist_l", "wrist_r", "ankle_l", "ankle_r", "skull_base"):
        assert np.abs(back.joints_world[j] - engine_joints[j]).max() < 1e-3, j


def test_review_reviews_an_existing_output_without_changing_it(reviewed, inputs):
    folder, _ = reviewed
    output = folder / "touches.blend"
    before = hashlib.sha256(output.read_bytes()).hexdigest()
    out = _bodycal("review", output, "--source", inputs / "takes" / "touches.bcrec.json", "--user",
                   inputs / "takes" / "performer.body.json", "-o", folder / "again" / "touches.png")
    assert out.returncode == 0 and out.stderr == "", out.stderr
    assert hashlib.sha256(output.read_bytes()).hexdigest() == before
    again = json.loads((folder / "again" / "touches.review.json").read_text())
    baked = json.loads((folder / "touches.review.json").read_text())
    assert _png_size(folder / "again" / "touches.png")[0] == len(engine.SHEET_FRAMES) * review.CELL_PX[0]
    # the same contacts and gaps as the bake's own review: the keys play what the engine computed
    gap = {f["name"]: f["value"] for f in again["flags"]}
    assert gap["contact gap"] == pytest.approx(next(f["value"] for f in baked["flags"] if f["name"] == "contact gap"),
                                               abs=2.0)
    assert _bodycal("review", output, "-o", folder / "again" / "touches.png").returncode == 2  # no --overwrite
    alone = _bodycal("review", output, "--overwrite", "-o", folder / "again" / "touches.png")
    assert alone.returncode == 0, alone.stderr
    names = {f["name"] for f in json.loads((folder / "again" / "touches.review.json").read_text())["flags"]}
    assert "contact gap" not in names and "foot skin" in names  # no source: nothing touches


def _jobs_file(inputs: Path) -> Path:
    """Both methods onto the good avatar and onto the one whose bake fails its check."""
    path = inputs / "jobs.toml"
    path.write_text('[defaults]\nmethod = ["egocentric", "rotations"]\noutput_dir = "batch"\nworkers = 2\n'
                    '[[recordings]]\npath = "takes/touches.bcrec.json"\nuser = "takes/performer.body.json"\n'
                    '[[avatars]]\nblend = "procedural.blend"\n[[avatars]]\nblend = "controlled.blend"\n')
    return path


@pytest.fixture(scope="module")
def batch(inputs):
    """The batch with --review."""
    out = _bodycal("batch", _jobs_file(inputs), "--review", timeout=1200)
    return inputs / "batch", out


@pytest.mark.slow
def test_batch_review_lists_every_job_worst_first(batch):
    folder, out = batch
    assert out.returncode == 2  # the controlled avatar's jobs failed
    assert f"saved {folder / PAGE_NAME}" in out.stdout
    listed = rows(folder)
    assert [r["job"] for r in listed[:2]] == sorted(["touches__controlled__egocentric",
                                                     "touches__controlled__rotations"])
    for r in listed[:2]:  # the failed verifications first, flagged
        assert r["status"] == "failed" and r["verified"] is False
        assert r["review"].flags[0].name == "verification" and r["review"].flags[0].over
    ok = listed[2:]
    assert [r["job"] for r in ok] == ["touches__procedural__rotations", "touches__procedural__egocentric"]
    contact = [next(f for f in r["review"].flags if f.name == "contact gap") for r in ok]
    assert contact[0].over and not contact[1].over  # the rotation copy loses its contacts, egocentric keeps them
    page = (folder / PAGE_NAME).read_text()
    assert page.index("touches__controlled") < page.index("touches__procedural__rotations") < \
        page.index("touches__procedural__egocentric")


def _dom(page: Path) -> str:
    if CHROMIUM is None:
        pytest.fail("this test opens the review page in a real headless browser: install Debian's chromium "
                    "(apt-get install chromium; .ci/run installs it when absent)")
    out = subprocess.run([CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--allow-file-access-from-files",
                          "--virtual-time-budget=5000", "--dump-dom", page.as_uri()], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout


@pytest.mark.slow
def test_the_review_page_opens_in_chromium_with_every_sheet(batch, tmp_path):
    import re

    folder, _ = batch
    dom = _dom(folder / PAGE_NAME)
    loaded = re.findall(r'<img class="sheet"[^>]*data-loaded="([^"]*)"', dom)
    assert len(loaded) == 2 and all(v.isdigit() and int(v) == 1500 for v in loaded), loaded
    assert dom.count('class="over"') >= 2 and "verification failed" in dom
    # the page moved with its folder still finds its sheets (relative links); a sheet gone is said
    moved = tmp_path / "moved"
    shutil.copytree(folder, moved)
    (moved / "touches__procedural__rotations.review.png").unlink()
    dom = _dom(moved / PAGE_NAME)
    loaded = re.findall(r'data-loaded="([^"]*)"', dom)
    assert sorted(loaded) == ["1500", "missing"] and "sheet missing" in dom


def test_the_sidebar_shows_the_review_and_jumps_to_its_frames(inputs):
    rec = load_recording(inputs / "takes" / "touches.bcrec.json")
    scene = bpy.context.scene
    arm, _mesh, _spec = rigs.build_procedural_avatar()
    recording_scene.import_recording_to_scene(rec, scene, frame_start=101)
    calibration_scene.store_user_model(scene, BodyModel.load(inputs / "takes" / "performer.body.json"))
    scene.bodycal_bake.armature = arm
    scene.bodycal_bake.frame_range = "take"
    scene.bodycal_retarget.method = "rotations"
    assert bpy.ops.bodycal.retarget_bake() == {"FINISHED"}
    flags = scene.bodycal_retarget.review_flags
    assert {f.armature for f in flags} == {arm.name}
    assert any(f.over and f.text.startswith("contact gap") for f in flags)  # a rotation copy: red
    assert [f.over for f in flags] == sorted((f.over for f in flags), reverse=True)  # the red ones first
    first, last = 101, 101 + rec.frame_count - 1
    for f in flags:
        if math.isfinite(f.frame):
            assert first <= f.frame <= last
            assert bpy.ops.bodycal.jump_to_flag(frame=f.frame) == {"FINISHED"}
            assert scene.frame_current == math.floor(f.frame)
    from ui_layout import draw

    panel = bpy.types.BODYCAL_PT_retarget
    log = draw(panel, bpy.context)
    jumps = [e for e in log if e[0] == "operator" and e[1] == "bodycal.jump_to_flag"]
    assert len(jumps) == sum(math.isfinite(f.frame) for f in flags)


@pytest.mark.skipif(shutil.which("node") is None, reason="the Flamenco job type's compile step is tested with node")
def test_exported_farm_jobs_review_and_then_write_the_page(inputs, tmp_path):
    from bodycal_addon.app.batch import command_line, load_jobs

    jobs_file = _jobs_file(inputs)
    assert _bodycal("batch", jobs_file, "--review", "--export-openjd", tmp_path / "openjd").returncode == 0
    table = json.loads((tmp_path / "openjd" / "bodycal_batch.commands.json").read_text())
    template = json.loads((tmp_path / "openjd" / "bodycal_batch.template.json").read_text())
    jobs, settings = load_jobs(jobs_file)
    assert all(c[-1] == "--review" for c in table["commands"][:-1]) and len(table["commands"]) == len(jobs) + 1
    assert table["commands"][-1] == [None, "-m", "bodycal_addon", "review", str(settings["output_dir"])]
    jobs_step, page_step = template["steps"]
    assert page_step["dependencies"] == [{"dependsOn": jobs_step["name"]}]
    assert page_step["script"]["actions"]["onRun"]["args"][-1] == str(len(jobs))  # the table's last command
    openjd = Path(sys.executable).with_name("openjd")
    if openjd.exists():
        check = subprocess.run([str(openjd), "check", str(tmp_path / "openjd" / "bodycal_batch.template.json")],
                               capture_output=True, text=True, timeout=120)
        assert check.returncode == 0, check.stdout + check.stderr

    assert _bodycal("batch", jobs_file, "--review", "--export-flamenco", tmp_path / "job.json").returncode == 0
    compiled = subprocess.run(["node", str(REPO / "tests" / "helpers" / "flamenco_standin.js"),
                               str(REPO / "farm" / "flamenco" / "bodycal_batch.js"), str(tmp_path / "job.json")],
                              capture_output=True, text=True, timeout=60)
    assert compiled.returncode == 0, compiled.stderr
    tasks = json.loads(compiled.stdout)["tasks"]
    *job_tasks, page = tasks
    for task, job in zip(job_tasks, jobs):
        p = task["commands"][0]["parameters"]
        assert ["blender", *p["exeArgs"].split(), *p["argsBefore"]] == command_line(
            type(job)(**{**job.__dict__, "review": True}), "blender")
    assert page["name"] == "review-page" and page["dependencies"] == [t["name"] for t in job_tasks]
    assert page["commands"][0]["parameters"]["argsBefore"] == ["-c", "bodycal", "review", str(settings["output_dir"])]


def test_review_refuses_what_it_cannot_review(tmp_path):
    (tmp_path / "notes.txt").write_text("x")
    for args, words in (((tmp_path / "missing.blend",), "no such file"),
                        ((tmp_path / "notes.txt",), "not a baked avatar file"),
                        ((tmp_path, "--source", tmp_path / "t.bcrec.json"), "is a folder")):
        out = _bodycal("review", *args)
        assert out.returncode == 2 and words in out.stderr and len(out.stderr.strip().splitlines()) == 1, out.stderr
    os.makedirs(tmp_path / "empty")
    out = _bodycal("review", tmp_path / "empty")
    assert out.returncode == 0 and "0 jobs" in (tmp_path / "empty" / PAGE_NAME).read_text()
