"""`bodycal batch JOBS.toml --cluster ...`: the batch's jobs as tasks on a Dask cluster (docs/FARM.md).

Most tests run the real command line with `bodycal_dev.fake_job` standing in for `retarget` (the
driver swaps `batch.runner.command_line`, which the cluster sends to its workers), so jobs take a
fraction of a second and can hang or kill their worker on purpose; one test bakes for real and compares the
actions with the local batch's. Clusters here have at most 2 workers, on 127.0.0.1 only."""

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import bpy
import pytest
from processes import still_alive as _still_alive
from repo_paths import REPO
from test_batch import _write_inputs

from bodycal_addon.app.batch import load_jobs

pytest.importorskip("distributed", reason="the cluster tests need dask and distributed (requirements-dev.txt)")

DRIVER = r"""
import sys
import bodycal_addon.app.batch.runner as runner
from bodycal_addon.app.cli import main
from bodycal_dev import fake_job

if __name__ == "__main__":  # the cluster's workers are spawned: they import this file as a module
    runner.command_line = fake_job.command
    sys.exit(main(["batch", *sys.argv[1:]]))
"""


def _jobs(tmp_path, stems, defaults="", methods=("egocentric",), make_inputs=True):
    text = f'[defaults]\noutput_dir = "results"\nmethod = {json.dumps(list(methods))}\n{defaults}\n'
    for stem in stems:
        text += f'[[recordings]]\npath = "{stem}.bcrec.json"\nuser = "u.body.json"\n'
        if make_inputs:
            (tmp_path / f"{stem}.bcrec.json").write_text("{}")
    text += '[[avatars]]\nfile = "a.blend"\n'
    for name in ("u.body.json", "a.blend"):
        (tmp_path / name).write_text("stand-in")
    (tmp_path / "jobs.toml").write_text(text)
    return tmp_path / "jobs.toml"


def _env(tmp_path):
    for folder in ("pids", "state"):
        (tmp_path / folder).mkdir(exist_ok=True)
    return {**os.environ, "PYTHONPATH": str(REPO), "FAKE_PIDS": str(tmp_path / "pids"),
            "FAKE_STATE": str(tmp_path / "state")}


def _driver(tmp_path, *args) -> list[str]:
    (tmp_path / "driver.py").write_text(DRIVER)
    return [sys.executable, str(tmp_path / "driver.py"), *map(str, args)]


def _run_fake(tmp_path, *args, timeout=180):
    return subprocess.run(_driver(tmp_path, *args), cwd=REPO, env=_env(tmp_path), capture_output=True, text=True,
                          timeout=timeout)


def _summary(tmp_path):
    return json.loads((tmp_path / "results" / "summary.json").read_text())


def _pids(tmp_path) -> list[int]:
    return [int(p.name) for p in (tmp_path / "pids").iterdir()]


