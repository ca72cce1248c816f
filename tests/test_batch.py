"""`bodycal batch`: recordings x avatars in worker processes; a failed job does not stop the others."""

import json
import subprocess
import sys

import bpy
import pytest
from conftest import REPO

from bodycal_addon import paths
from bodycal_addon.batch import command_line, load_jobs
from bodycal_addon.errors import BodyCalError
from bodycal_dev import synthetic

rigs = paths.sample_rigs()


def _write_inputs(tmp_path):
    perf = synthetic.make_performer(seed=5)
    rec, truth = synthetic.record_session(perf, motions=("clap",), calibration=["tpose"], seed=5)
    rec.name = "clap"
    synthetic.write_session(tmp_path / "takes", "clap", rec, truth)
    truth.body_model().save(tmp_path / "takes" / "performer.body.json")
    rigs.build_procedural_avatar()
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "procedural.blend"))


@pytest.mark.slow
def test_batch_finishes_good_jobs_and_reports_the_failed_one(tmp_path):
    _write_inputs(tmp_path)
    (tmp_path / "jobs.toml").write_text('''
[defaults]
method = ["egocentric", "rotations"]
output_dir = "results"
workers = 2

[[recordings]]
path = "takes/clap.bcrec.json"
user = "takes/performer.body.json"

[[avatars]]
blend = "procedural.blend"

[[avatars]]
blend = "missing_avatar.blend"
''')
    out = subprocess.run([sys.executable, "-m", "bodycal_addon", "batch", str(tmp_path / "jobs.toml")], cwd=REPO,
                         capture_output=True, text=True, timeout=900)
    progress = [ln for ln in out.stdout.splitlines() if ln.startswith("[")]
    assert len(progress) == 4  # one line per job
    summary = json.loads((tmp_path / "results" / "summary.json").read_text())
    assert (summary["jobs"], summary["ok"], summary["failed"]) == (4, 2, 2)
    failed = [r for r in summary["results"] if not r["ok"]]
    assert all("missing_avatar.blend" in r["error"] and "no such file" in r["error"] for r in failed)
    for r in summary["results"]:
        if r["ok"]:
            assert (tmp_path / "results" / f"{r['job']}.blend").is_file()
    assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1


def test_jobs_file_errors_name_the_field(tmp_path):
    bad = tmp_path / "jobs.toml"
    bad.write_text('[defaults]\nmethod = "sideways"\n[[recordings]]\npath="a"\nuser="b"\n[[avatars]]\nblend="c"\n')
    with pytest.raises(BodyCalError, match="defaults.method"):
        load_jobs(bad)
    bad.write_text("[[recordings]]\npath = 'a.json'\n")
    with pytest.raises(BodyCalError, match="at least one"):
        load_jobs(bad)
    bad.write_text("not = [toml")
    with pytest.raises(BodyCalError, match="not valid TOML"):
        load_jobs(bad)


def test_each_job_is_a_self_contained_command(tmp_path):
    (tmp_path / "jobs.toml").write_text('[[recordings]]\npath="t.bcrec.json"\nuser="u.body.json"\n'
                                        '[[avatars]]\nblend="a.blend"\narmature="Rig"\n')
    (job,), _settings = load_jobs(tmp_path / "jobs.toml")
    cmd = command_line(job, "blender")
    assert cmd[:4] == ["blender", "-b", "-c", "bodycal"]
    assert cmd[4:] == ["retarget", str(tmp_path / "t.bcrec.json"), "--user", str(tmp_path / "u.body.json"),
                       "--avatar", str(tmp_path / "a.blend"), "--method", "egocentric", "-o",
                       str(tmp_path / "out" / "batch" / "t__Rig__egocentric.blend"), "--armature", "Rig"]


def test_filter_and_feet_settings_reach_every_job(tmp_path):
    (tmp_path / "jobs.toml").write_text('[defaults]\nfilter = "2,6"\nplant_feet = false\n'
                                        '[[recordings]]\npath="t.bcrec.json"\nuser="u.body.json"\n'
                                        '[[avatars]]\nblend="a.blend"\n')
    (job,), _settings = load_jobs(tmp_path / "jobs.toml")
    assert job.argv()[-3:] == ["--filter", "2,6", "--no-plant-feet"]
    (tmp_path / "jobs.toml").write_text('[defaults]\nfilter = true\n[[recordings]]\npath="t"\nuser="u"\n'
                                        '[[avatars]]\nblend="a"\n')
    (job,), _settings = load_jobs(tmp_path / "jobs.toml")
    assert job.argv()[-2:] == ["--filter", "on"]
    (tmp_path / "jobs.toml").write_text('[defaults]\nfilter = "soft"\n[[recordings]]\npath="t"\nuser="u"\n'
                                        '[[avatars]]\nblend="a"\n')
    with pytest.raises(BodyCalError, match="--filter"):
        load_jobs(tmp_path / "jobs.toml")
