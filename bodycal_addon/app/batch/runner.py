"""Running a batch's jobs (`jobs.py`) here, each in its own worker process: `workers` at a time, a
job over its `timeout` ended, a failed job reported while the others finish, and the summary
(`<output_dir>/summary.json`, docs/FORMATS.md §4.1).

Stopping: on SIGINT (Ctrl-C) or SIGTERM no new job starts, running workers are sent SIGTERM and,
after GRACE_SECONDS, SIGKILL (a second signal kills at once); the summary lists what finished and
what was cancelled (status "cancelled"), and `bodycal batch` exits 130 (SIGINT) or 143 (SIGTERM).
A worker that fails or is ended can leave Blender's temporary save file `<output>@`; it is removed
and said in that job's error line. One left by an earlier killed batch is removed before the jobs
start and listed in the summary (`removed_stale`).

A job that runs longer than `timeout` seconds is ended (SIGKILL) and failed. On Linux every job
process is tied to the process that started it (PR_SET_PDEATHSIG): a batch or a cluster worker
that is killed outright takes its running jobs with it, so none is left writing an output that a
retry writes again. The same jobs run on a Dask cluster through `app/cluster.py`, and are
exported for farms by `app/openjd.py` and `app/flamenco.py` (docs/FARM.md).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from collections import deque
from dataclasses import dataclass, replace
from pathlib import Path

from ...core.errors import BodyCalError
from ...core.paths import ROOT_DIR
from .jobs import Job, load_jobs

GRACE_SECONDS = 3.0  # between SIGTERM and SIGKILL for a running worker when the batch is stopped
EXIT_ON_SIGNAL = {signal.SIGINT: 130, signal.SIGTERM: 143}  # 128 + signal number, as shells do


def command_line(job: Job, runner: str) -> list[str]:
    """The self-contained command for one job: what a farm worker runs. Evaluated where the job runs
    (a cluster worker calls it itself), so `sys.executable` is that machine's interpreter."""
    if runner == "blender":  # the extension must be installed and enabled in that Blender
        return ["blender", "-b", "-c", "bodycal", *job.argv()]
    return [sys.executable, "-m", "bodycal_addon", *job.argv()]


# Run before the job's own command (Linux): the job gets SIGKILL when the process that started it
# dies, then becomes that command (execvp keeps the pid and the death signal). A batch or a cluster
# worker killed outright so never leaves a bake running on behind it.
_TIED_TO_PARENT = (
    "import ctypes, os, sys\n"
    "ctypes.CDLL(None).prctl(1, 9)\n"  # PR_SET_PDEATHSIG, SIGKILL
    "os.getppid() == int(sys.argv[1]) or os._exit(137)\n"  # the parent died before prctl: end as if killed
    "os.execvp(sys.argv[2], sys.argv[2:])\n")


def _tied_to_parent(command: list[str]) -> list[str]:
    if not sys.platform.startswith("linux"):
        return command
    return [sys.executable, "-c", _TIED_TO_PARENT, str(os.getpid()), *command]


class Stop:
    """Signal handler: the first SIGINT/SIGTERM stops the batch, a second one kills at once."""

    def __init__(self):
        self.signum: int | None = None
        self.force = False

    def __call__(self, signum, _frame):
        if self.signum is None:
            self.signum = signum
        else:
            self.force = True

    def install(self) -> dict:
        previous = {}
        for sig in EXIT_ON_SIGNAL:
            try:
                previous[sig] = signal.signal(sig, self)
            except ValueError:  # not the main thread: Ctrl-C reaches the caller as KeyboardInterrupt
                pass
        return previous

    @staticmethod
    def restore(previous: dict):
        for sig, handler in previous.items():
            signal.signal(sig, handler)


@dataclass
class Running:
    job: Job
    proc: subprocess.Popen
    stderr: object
    t0: float
    timed_out: bool = False

    def overdue(self) -> bool:
        return self.job.timeout is not None and time.perf_counter() - self.t0 > self.job.timeout


def signal_name(signum: int) -> str:
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


