"""`bodycal batch --export-openjd DIR` and `--export-flamenco FILE.json` (docs/FARM.md): the batch's own
command lines for a farm. The Open Job Description template is run here with `openjd run`; the
Flamenco job type's compileJob is run with node against a stand-in of Flamenco's API
(tests/helpers/flamenco_standin.js), Flamenco itself not being installable here."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from repo_paths import REPO
from test_batch import _write_inputs
from test_cluster import _actions

from bodycal_addon.app.batch import command_line, load_jobs
from bodycal_addon.body.bone_presets import builtin_presets

NODE = shutil.which("node")
OPENJD = Path(sys.executable).with_name("openjd")
JOB_TYPE = REPO / "farm" / "flamenco" / "bodycal_batch.js"
STANDIN = REPO / "tests" / "helpers" / "flamenco_standin.js"


def _bodycal(*args, cwd=REPO):
    return subprocess.run([sys.executable, "-m", "bodycal_addon", *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=300, env=None)


def _compile_on_flamenco_standin(submission: Path) -> dict:
    out = subprocess.run([NODE, str(STANDIN), str(JOB_TYPE), str(submission)], capture_output=True, text=True,
                         timeout=60)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout)


JOBS_FILES = {
    "plain": ('[[recordings]]\npath = "takes/take1.bcrec.json"\nuser = "takes/anna.body.json"\n'
              '[[avatars]]\nfile = "avatars/ogre.blend"\n'),
    # same stem in two folders (the folder rule), the same recording for two performers (the hash
    # rule), an armature, a bone map, every bake option and several formats
    "clashes and options": ('[defaults]\nmethod = ["egocentric", "offsets", "rotations"]\noutput_dir = "../farm out"\n'
                            'filter = "2,6"\nplant_feet = false\nplacement = "performer"\nroot_motion = "in-place"\n'
                            'rigify_target = "def"\ntolerance = 0.25\nfps = 30\noverwrite = true\n'
                            'export = ["fbx", "blend"]\n'
                            '[[recordings]]\npath = "monday/take.bcrec.json"\nuser = "anna.body.json"\n'
                            '[[recordings]]\npath = "tuesday/take.csv"\nuser = "anna.body.json"\n'
                            '[[recordings]]\npath = "monday/take.bcrec.json"\nuser = "ben.body.json"\n'
                            '[[avatars]]\nfile = "Ogre Rig.fbx"\narmature = "x/../Ogre Ärmature"\n'
                            'bone_map = "unreal.bonemap.json"\n[[avatars]]\nfile = "child.glb"\n'),
    "unsmoothed": ('[defaults]\nfilter = false\n[[recordings]]\npath = "t.bcrec.json"\nuser = "u.body.json"\n'
                   '[[avatars]]\nfile = "a.blend"\n'),
    "animations": ('[defaults]\nmethod = ["rotations", "offsets", "egocentric"]\nfilter = true\n'
                   '[[recordings]]\npath = "walk.bcrec.json"\nuser = "u.body.json"\n'
                   '[[animations]]\npath = "clips/walk.bvh"\n'
                   '[[animations]]\npath = "clips/walk.blend"\nsource_armature = "Walker"\naction = "Walk \\"fast\\""\n'
                   '[[avatars]]\nfile = "a.vrm"\n'),
}


@pytest.mark.skipif(NODE is None, reason="the Flamenco job type's compile step is tested with node (not on PATH)")
@pytest.mark.parametrize("name", sorted(JOBS_FILES))
def test_the_flamenco_job_type_compiles_the_batch_command_lines(tmp_path, name):
    builtin_presets()[0].save(tmp_path / "unreal.bonemap.json")
    (tmp_path / "jobs.toml").write_text(JOBS_FILES[name])
    out = _bodycal("batch", tmp_path / "jobs.toml", "--export-flamenco", tmp_path / "job.json")
    assert out.returncode == 0, out.stderr
    submission = json.loads((tmp_path / "job.json").read_text())
    assert submission["type"] == "bodycal-batch"
    compiled = _compile_on_flamenco_standin(tmp_path / "job.json")
    assert {s["key"] for s in compiled["job_type"]["settings"]} == set(submission["settings"])

    jobs, _settings = load_jobs(tmp_path / "jobs.toml")
    assert [t["name"] for t in compiled["tasks"]] == [j.name for j in jobs]
    for task, job in zip(compiled["tasks"], jobs):
        (command,) = task["commands"]
        p = command["parameters"]
        assert command["type"] == "blender-render" and p["exe"] == "{blender}"  # the Worker's own Blender
        argv = ["blender", *p["exeArgs"].split(), *p["argsBefore"], *p["args"]]
        assert argv == command_line(job, "blender")


@pytest.mark.skipif(NODE is None, reason="the Flamenco job type's compile step is tested with node (not on PATH)")
def test_the_flamenco_job_type_reads_its_settings_not_the_exporters_names(tmp_path):
    """The names come from the job type's own rule: a submission whose avatars list is reordered by
    hand still names every task as `load_jobs` names the reordered file."""
    (tmp_path / "jobs.toml").write_text(JOBS_FILES["plain"] + '[[avatars]]\nfile = "avatars/child.blend"\n')
    assert _bodycal("batch", tmp_path / "jobs.toml", "--export-flamenco", tmp_path / "job.json").returncode == 0
    submission = json.loads((tmp_path / "job.json").read_text())
    submission["settings"]["avatars"] = json.dumps(json.loads(submission["settings"]["avatars"])[::-1])
    (tmp_path / "job.json").write_text(json.dumps(submission))
    names = [t["name"] for t in _compile_on_flamenco_standin(tmp_path / "job.json")["tasks"]]
    assert names == ["take1__child__egocentric", "take1__ogre__egocentric"]


def test_the_openjd_export_holds_the_batch_command_lines(tmp_path):
    (tmp_path / "jobs.toml").write_text(JOBS_FILES["clashes and options"].replace("[defaults]\n",
                                                                                  "[defaults]\ntimeout = 90.5\n"))
    builtin_presets()[0].save(tmp_path / "unreal.bonemap.json")
    out = _bodycal("batch", tmp_path / "jobs.toml", "--export-openjd", tmp_path / "farm")
    assert out.returncode == 0, out.stderr
    table = json.loads((tmp_path / "farm" / "bodycal_batch.commands.json").read_text())
    template = json.loads((tmp_path / "farm" / "bodycal_batch.template.json").read_text())
    jobs, _settings = load_jobs(tmp_path / "jobs.toml")
    assert table["commands"] == [[None, *command_line(job, "python")[1:]] for job in jobs]
    (step,) = template["steps"]
    assert step["parameterSpace"]["taskParameterDefinitions"] == [{"name": "Job", "type": "INT",
                                                                   "range": f"0-{len(jobs) - 1}"}]
    assert step["script"]["actions"]["onRun"]["timeout"] == 91
    if OPENJD.exists():
        check = subprocess.run([str(OPENJD), "check", str(tmp_path / "farm" / "bodycal_batch.template.json")],
                               capture_output=True, text=True, timeout=60)
        assert check.returncode == 0, check.stdout + check.stderr


@pytest.mark.parametrize("option, target, words", [
    ("--export-flamenco", "folder", "not a regular file"),
    ("--export-openjd", "file", "cannot create the folder"),
])
def test_an_export_that_cannot_be_written_is_one_line(tmp_path, option, target, words):
    (tmp_path / "jobs.toml").write_text(JOBS_FILES["plain"])
    (tmp_path / "folder").mkdir()
    (tmp_path / "file").write_text("a file where the folder would go")
    out = _bodycal("batch", tmp_path / "jobs.toml", option, tmp_path / target / "x" if target == "file" else
                   tmp_path / target)
    assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1 and words in out.stderr
    assert (tmp_path / "file").read_text() == "a file where the folder would go"


def _openjd_run(template: Path, cwd: Path):
    return subprocess.run([str(OPENJD), "run", str(template), "--step", "BodyCalJobs"], cwd=cwd, capture_output=True,
                          text=True, timeout=900)


@pytest.mark.skipif(not OPENJD.exists(), reason="needs openjd-cli (requirements-dev.txt)")
def test_a_failed_openjd_task_fails_the_run_with_the_jobs_one_line(tmp_path):
    (tmp_path / "jobs.toml").write_text('[[recordings]]\npath = "take.bcrec.json"\nuser = "u.body.json"\n'
                                        '[[avatars]]\nfile = "missing.blend"\n')
    assert _bodycal("batch", tmp_path / "jobs.toml", "--export-openjd", tmp_path / "farm").returncode == 0
    out = _openjd_run(tmp_path / "farm" / "bodycal_batch.template.json", tmp_path)
    assert out.returncode != 0
    assert "bodycal retarget: error:" in out.stdout and "take.bcrec.json" in out.stdout
    assert not (tmp_path / "out").exists() or not list((tmp_path / "out").rglob("*.blend"))


@pytest.mark.slow
@pytest.mark.skipif(not OPENJD.exists(), reason="needs openjd-cli (requirements-dev.txt)")
def test_openjd_run_bakes_what_the_local_batch_bakes(tmp_path):
    _write_inputs(tmp_path)
    text = ('[defaults]\nmethod = ["egocentric", "rotations"]\nworkers = 2\noutput_dir = "{out}"\n'
            '[[recordings]]\npath = "takes/clap.bcrec.json"\nuser = "takes/performer.body.json"\n'
            '[[avatars]]\nfile = "procedural.blend"\n')
    (tmp_path / "local.toml").write_text(text.format(out="local"))
    (tmp_path / "farm.toml").write_text(text.format(out="farm-out"))
    assert _bodycal("batch", tmp_path / "local.toml").returncode == 0
    assert _bodycal("batch", tmp_path / "farm.toml", "--export-openjd", tmp_path / "openjd").returncode == 0
    out = _openjd_run(tmp_path / "openjd" / "bodycal_batch.template.json", tmp_path)
    assert out.returncode == 0, out.stdout[-3000:]
    names = sorted(p.name for p in (tmp_path / "local").glob("*.blend"))
    assert names == ["clap__procedural__egocentric.blend", "clap__procedural__rotations.blend"]
    assert sorted(p.name for p in (tmp_path / "farm-out").glob("*.blend")) == names
    for name in names:
        local = _actions(tmp_path / "local" / name)
        assert local and _actions(tmp_path / "farm-out" / name) == local  # every key equal
