"""`bodycal batch JOBS.toml --cluster ADDRESS`: the batch's jobs as tasks on a Dask distributed
cluster (docs/FARM.md, docs/FORMATS.md §4.1).

ADDRESS is `tcp://HOST:PORT`, a running scheduler whose workers were started with the project's
environment, or `local:N`, a LocalCluster of N worker processes on this machine (loopback only).
Dask does the scheduling; this module only turns jobs into tasks and results into the batch's
summary. Each task runs one job as its own process (`batch.start_job`, the same command line as
the local batch), so a worker never holds two bakes in one interpreter and Blender is never
loaded in a forked process; the workers themselves are spawned. Output names, overwrite rules,
`defaults.timeout` and `summary.json` are the local batch's; each result also names the worker
that ran it (`worker`, `host`) and how many `attempts` it took.

A job whose worker died (the Dask worker lost: KilledWorker, or the job's process killed by a
signal nobody in the batch sent) is submitted again, up to `--retries` times. An output that did
not exist when the batch started is this batch's own, so a job run again (a retry, or Dask running
a task again whose result was lost with its worker) replaces it; one that existed is replaced only
with `overwrite = true`, as in the local batch. A dead worker also fails
the tasks that were only waiting on it; a job that had not started (its task never logged the
STARTED event) is submitted again without using a retry, at most MAX_REQUEUES times. On a local
cluster the scheduler itself gives up on the first death (`allowed-failures` 0) so that only
`--retries` counts; a remote scheduler applies its own `allowed-failures` first (docs/FARM.md).

Ctrl-C or SIGTERM: the futures not yet on a worker are cancelled; the running jobs are told to
stop through a Dask Variable the tasks poll, and are ended as the local batch ends its workers.
"""

from __future__ import annotations

import itertools
import logging
import re
import signal
import socket
import subprocess
import time
import uuid
from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import replace

import dask
from distributed import Client, LocalCluster, Variable, as_completed, get_worker
from distributed.scheduler import KilledWorker

from ..core.errors import BodyCalError
from . import batch
from .batch import GRACE_SECONDS, MAX_WORKERS, Job, Stop, runner

CONNECT_SECONDS = 10.0  # to reach a remote scheduler
WORKERS_SECONDS = 60.0  # for a remote scheduler to have at least one worker
POLL_SECONDS = 0.2  # how often the client looks for finished futures, and a task for the stop
LOOPBACK_ANY_PORT = "127.0.0.1:0"  # every server a local cluster starts (its dashboards too) listens on loopback only
STOPPING_SECONDS = 10.0  # beyond the grace: how long the client waits for running jobs to report a stop
_LOCAL = re.compile(r"local:(\d{1,4})")
_REMOTE = re.compile(r"(tcp|tls)://[^\s/]+:\d{1,5}")
STARTED = "bodycal-job-started"  # the event topic a task logs as its job's process starts
MAX_REQUEUES = 10  # a job that never started, failed with its worker: submitted again without a retry
ADDRESS_HELP = "tcp://HOST:PORT (a running Dask scheduler) or local:N (N worker processes on this machine)"


def parse_address(text: str) -> str | int:
    """The scheduler address, or the worker count of a local cluster."""
    local = _LOCAL.fullmatch(text)
    if local and 1 <= int(local[1]) <= MAX_WORKERS:
        return int(local[1])
    if local or not _REMOTE.fullmatch(text):
        raise BodyCalError(f"{text!r} is not a cluster; use {ADDRESS_HELP}, N from 1 to {MAX_WORKERS}",
                           source="--cluster")
    return text


# ---- on the worker --------------------------------------------------------------------------------

def _inputs(job: Job) -> list:
    return [p for p in (job.recording, job.user, job.avatar, job.bone_map) if p is not None]


def _unreadable(job: Job, where: str) -> str | None:
    """One line naming the worker and the first input it cannot read, or None."""
    for path in _inputs(job):
        try:
            with open(path, "rb"):
                pass
        except OSError as exc:
            return (f"worker {where} cannot read {path}: {exc.strerror or exc}; every worker needs the inputs "
                    "at the same path on shared storage (docs/FARM.md)")
    return None


def _wait(run: batch.Running, stop: Variable) -> str | None:
    """Waits for the job's process; ends it past its timeout, or when the batch is stopped (then the
    signal's name)."""
    while run.proc.poll() is None:
        try:
            run.proc.wait(timeout=POLL_SECONDS)
        except subprocess.TimeoutExpired:
            pass
        if batch.end_if_overdue(run) or run.proc.poll() is not None:
            continue
        stopped_by = stop.get()
        if stopped_by:
            batch.stop_running([run], Stop(), GRACE_SECONDS)
            return stopped_by
    return None