def remove_partial(job: Job) -> list[str]:
    """Remove the job's leftovers; the names of those removed (one left in place, e.g. for lack of
    permission, is not said to be removed)."""
    removed = []
    for path in job.leftovers():
        try:
            path.unlink()
            removed.append(path.name)
        except OSError:
            pass
    return removed


def start_job(job: Job, command: list[str]) -> Running | dict:
    """Starts one job's command in its own process (never a fork of a process that loaded Blender);
    a result dict if it cannot start."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT_DIR), env.get("PYTHONPATH", "")) if p)
    err = tempfile.TemporaryFile()  # a file, not a pipe: a chatty worker can never block on it
    t0 = time.perf_counter()
    try:
        # Its own session (POSIX): the terminal's Ctrl-C reaches only the batch, which ends the
        # worker and everything it started (os.killpg).
        proc = subprocess.Popen(_tied_to_parent(command), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=err, cwd=ROOT_DIR, env=env, start_new_session=os.name == "posix")
    except OSError as exc:
        err.close()
        return job_result(job, "failed", None, 0.0, f"cannot start the worker: {exc.strerror or exc}")
    return Running(job, proc, err, t0)


def signal_job(run: Running, sig: int):
    if run.proc.poll() is not None:
        return
    try:
        if os.name == "posix":
            os.killpg(run.proc.pid, sig)
        elif sig == signal.SIGTERM:
            run.proc.terminate()
        else:
            run.proc.kill()
    except (ProcessLookupError, PermissionError):
        pass


KILL = signal.SIGKILL if hasattr(signal, "SIGKILL") else signal.SIGTERM


def end_if_overdue(run: Running) -> bool:
    """Ends a job past its timeout (SIGKILL: a bake that overran gets no grace); True if it did."""
    if run.timed_out or not run.overdue():
        return False
    run.timed_out = True
    signal_job(run, KILL)
    return True


def job_result(job: Job, status: str, code: int | None, seconds: float, error: str | None) -> dict:
    return {"job": job.name, "status": status, "ok": status == "ok", "exit_code": code, "seconds": round(seconds, 2),
            "output": str(job.output) if status == "ok" else None,
            "outputs": [str(o) for o in job.outputs] if status == "ok" else [],
            "error": " ".join(error.split()) if error else None}


def finish_job(run: Running, stopped_by: str | None = None) -> dict:
    job, code = run.job, run.proc.wait()
    seconds = time.perf_counter() - run.t0
    run.stderr.seek(0)
    lines = [ln for ln in run.stderr.read().decode("utf-8", errors="replace").splitlines() if ln.strip()]
    run.stderr.close()
    removed = remove_partial(job)
    if code == 0 and not run.timed_out:
        error = f"removed a temporary save file {', '.join(removed)} the worker left" if removed else None
        return {**job_result(job, "ok", code, seconds, None), **({"note": error} if error else {})}
    if stopped_by:
        status, error = "cancelled", f"cancelled by {stopped_by} while running"
    else:
        status = "failed"
        if run.timed_out:
            error = f"timed out after {job.timeout:g} s (defaults.timeout) and was ended"
        elif code < 0:
            error = f"the worker was killed by {signal_name(-code)}"
        else:
            error = lines[-1] if lines else f"the worker ended with exit code {code}"
    if removed:
        error += f"; removed its partial save {', '.join(removed)}"
    return job_result(job, status, code, seconds, error)


def stop_running(running: list[Running], stop: Stop, grace: float):
    for run in running:
        signal_job(run, signal.SIGTERM)
    deadline = time.monotonic() + grace
    while any(r.proc.poll() is None for r in running) and time.monotonic() < deadline and not stop.force:
        time.sleep(0.05)
    for run in running:
        signal_job(run, KILL)


def prepare_batch(jobs_file, log=print, review: bool = False) -> tuple[list[Job], dict, list[str]]:
    """The checked jobs (each writing its review too with `review`), the settings, and the partial
    saves of an earlier killed batch, removed (said on `log`); the output folder is created."""
    jobs, settings = load_jobs(jobs_file)
    if review:
        jobs = [replace(job, review=True) for job in jobs]
    out_dir = Path(settings["output_dir"])
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise BodyCalError(f"cannot create the output folder {out_dir}: {exc.strerror or exc}", source=str(jobs_file),
                           field="defaults.output_dir") from None
    stale = [str(Path(job.output.parent, name)) for job in jobs for name in remove_partial(job)]
    for name in stale:
        log(f"removed {name}, a partial save left by an earlier batch that was killed")
    return jobs, settings, stale


def progress_line(r: dict, done: int, total: int) -> str:
    status = {"ok": "ok", "cancelled": r["error"]}.get(r["status"], f"FAILED: {r['error']}")
    where = f" on {r['worker']}" if r.get("worker") else ""
    return f"[{done}/{total}] {r['job']}: {status} ({r['seconds']} s{where})"


def write_summary(jobs: list[Job], settings: dict, results: list[dict], stop: Stop, stale: list[str],
                  **extra) -> dict:
    """`<output_dir>/summary.json` (docs/FORMATS.md §4.1), whole or absent; the summary, with
    `summary_file`."""
    results.sort(key=lambda r: r["job"])
    summary = {"jobs": len(jobs), "ok": sum(r["status"] == "ok" for r in results),
               "failed": sum(r["status"] == "failed" for r in results),
               "cancelled": sum(r["status"] == "cancelled" for r in results),
               "interrupted": signal_name(stop.signum) if stop.signum is not None else None,
               "removed_stale": stale, **extra, "results": results}
    summary_path = Path(settings["output_dir"]) / "summary.json"
    tmp = summary_path.with_name(summary_path.name + ".tmp")
    tmp.write_text(json.dumps(summary, indent=1))
    os.replace(tmp, summary_path)  # a summary is whole or absent, even if the batch is killed now
    summary["summary_file"] = str(summary_path)
    return summary


def _poll(running: list[Running], report):
    for run in running:
        end_if_overdue(run)
    for run in [r for r in running if r.proc.poll() is not None]:
        running.remove(run)
        report(finish_job(run))


def _run_all(jobs: list[Job], settings: dict, stop: Stop, report, grace: float):
    workers = max(1, min(settings["workers"], len(jobs)))
    pending, running = deque(jobs), []
    try:
        try:
            while (pending or running) and stop.signum is None:
                while pending and len(running) < workers and stop.signum is None:
                    job = pending.popleft()
                    started = start_job(job, command_line(job, settings["runner"]))
                    if isinstance(started, dict):
                        report(started)
                    else:
                        running.append(started)
                time.sleep(0.05)
                _poll(running, report)
        except KeyboardInterrupt:  # handlers could not be installed (not the main thread)
            stop.signum = signal.SIGINT
        if stop.signum is not None:
            name = signal_name(stop.signum)
            stop_running(running, stop, grace)
            for run in running:
                report(finish_job(run, stopped_by=name))
            for job in pending:
                report(job_result(job, "cancelled", None, 0.0, f"cancelled by {name} before it started"))
    finally:
        for run in running:  # only if something above raised: never leave a worker behind
            signal_job(run, KILL)


def job_progress(results: list[dict], total: int) -> tuple[str, float]:
    """(stage, fraction) of a batch's progress line: the jobs done, ok and failed."""
    failed = sum(r["status"] == "failed" for r in results)
    return (f"{len(results)}/{total} jobs" + (f", {failed} failed" if failed else ""),
            len(results) / max(total, 1))


def run_batch(jobs_file, log=print, *, grace: float = GRACE_SECONDS, progress=None, review: bool = False) -> dict:
    """Runs the jobs file's jobs in worker processes here (module docstring); `log` gets one line per
    finished job, `progress(stage, fraction)` how many are done; `review`: each job reviews its bake."""
    jobs, settings, stale = prepare_batch(jobs_file, log, review)
    results: list[dict] = []
    stop = Stop()
    previous = stop.install()
    step = progress or (lambda stage, fraction: None)
    step(*job_progress(results, len(jobs)))

    def report(r):
        results.append(r)
        log(progress_line(r, len(results), len(jobs)))
        step(*job_progress(results, len(jobs)))

    try:
        _run_all(jobs, settings, stop, report, grace)
    finally:
        Stop.restore(previous)
    return write_summary(jobs, settings, results, stop, stale)
