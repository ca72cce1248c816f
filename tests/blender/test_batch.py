"""`bodycal batch`: recordings x avatars in worker processes; a failed job does not stop the others."""

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
import unicodedata
from pathlib import Path

import bpy
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from processes import alive as _alive
from repo_paths import REPO

from bodycal_addon.app import batch
from bodycal_addon.app.batch import command_line, load_jobs, output_names
from bodycal_addon.core import paths
from bodycal_addon.core.errors import BodyCalError
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
    assert job.argv()[-3:] == ["--filter", "2,6", "--no-plant-feet"] and "--overwrite" not in job.argv()
    (tmp_path / "jobs.toml").write_text('[defaults]\noverwrite = true\n[[recordings]]\npath="t"\nuser="u"\n'
                                        '[[avatars]]\nblend="a.blend"\n')
    (job,), _settings = load_jobs(tmp_path / "jobs.toml")
    assert job.argv()[-1] == "--overwrite"
    (tmp_path / "jobs.toml").write_text('[defaults]\nfilter = true\n[[recordings]]\npath="t"\nuser="u"\n'
                                        '[[avatars]]\nblend="a.blend"\n')
    (job,), _settings = load_jobs(tmp_path / "jobs.toml")
    assert "--filter" not in job.argv() and "--no-filter" not in job.argv()  # the command's default
    (tmp_path / "jobs.toml").write_text('[defaults]\nfilter = false\n[[recordings]]\npath="t"\nuser="u"\n'
                                        '[[avatars]]\nblend="a.blend"\n')
    (job,), _settings = load_jobs(tmp_path / "jobs.toml")
    assert job.argv()[-1] == "--no-filter"
    (tmp_path / "jobs.toml").write_text('[defaults]\nfilter = "soft"\n[[recordings]]\npath="t"\nuser="u"\n'
                                        '[[avatars]]\nblend="a.blend"\n')
    with pytest.raises(BodyCalError, match="--filter"):
        load_jobs(tmp_path / "jobs.toml")


def test_output_settings_and_exports_reach_every_job(tmp_path):
    (tmp_path / "jobs.toml").write_text('[defaults]\ntolerance = 0.25\nfps = 30\nexport = ["fbx", "blend", "bvh"]\n'
                                        '[[recordings]]\npath="t.bcrec.json"\nuser="u.body.json"\n'
                                        '[[avatars]]\nblend="a.blend"\n')
    (job,), _settings = load_jobs(tmp_path / "jobs.toml")
    argv = job.argv()
    outs = [argv[i + 1] for i, a in enumerate(argv) if a == "-o"]
    base = tmp_path / "out" / "batch" / "t__a__egocentric"
    assert outs == [f"{base}.fbx", f"{base}.blend", f"{base}.bvh"]
    assert argv[argv.index("--tolerance") + 1] == "0.25" and argv[argv.index("--fps") + 1] == "30.0"
    assert "--interpolation" not in argv
    (tmp_path / "jobs.toml").write_text('[defaults]\ninterpolation = "bezier"\n[[recordings]]\npath="t"\nuser="u"\n'
                                        '[[animations]]\npath="walk.bvh"\n[[avatars]]\nblend="a.blend"\n')
    jobs, _settings = load_jobs(tmp_path / "jobs.toml")
    assert [job.argv()[job.argv().index("--interpolation") + 1] for job in jobs] == ["bezier", "bezier"]


@pytest.mark.slow
def test_a_batch_writes_every_export_it_is_asked_for(tmp_path):
    _write_inputs(tmp_path)
    (tmp_path / "jobs.toml").write_text('''
[defaults]
method = "rotations"
output_dir = "results"
workers = 1
fps = 30
export = ["blend", "glb"]

[[recordings]]
path = "takes/clap.bcrec.json"
user = "takes/performer.body.json"

[[avatars]]
blend = "procedural.blend"
''')
    out = subprocess.run([sys.executable, "-m", "bodycal_addon", "batch", str(tmp_path / "jobs.toml")], cwd=REPO,
                         capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-2000:]
    (result,) = json.loads((tmp_path / "results" / "summary.json").read_text())["results"]
    assert result["ok"] and [Path(p).name for p in result["outputs"]] == ["clap__procedural__rotations.blend",
                                                                          "clap__procedural__rotations.glb"]
    assert all(Path(p).stat().st_size > 0 for p in result["outputs"])