def run_on_worker(job: Job, runner: str, command: Callable[[Job, str], list[str]], stop_name: str,
                  may_replace: bool) -> dict:
    """One job, on a Dask worker: the result dict of the batch's summary, with the worker."""
    worker = get_worker()
    host = socket.gethostname()
    where = f"{worker.address} ({host})"
    stop = Variable(stop_name)
    stopped_by = stop.get()
    if stopped_by:
        result = batch.job_result(job, "cancelled", None, 0.0, f"cancelled by {stopped_by} before it started")
    elif (unreadable := _unreadable(job, where)) is not None:
        result = batch.job_result(job, "failed", None, 0.0, unreadable)
    else:
        if may_replace:  # absent when the batch started: a run of this job wrote it, ours to replace
            job = replace(job, overwrite=True)
        worker.log_event(STARTED, worker.get_current_task())
        run = batch.start_job(job, command(job, runner))
        if isinstance(run, dict):
            result = run
        else:
            stopped_by = _wait(run, stop)
            result = batch.finish_job(run, stopped_by)
            # killed by a signal that neither the timeout nor the batch's stop sent: the machine's doing
            result["killed"] = bool(run.proc.returncode < 0 and not run.timed_out and not stopped_by)
    return {**result, "worker": worker.address, "host": host}


# ---- on the client --------------------------------------------------------------------------------

@contextmanager
def connect(target: str | int) -> Iterator[Client]:
    """A client of the remote scheduler, or of a LocalCluster of `target` spawned worker processes
    (one thread each) listening on loopback only; closed (the local workers ended) on leaving."""
    if isinstance(target, int):
        settings = {"distributed.worker.multiprocessing-method": "spawn",  # never fork a process
                    "distributed.scheduler.allowed-failures": 0}  # --retries alone counts deaths
        with dask.config.set(settings):
            cluster = LocalCluster(n_workers=target, threads_per_worker=1, processes=True, host="127.0.0.1",
                                   dashboard_address=LOOPBACK_ANY_PORT, worker_dashboard_address=LOOPBACK_ANY_PORT,
                                   silence_logs=logging.CRITICAL)
        try:
            with Client(cluster, set_as_default=False) as client:
                yield client
        finally:
            cluster.close()
        return
    logging.getLogger("distributed").setLevel(logging.CRITICAL)  # stderr is for BodyCal's own lines
    try:
        client = Client(target, timeout=CONNECT_SECONDS, set_as_default=False)
    except (OSError, TimeoutError) as exc:
        raise BodyCalError(f"cannot reach a Dask scheduler ({' '.join(str(exc).split())[:120]}); start one with "
                           "`dask scheduler` or check the address", source=target) from None
    with client:
        try:
            client.wait_for_workers(1, timeout=WORKERS_SECONDS)
        except TimeoutError:
            raise BodyCalError(f"the scheduler has no worker after {WORKERS_SECONDS:g} s; start workers with "
                               f"`dask worker {target}`", source=target) from None
        yield client


def _outcome(outcome, job: Job, attempt: int) -> tuple[dict, bool]:
    """The job's result from what its future gave (the task's dict, an error as (type, exception,
    traceback), or a CancelledError), and whether its worker died (a retry may help)."""
    if isinstance(outcome, dict):
        result = dict(outcome)
        died = result.pop("killed", False)
    else:
        exc = outcome[1] if isinstance(outcome, tuple) else outcome
        died = isinstance(exc, KilledWorker)
        error = "the Dask worker running it died" if died else f"the task failed on the cluster: {exc!r}"
        result = batch.job_result(job, "failed", None, 0.0, error)
    return {**result, "attempts": attempt + 1}, died