@pytest.mark.parametrize("args, words", [
    (["--cluster", "local:0"], "local:N"),
    (["--cluster", "local:two"], "tcp://HOST:PORT"),
    (["--cluster", "http://127.0.0.1:8786"], "tcp://HOST:PORT"),
    (["--retries", "2"], "--cluster"),
    (["--cluster", "local:1", "--retries", "-1"], "0 to 100"),
    (["--cluster", "local:1", "--retries", "many"], "invalid int"),
    (["--cluster", "local:1", "--export-openjd", "farm"], "not allowed with"),
])
def test_bad_cluster_options_are_one_line_and_run_nothing(tmp_path, args, words):
    jobs = _jobs(tmp_path, ["fast"])
    out = subprocess.run([sys.executable, "-m", "bodycal_addon", "batch", str(jobs), *args], cwd=REPO,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 2, out.stderr
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and words in lines[0] and "Traceback" not in out.stderr
    assert not (tmp_path / "results").exists()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_an_unreachable_scheduler_is_one_line(tmp_path):
    jobs = _jobs(tmp_path, ["fast"])
    address = f"tcp://127.0.0.1:{_free_port()}"  # nothing listens there
    out = subprocess.run([sys.executable, "-m", "bodycal_addon", "batch", str(jobs), "--cluster", address], cwd=REPO,
                         capture_output=True, text=True, timeout=120)
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and address in lines[0] and "cannot reach a Dask scheduler" in lines[0]


def test_a_local_cluster_runs_every_job_once_under_the_batch_names(tmp_path):
    jobs = _jobs(tmp_path, ["fast1", "fast2", "fast3"], methods=("egocentric", "rotations"))
    out = _run_fake(tmp_path, jobs, "--cluster", "local:2")
    assert out.returncode == 0, out.stderr
    summary = _summary(tmp_path)
    expected, _settings = load_jobs(jobs)
    assert sorted(r["job"] for r in summary["results"]) == sorted(j.name for j in expected)
    assert (summary["jobs"], summary["ok"], summary["cluster"]) == (6, 6, "local:2")
    for r in summary["results"]:
        assert r["worker"].startswith("tcp://127.0.0.1:") and r["attempts"] == 1 and r["host"]
        assert [Path(p).read_bytes() for p in r["outputs"]] == [b"fake bake\n"]
    assert len({r["worker"] for r in summary["results"]}) <= 2
    assert len(_pids(tmp_path)) == 6  # each job ran once, in a process of its own
    assert len([ln for ln in out.stdout.splitlines() if ln.startswith("[")]) == 6
    assert out.stderr == ""  # no progress bar when stderr is not a terminal, and no Dask log lines
    # a second run keeps the first run's outputs, as the local batch does without overwrite
    again = _run_fake(tmp_path, jobs, "--cluster", "local:1")
    assert again.returncode == 2 and _summary(tmp_path)["failed"] == 6
    assert all("exists" in r["error"] for r in _summary(tmp_path)["results"])


def test_a_worker_killed_mid_job_is_retried_and_takes_its_job_with_it(tmp_path):
    jobs = _jobs(tmp_path, ["killworker", "fast"], methods=("egocentric", "rotations"))
    out = _run_fake(tmp_path, jobs, "--cluster", "local:2", "--retries", "1")
    assert out.returncode == 0, out.stderr
    summary = _summary(tmp_path)
    attempts = {r["job"]: r["attempts"] for r in summary["results"]}
    assert attempts == {"killworker__a__egocentric": 2, "killworker__a__rotations": 2, "fast__a__egocentric": 1,
                        "fast__a__rotations": 1}
    assert all(Path(r["output"]).is_file() for r in summary["results"])
    assert out.stdout.count("retrying killworker__a__") == 2
    first_attempts = [int(p.read_text()) for p in (tmp_path / "state").iterdir()]
    assert len(first_attempts) == 2 and not _still_alive(first_attempts)  # died with the worker


def test_without_retries_a_dead_worker_fails_its_job_in_one_line(tmp_path):
    jobs = _jobs(tmp_path, ["killworker", "fast"])
    out = _run_fake(tmp_path, jobs, "--cluster", "local:2")
    assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1
    status = {r["job"]: (r["status"], r["error"]) for r in _summary(tmp_path)["results"]}
    assert status == {"killworker__a__egocentric": ("failed", "the Dask worker running it died"),
                      "fast__a__egocentric": ("ok", None)}


@pytest.mark.parametrize("where", [[], ["--cluster", "local:1"]], ids=["local-batch", "cluster"])
def test_a_job_over_its_timeout_is_ended_and_failed(tmp_path, where):
    jobs = _jobs(tmp_path, ["slow", "fast"], defaults="timeout = 1")
    out = _run_fake(tmp_path, jobs, *where)
    assert out.returncode == 2
    results = {r["job"]: r for r in _summary(tmp_path)["results"]}
    slow = results["slow__a__egocentric"]
    assert slow["status"] == "failed" and slow["error"].startswith("timed out after 1 s")
    assert "removed its partial save slow__a__egocentric.blend@" in slow["error"]
    assert results["fast__a__egocentric"]["ok"]
    assert not _still_alive(_pids(tmp_path)) and not list((tmp_path / "results").glob("*@"))


def test_an_input_a_worker_cannot_read_fails_naming_the_worker_and_the_path(tmp_path):
    jobs = _jobs(tmp_path, ["fast"])
    text = jobs.read_text().replace('path = "fast.bcrec.json"', 'path = "elsewhere/fast.bcrec.json"')
    jobs.write_text(text)
    out = _run_fake(tmp_path, jobs, "--cluster", "local:1")
    assert out.returncode == 2
    (result,) = _summary(tmp_path)["results"]
    missing = tmp_path / "elsewhere" / "fast.bcrec.json"
    assert result["error"].startswith(f"worker {result['worker']} (")
    assert f"cannot read {missing}: No such file or directory" in result["error"]
    assert _pids(tmp_path) == []  # refused before the job's command started


def test_ctrl_c_cancels_what_is_pending_ends_what_runs_and_says_what_finished(tmp_path):
    jobs = _jobs(tmp_path, ["fast", "slow1", "slow2", "slow3"])
    proc = subprocess.Popen(_driver(tmp_path, jobs, "--cluster", "local:1"), cwd=REPO, env=_env(tmp_path),
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().startswith("[1/4] fast__a__egocentric: ok")
        for _ in range(600):  # until the one worker holds slow1's partial save
            if list((tmp_path / "results").glob("slow*@")):
                break
            time.sleep(0.05)
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=90)
    finally:
        proc.kill()
    assert proc.returncode == 130
    assert len(err.strip().splitlines()) == 1 and "stopped by SIGINT" in err
    summary = _summary(tmp_path)
    assert (summary["ok"], summary["cancelled"], summary["interrupted"]) == (1, 3, "SIGINT")
    errors = {r["job"]: r["error"] for r in summary["results"] if not r["ok"]}
    running = [e for e in errors.values() if "while running" in e]
    assert len(running) == 1 and "removed its partial save" in running[0]
    assert sum("before it started" in e for e in errors.values()) == 2
    assert len(_pids(tmp_path)) == 2  # fast and one slow job: the pending ones never started
    assert not _still_alive(_pids(tmp_path))  # the SIGTERM-deaf job was killed
    assert not list((tmp_path / "results").glob("*@"))
    assert len([ln for ln in out.splitlines() if ln.startswith("[")]) == 3  # + the first: one line per job


def _start_dask(tmp_path) -> tuple[list[subprocess.Popen], str]:
    dask_cli = Path(sys.executable).with_name("dask")
    sched_file = tmp_path / "scheduler.json"
    env = {**_env(tmp_path)}
    scheduler = subprocess.Popen([str(dask_cli), "scheduler", "--host", "127.0.0.1", "--port", "0",
                                  "--dashboard-address", "127.0.0.1:0", "--scheduler-file", str(sched_file)],
                                 cwd=tmp_path, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    procs = [scheduler]
    for _ in range(600):
        if sched_file.exists() and sched_file.read_text().strip():
            break
        time.sleep(0.05)
    address = json.loads(sched_file.read_text())["address"]
    procs.append(subprocess.Popen([str(dask_cli), "worker", address, "--nthreads", "1", "--host", "127.0.0.1",
                                   "--dashboard-address", "127.0.0.1:0", "--name", "farm-worker-1"],
                                  cwd=REPO, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
    return procs, address


def test_a_running_scheduler_and_its_worker_run_the_jobs(tmp_path):
    procs, address = _start_dask(tmp_path)
    try:
        jobs = _jobs(tmp_path, ["fast1", "fast2"])
        out = _run_fake(tmp_path, jobs, "--cluster", address)
    finally:
        for proc in procs:
            proc.terminate()
        for proc in procs:
            proc.wait(timeout=30)
    assert out.returncode == 0, out.stderr
    summary = _summary(tmp_path)
    assert summary["ok"] == 2 and summary["cluster"] == address
    assert len({r["worker"] for r in summary["results"]}) == 1  # the one worker we started
    assert all(Path(r["output"]).is_file() for r in summary["results"])


# ---- a real bake: the cluster gives what the local batch gives --------------------------------------

def _actions(blend: Path) -> dict:
    """Every action of the file: {action: {(data_path, index): [keyframe (frame, value), ...]}}."""
    bpy.ops.wm.open_mainfile(filepath=str(blend), load_ui=False, use_scripts=False)
    return {a.name: {(fc.data_path, fc.array_index): [tuple(k.co) for k in fc.keyframe_points]
                     for fc in a.fcurves} for a in bpy.data.actions}


@pytest.mark.slow
def test_a_local_cluster_bakes_the_same_actions_as_the_local_batch(tmp_path):
    _write_inputs(tmp_path)
    text = ('[defaults]\nmethod = ["egocentric", "rotations"]\nworkers = 2\n'
            '[[recordings]]\npath = "takes/clap.bcrec.json"\nuser = "takes/performer.body.json"\n'
            '[[avatars]]\nfile = "procedural.blend"\n')
    (tmp_path / "local.toml").write_text(text.replace("workers = 2\n", 'workers = 2\noutput_dir = "local"\n'))
    (tmp_path / "cluster.toml").write_text(text.replace("workers = 2\n", 'workers = 2\noutput_dir = "cluster"\n'))
    for jobs, extra in (("local.toml", []), ("cluster.toml", ["--cluster", "local:2"])):
        out = subprocess.run([sys.executable, "-m", "bodycal_addon", "batch", str(tmp_path / jobs), *extra], cwd=REPO,
                             capture_output=True, text=True, timeout=900)
        assert out.returncode == 0, out.stderr
    names = sorted(p.name for p in (tmp_path / "local").glob("*.blend"))
    assert names == ["clap__procedural__egocentric.blend", "clap__procedural__rotations.blend"]
    assert sorted(p.name for p in (tmp_path / "cluster").glob("*.blend")) == names
    for name in names:
        local, cluster = _actions(tmp_path / "local" / name), _actions(tmp_path / "cluster" / name)
        assert local and any(len(curves) > 10 for curves in local.values())
        assert cluster == local  # every key equal