def _jobs_file(tmp_path, defaults="", recordings=(("t.bcrec.json", "u.body.json"),), avatars=(("a.blend", None),)):
    text = f"[defaults]\n{defaults}\n"
    for path, user in recordings:
        text += f"[[recordings]]\npath = {json.dumps(path)}\nuser = {json.dumps(user)}\n"
    for blend, armature in avatars:
        text += f"[[avatars]]\nblend = {json.dumps(blend)}\n"
        text += f"armature = {json.dumps(armature)}\n" if armature is not None else ""
    (tmp_path / "jobs.toml").write_text(text)
    return tmp_path / "jobs.toml"


def test_same_stem_recordings_in_two_folders_get_distinct_outputs(tmp_path):
    jobs, settings_ = load_jobs(_jobs_file(tmp_path, recordings=(("monday/take.bcrec.json", "u.body.json"),
                                                                  ("tuesday/take.csv", "u.body.json"),
                                                                  ("other.bcrec.json", "u.body.json"))))
    assert [j.output.name for j in jobs] == ["monday-take__a__egocentric.blend", "tuesday-take__a__egocentric.blend",
                                             "other__a__egocentric.blend"]  # a name without a clash is unchanged
    assert all(j.output.parent == settings_["output_dir"] for j in jobs)


def test_a_clash_the_folder_cannot_settle_gets_a_stable_hash(tmp_path):
    # the same recording for two performers: same folder, same stem
    recs = (("takes/take.bcrec.json", "anna.body.json"), ("takes/take.bcrec.json", "ben.body.json"))
    jobs, _ = load_jobs(_jobs_file(tmp_path, recordings=recs))
    names = [j.name for j in jobs]
    assert len(set(names)) == 2 and all(n.startswith("takes-take__a__egocentric__") for n in names)
    identity = [str(tmp_path / "takes" / "take.bcrec.json"), str(tmp_path / "anna.body.json"),
                str(tmp_path / "a.blend"), None, "egocentric"]  # the documented rule, computed independently
    assert names[0].endswith("__" + hashlib.sha256(json.dumps(identity).encode()).hexdigest()[:8])
    again, _ = load_jobs(tmp_path / "jobs.toml")
    assert [j.name for j in again] == names  # deterministic
    # letter case is ignored when looking for clashes (macOS and Windows file systems)
    jobs, _ = load_jobs(_jobs_file(tmp_path, recordings=(("x/Take.csv", "u"), ("y/take.csv", "u"))))
    assert [j.name for j in jobs] == ["x-Take__a__egocentric", "y-take__a__egocentric"]


def test_a_malicious_armature_name_stays_inside_output_dir(tmp_path):
    jobs, settings_ = load_jobs(_jobs_file(tmp_path, avatars=(("a.blend", "x/../../../ESCAPED"),
                                                              ("b.blend", "..\\..\\win"), ("c.blend", "../.."))))
    out = settings_["output_dir"].resolve()
    for job in jobs:
        assert job.output.resolve().parent == out
        assert "/" not in job.name and "\\" not in job.name and ".." not in job.name
    assert jobs[0].armature == "x/../../../ESCAPED"  # the armature itself is still looked up by its real name
    assert len({j.name for j in jobs}) == 3


def test_repeated_entries_are_an_error_not_a_lost_result(tmp_path):
    with pytest.raises(BodyCalError, match=r"recordings\[1\]: same path and user as recordings\[0\]"):
        load_jobs(_jobs_file(tmp_path, recordings=(("t.csv", "u"), ("./t.csv", "u"))))
    with pytest.raises(BodyCalError, match=r"avatars\[1\]: same file and armature as avatars\[0\]"):
        load_jobs(_jobs_file(tmp_path, avatars=(("a.blend", "R"), ("a.blend", "R"))))


_names = st.text(st.characters(blacklist_categories=("Cs",)), min_size=0, max_size=30)


@settings(max_examples=200, deadline=None)
@given(entries=st.lists(st.tuples(_names, _names, st.one_of(st.none(), _names), st.sampled_from(("a", "b"))),
                        min_size=1, max_size=6))