class Scheduling:
    """The futures of one batch on one client: submitted, awaited, retried, cancelled."""

    def __init__(self, client: Client, jobs: list[Job], settings: dict, retries: int, report, log):
        self.client, self.settings, self.retries, self.report, self.log = client, settings, retries, report, log
        self.token = uuid.uuid4().hex[:12]
        self.stop = Variable(f"bodycal-stop-{self.token}", client=client)
        self.stop.set("")
        self.fresh = {job.name: not any(o.exists() for o in job.outputs) for job in jobs}
        self.futures = {}
        self.requeued = Counter()
        self.serial = itertools.count()  # every submission its own key: Dask keeps a failed key's error
        # with_results: each result is fetched as its task ends, so a worker lost later loses nothing
        self.done = as_completed(loop=client.loop, with_results=True, raise_errors=False)
        for index, job in enumerate(jobs):
            self.submit(index, job, 0)

    def started(self, key: str) -> bool:
        return any(message == key for _time, message in self.client.get_events(STARTED))

    def submit(self, index: int, job: Job, attempt: int):
        # runner.command_line is looked up now, and called on the worker (its own interpreter)
        future = self.client.submit(run_on_worker, job, self.settings["runner"], runner.command_line, self.stop.name,
                                    self.fresh[job.name], key=f"bodycal-{self.token}-{index}-{next(self.serial)}",
                                    pure=False)
        self.futures[future] = (index, job, attempt)
        self.done.add(future)

    def collect(self):
        """Reports what finished since the last call; resubmits a job whose worker died."""
        for future, outcome in self.done.next_batch(block=False):
            if future not in self.futures:
                continue  # cancelled by the stop, reported already
            index, job, attempt = self.futures.pop(future)
            result, died = _outcome(outcome, job, attempt)
            if died and not self.started(future.key) and self.requeued[job.name] < MAX_REQUEUES:
                self.requeued[job.name] += 1  # it was waiting on the worker that died: not a try
                self.submit(index, job, attempt)
            elif died and attempt < self.retries:
                self.log(f"retrying {job.name} ({result['error']}; attempt {attempt + 2} of {self.retries + 1})")
                self.submit(index, job, attempt + 1)
            else:
                self.report(result)

    def run(self, stop: Stop):
        while self.futures and stop.signum is None:
            self.collect()
            time.sleep(POLL_SECONDS)

    def cancel(self, name: str, stop: Stop):
        """After SIGINT/SIGTERM: the futures not on a worker are cancelled; the running jobs are told
        to stop, and those that do not report in time are cancelled too."""
        self.stop.set(name)
        on_workers = {key for keys in self.client.processing().values() for key in keys}
        waiting = [f for f in self.futures if f.key not in on_workers]
        self._cancel(waiting, f"cancelled by {name} before it started")
        deadline = time.monotonic() + GRACE_SECONDS + STOPPING_SECONDS
        while self.futures and time.monotonic() < deadline and not stop.force:
            self.collect()
            time.sleep(POLL_SECONDS)
        self._cancel(list(self.futures), f"cancelled by {name} while running")

    def _cancel(self, futures: list, error: str):
        self.client.cancel(futures)
        for future in futures:
            _index, job, attempt = self.futures.pop(future)
            self.report({**batch.job_result(job, "cancelled", None, 0.0, error), "attempts": attempt + 1})


def run_on_cluster(jobs_file, address: str, retries: int = 0, log=print, progress=None, review: bool = False) -> dict:
    """Runs the jobs file on the cluster at `address` (module docstring); the summary, as
    `batch.run_batch`'s, written to `<output_dir>/summary.json`; `progress(stage, fraction)` how many
    jobs are done (the command line's progress line, which steps aside for `log`'s lines); `review`:
    each job reviews its bake."""
    target = parse_address(address)
    if isinstance(retries, bool) or not isinstance(retries, int) or not 0 <= retries <= 100:
        raise BodyCalError(f"must be a whole number from 0 to 100, got {retries!r}", source="--retries")
    jobs, settings, stale = batch.prepare_batch(jobs_file, log, review)
    results: list[dict] = []
    step = progress or (lambda stage, fraction: None)
    step(*batch.job_progress(results, len(jobs)))
    say = log

    def report(result: dict):
        results.append(result)
        say(batch.progress_line(result, len(results), len(jobs)))
        step(*batch.job_progress(results, len(jobs)))

    stop = Stop()
    previous = stop.install()
    try:
        with connect(target) as client:
            scheduling = Scheduling(client, jobs, settings, retries, report, say)
            try:
                scheduling.run(stop)
            except KeyboardInterrupt:  # the handlers could not be installed (not the main thread)
                stop.signum = signal.SIGINT
            if stop.signum is not None:
                scheduling.cancel(batch.signal_name(stop.signum), stop)
    finally:
        Stop.restore(previous)
    by_name = {job.name: job for job in jobs}
    for result in results:  # a job ended with its worker (a local cluster closed) leaves its partial save
        if result["status"] == "cancelled":
            batch.remove_partial(by_name[result["job"]])
    return batch.write_summary(jobs, settings, results, stop, stale, cluster=address)