def test_any_names_give_unique_safe_outputs_inside_output_dir(entries):
    out_dir = Path("/batch/out")
    specs, seen = [], set()
    for folder, stem, armature, avatar in entries:
        rp = Path("/takes") / (folder.replace("/", "_") or "f") / ((stem.replace("/", "_") or "s") + ".csv")
        key = (str(rp), avatar, armature)
        if key not in seen:  # load_jobs rejects repeated entries before naming
            seen.add(key)
            specs.append((rp, Path("/u.body.json"), Path(f"/{avatar}.blend"), armature, "egocentric"))
    names = output_names(specs)
    assert len({n.casefold() for n in names}) == len(names)
    assert output_names(specs) == names
    for n in names:
        assert n and "/" not in n and "\\" not in n and ".." not in n and not n.startswith((".", "-"))
        assert not any(unicodedata.category(c).startswith("C") for c in n)
        assert len((n + ".blend").encode()) < 255
        assert os.path.normpath(out_dir / f"{n}.blend").startswith(str(out_dir) + os.sep)


BAD_DEFAULTS = [
    ('workers = "abc"', "defaults.workers", "whole number"),
    ("workers = 0", "defaults.workers", "whole number"),
    ("workers = true", "defaults.workers", "whole number"),
    ("method = 5", "defaults.method", "egocentric"),
    ("method = []", "defaults.method", "non-empty"),
    ('method = ["rotations", "rotations"]', "defaults.method", "twice"),
    ("output_dir = 5", "defaults.output_dir", "folder"),
    ('output_dir = ""', "defaults.output_dir", "folder"),
    ('output_dir = "a\\u0000b"', "defaults.output_dir", "control character"),
    ("runner = 5", "defaults.runner", '"python" or "blender"'),
    ("filter = 3", "defaults.filter", "true, false"),
    ('plant_feet = "no"', "defaults.plant_feet", "true or false"),
    ("overwrite = 1", "defaults.overwrite", "true or false"),
    ('placement = "stage"', "defaults.placement", '"object" or "performer"'),
    ('interpolation = "cubic"', "defaults.interpolation", '"linear" or "bezier"'),
    ("plant_foot = false", "defaults", "unknown key"),
    ("tolerance = -0.1", "defaults.tolerance", "number from 0"),
    ('tolerance = "0.1"', "defaults.tolerance", "number from 0"),
    ("fps = 0", "defaults.fps", "number from 1"),
    ("fps = true", "defaults.fps", "number from 1"),
    ('export = ["obj"]', "defaults.export", "unknown format"),
    ('export = ["fbx", "fbx"]', "defaults.export", "twice"),
    ("export = []", "defaults.export", "non-empty"),
    ("timeout = 0", "defaults.timeout", "number from 1"),
    ('timeout = "1h"', "defaults.timeout", "seconds a job may run"),
]


def _cli(jobs, env=None):
    return subprocess.run([sys.executable, "-m", "bodycal_addon", "batch", str(jobs)], cwd=REPO, capture_output=True,
                          text=True, timeout=120, env=env)


def _assert_one_line(out, jobs, field, words):
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in out.stderr
    assert str(jobs) in lines[0] and f"{field}:" in lines[0] and words in lines[0]


@pytest.mark.parametrize("defaults, field, words", BAD_DEFAULTS)
def test_each_bad_defaults_field_is_one_line(tmp_path, defaults, field, words):
    jobs = _jobs_file(tmp_path, defaults)
    _assert_one_line(_cli(jobs), jobs, field, words)
    assert not (tmp_path / "out").exists()  # nothing started


@pytest.mark.parametrize("avatars, recordings, field, words", [
    ((("a.blend", 5),), (("t", "u"),), "avatars[0].armature", "armature name"),
    ((("a.blend", "R\n"),), (("t", "u"),), "avatars[0].armature", "control character"),
    ((("a.blend", None),), (("t", ""),), "recordings[0].user", "non-empty"),
    ((("a.obj", None),), (("t", "u"),), "avatars[0].blend", ".fbx, .glb, .gltf, .vrm"),
    ((("a", None),), (("t", "u"),), "avatars[0].blend", "avatar file"),
])
def test_each_bad_entry_field_is_one_line(tmp_path, avatars, recordings, field, words):
    jobs = _jobs_file(tmp_path, recordings=recordings, avatars=avatars)
    _assert_one_line(_cli(jobs), jobs, field, words)


def test_structure_errors_are_one_line(tmp_path):
    jobs = tmp_path / "jobs.toml"
    for text, field, words in [('recordings = "t"\n[[avatars]]\nblend="a"\n', "recordings", "[[recordings]]"),
                               ('[[recordings]]\npath="t"\nuser="u"\nspeed=2\n[[avatars]]\nblend="a"\n',
                                "recordings[0]", "unknown key"),
                               ('[[recordings]]\npath="t"\nuser="u"\n[[avatars]]\nfile="a.glb"\nblend="a.blend"\n',
                                "avatars[0]", "both 'file' and 'blend'"),
                               ('[[recordings]]\npath="t"\nuser="u"\n[[avatars]]\narmature="R"\n',
                                "avatars[0]", "missing 'file'"),
                               ("[[defaults]]\nworkers=1\n", "defaults", "table")]:
        jobs.write_text(text)
        _assert_one_line(_cli(jobs), jobs, field, words)


def test_runner_blender_without_blender_on_the_path_is_one_line(tmp_path):
    jobs = _jobs_file(tmp_path, 'runner = "blender"')
    env = {**os.environ, "PATH": str(tmp_path / "empty_bin")}  # a folder that does not exist: no blender
    _assert_one_line(_cli(jobs, env), jobs, "defaults.runner", "PATH")


@pytest.mark.parametrize("text", ["a = " + "[" * 100_000 + "]" * 100_000,
                                  "a = " + "{b = " * 100_000 + "1" + "}" * 100_000,
                                  '{"a": ' * 100_000 + "1" + "}" * 100_000])
def test_deeply_nested_jobs_file_is_one_line(tmp_path, text):
    jobs = tmp_path / "jobs.toml"
    jobs.write_text(text)
    out = _cli(jobs)
    assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1 and "Traceback" not in out.stderr
    assert str(jobs) in out.stderr and "not valid TOML" in out.stderr


# ---- stopping and partial saves: fake workers stand in for `retarget` (command_line replaced) -----

FAKE_WORKER = r"""
import os, signal, sys, time
out = sys.argv[sys.argv.index("-o") + 1]
name = os.path.basename(out)
open(os.path.join(os.environ["FAKE_PIDS"], str(os.getpid())), "w").close()
if name.startswith("fast"):
    open(out, "wb").write(b"blend")
elif name.startswith("crash"):  # killed while Blender saves: its temporary files stay
    open(out + "@", "wb").write(b"half a blend")
    tmp = os.path.join(os.path.dirname(out), "." + name + ".0a1b2c3d.tmp.blend")
    open(tmp, "wb").write(b"half a blend")
    open(tmp + "@", "wb").write(b"half a blend")
    os.kill(os.getpid(), signal.SIGKILL)
else:  # slow, and deaf to SIGTERM: only SIGKILL ends it
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    open(out + "@", "wb").write(b"half a blend")
    time.sleep(600)
"""

DRIVER = r"""
import sys
import bodycal_addon.app.batch.runner as runner
from bodycal_addon.app.cli import main
runner.command_line = lambda job, how: [sys.executable, sys.argv[1], *job.argv()]
sys.exit(main(["batch", sys.argv[2]]))
"""


def _fake_setup(tmp_path, recordings, workers=2):
    (tmp_path / "fake_worker.py").write_text(FAKE_WORKER)
    (tmp_path / "pids").mkdir()
    return _jobs_file(tmp_path, f'output_dir = "results"\nworkers = {workers}',
                      recordings=[(f"{r}.bcrec.json", "u.body.json") for r in recordings])


def test_a_worker_killed_while_saving_leaves_nothing_and_is_one_failure(tmp_path, monkeypatch):
    jobs = _fake_setup(tmp_path, ["crash", "fast"])
    (tmp_path / "results").mkdir()
    (tmp_path / "results" / "fast__a__egocentric.blend@").write_text("left by a batch killed yesterday")
    monkeypatch.setenv("FAKE_PIDS", str(tmp_path / "pids"))
    fake = str(tmp_path / "fake_worker.py")
    monkeypatch.setattr(batch.runner, "command_line", lambda job, runner: [sys.executable, fake, *job.argv()])
    lines = []
    summary = batch.run_batch(jobs, log=lines.append)
    assert (summary["ok"], summary["failed"], summary["cancelled"], summary["interrupted"]) == (1, 1, 0, None)
    crash = next(r for r in summary["results"] if r["job"].startswith("crash"))
    assert crash["status"] == "failed" and "killed by SIGKILL" in crash["error"]
    assert "removed its partial save crash__a__egocentric.blend@" in crash["error"]
    assert ".crash__a__egocentric.blend.0a1b2c3d.tmp.blend@" in crash["error"]  # the command's own temp too
    assert summary["removed_stale"] == [str(tmp_path / "results" / "fast__a__egocentric.blend@")]
    assert any("fast__a__egocentric.blend@" in ln and "earlier batch" in ln for ln in lines)
    assert not list((tmp_path / "results").glob("*@"))
    assert not list((tmp_path / "results").glob(".*.tmp*"))
    assert (tmp_path / "results" / "fast__a__egocentric.blend").read_bytes() == b"blend"
    assert json.loads((tmp_path / "results" / "summary.json").read_text())["failed"] == 1


def test_a_batch_at_a_terminal_counts_its_jobs_on_one_progress_line(tmp_path):
    """`bodycal batch` at a terminal: one progress line counts the jobs done (and failed), each job's
    own line printed above it; piped, only the job lines and the summary."""
    from terminal import lines_left, run_in_terminal

    jobs = _fake_setup(tmp_path, ["fast1", "fast2", "crash"], workers=1)
    (tmp_path / "driver.py").write_text(DRIVER)
    env = {**os.environ, "FAKE_PIDS": str(tmp_path / "pids"), "PYTHONPATH": str(REPO)}
    argv = [sys.executable, str(tmp_path / "driver.py"), str(tmp_path / "fake_worker.py"), str(jobs)]
    code, received, err = run_in_terminal(argv, cwd=REPO, env=env, timeout=120)
    assert code == 2 and "1 of 3 jobs failed" in err
    shown = received.decode(errors="replace")
    for count in ("0/3 jobs", "1/3 jobs", "2/3 jobs", "3/3 jobs, 1 failed"):
        assert f"\rbodycal batch: {count} " in shown, shown
    lines = lines_left(received)
    assert [line.split(":")[0] for line in lines[:3]] == ["[1/3] fast1__a__egocentric", "[2/3] fast2__a__egocentric",
                                                         "[3/3] crash__a__egocentric"], lines
    assert json.loads(lines[3])["failed"] == 1 and len(lines) == 4
    for name in ("fast1", "fast2"):
        (tmp_path / "results" / f"{name}__a__egocentric.blend").unlink()
    piped = subprocess.run(argv, cwd=REPO, env=env, capture_output=True, text=True, timeout=120)
    untimed = [line.rsplit(" (", 1)[0] for line in piped.stdout.splitlines()[:3]]
    assert untimed == [line.rsplit(" (", 1)[0] for line in lines[:3]]
    assert len(piped.stdout.splitlines()) == 4 and "\r" not in piped.stdout and "%|" not in piped.stdout


def test_sigterm_stops_the_batch_ends_deaf_workers_and_writes_the_summary(tmp_path):
    jobs = _fake_setup(tmp_path, ["fast", "slow1", "slow2", "slow3"])
    (tmp_path / "driver.py").write_text(DRIVER)
    env = {**os.environ, "FAKE_PIDS": str(tmp_path / "pids"), "PYTHONPATH": str(REPO)}
    proc = subprocess.Popen([sys.executable, str(tmp_path / "driver.py"), str(tmp_path / "fake_worker.py"), str(jobs)],
                            cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        first = proc.stdout.readline()
        assert first.startswith("[1/4] fast__a__egocentric: ok")
        # the freed slot starts slow2 at once; wait until both slow workers hold their partial saves
        for _ in range(600):
            if len(list((tmp_path / "results").glob("slow*@"))) == 2:
                break
            subprocess.run(["sleep", "0.05"])
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    assert proc.returncode == 143
    assert len(err.strip().splitlines()) == 1 and "stopped by SIGTERM" in err and "Traceback" not in err
    summary = json.loads((tmp_path / "results" / "summary.json").read_text())
    status = {r["job"]: r["status"] for r in summary["results"]}
    assert status == {"fast__a__egocentric": "ok", "slow1__a__egocentric": "cancelled",
                      "slow2__a__egocentric": "cancelled", "slow3__a__egocentric": "cancelled"}
    assert summary["interrupted"] == "SIGTERM" and summary["cancelled"] == 3
    errors = {r["job"]: r["error"] for r in summary["results"]}
    assert "while running" in errors["slow1__a__egocentric"] and "removed its partial save" in errors[
        "slow1__a__egocentric"]
    assert "before it started" in errors["slow3__a__egocentric"]
    pids = [int(p.name) for p in (tmp_path / "pids").iterdir()]
    assert len(pids) == 3  # slow3 never started
    assert not any(_alive(pid) for pid in pids)  # the SIGTERM-deaf workers were killed, not left behind
    assert not list((tmp_path / "results").glob("*@"))
    assert len([ln for ln in out.splitlines() if ln.startswith("[")]) == 3  # + the first: one line per job


def _children(pid: int) -> set[int]:
    """The live child processes of pid (Linux /proc)."""
    found = set()
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[1]) == pid:
            found.add(int(stat.parent.name))
    return found


@pytest.mark.slow
@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="finds worker processes through /proc")
def test_ctrl_c_stops_real_workers_and_writes_the_summary(tmp_path):
    _write_inputs(tmp_path)
    jobs = _jobs_file(tmp_path, 'output_dir = "results"\nworkers = 1\nmethod = ["egocentric", "offsets", "rotations"]',
                      recordings=[("takes/clap.bcrec.json", "takes/performer.body.json")],
                      avatars=[("procedural.blend", None)])
    proc = subprocess.Popen([sys.executable, "-m", "bodycal_addon", "batch", str(jobs)], cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    workers = set()

    def watch():  # every worker the batch starts, noted while it runs
        while proc.poll() is None:
            workers.update(_children(proc.pid))
            time.sleep(0.02)

    watcher = threading.Thread(target=watch, daemon=True)
    watcher.start()
    try:
        line = proc.stdout.readline()  # one real job at a time: this comes when the first has finished
        assert line.startswith("[1/3] clap__procedural__") and ": ok" in line
        # the first worker was reaped before its line was printed, so a worker now is the next job's
        for _ in range(1200):
            if _children(proc.pid):
                break
            time.sleep(0.05)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=120)
    finally:
        proc.kill()
    assert proc.returncode == 130
    assert len(err.strip().splitlines()) == 1 and "stopped by SIGINT" in err and "Traceback" not in err
    summary = json.loads((tmp_path / "results" / "summary.json").read_text())
    assert (summary["jobs"], summary["ok"], summary["cancelled"], summary["interrupted"]) == (3, 1, 2, "SIGINT")
    for r in summary["results"]:
        assert r["status"] in ("ok", "cancelled")
        assert (tmp_path / "results" / f"{r['job']}.blend").is_file() == (r["status"] == "ok")
    watcher.join(timeout=10)
    assert len(workers) >= 2 and not any(_alive(pid) for pid in workers)
    assert not list((tmp_path / "results").glob("*@"))


@pytest.mark.slow
def test_same_stem_takes_in_two_folders_both_arrive(tmp_path):
    _write_inputs(tmp_path)
    for folder in ("monday", "tuesday"):
        (tmp_path / folder).mkdir()
        shutil.copy(tmp_path / "takes" / "clap.bcrec.json", tmp_path / folder / "clap.bcrec.json")
    jobs = _jobs_file(tmp_path, 'output_dir = "results"\nworkers = 2',
                      recordings=[("monday/clap.bcrec.json", "takes/performer.body.json"),
                                  ("tuesday/clap.bcrec.json", "takes/performer.body.json")],
                      avatars=[("procedural.blend", None)])
    out = _cli(jobs)
    assert out.returncode == 0, out.stderr
    summary = json.loads((tmp_path / "results" / "summary.json").read_text())
    assert sorted(r["output"] for r in summary["results"]) == [
        str(tmp_path / "results" / "monday-clap__procedural__egocentric.blend"),
        str(tmp_path / "results" / "tuesday-clap__procedural__egocentric.blend")]
    assert all(Path(r["output"]).is_file() for r in summary["results"])
