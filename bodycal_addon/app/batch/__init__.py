"""`bodycal batch JOBS.toml`: many recordings x avatars, in parallel worker processes.

Each job is one self-contained `retarget` command line (the same one a person would type), so the
same jobs run unchanged on a render farm that runs `blender -b` commands (see README, "Batch jobs
and render farms"). A failed job is reported and the others finish.

Two modules behind this face: `jobs` reads and checks the jobs file and expands it into named jobs
(the file's format and the output names are in its docstring, docs/FORMATS.md §4.1); `runner` runs
them in worker processes here (workers, timeouts, stopping, the summary). `app/cluster.py` runs the
same jobs on a Dask cluster with the runner's parts; `app/openjd.py` and `app/flamenco.py` export
them for farms (docs/FARM.md). `runner.command_line` is the one command a job runs, looked up when
a job starts (the tests and benchmarks put a stand-in there: bodycal_dev/fake_job.py).
"""

from .jobs import (
    EXPORT_FORMATS,
    MAX_TIMEOUT,
    MAX_WORKERS,
    METHODS,
    RUNNERS,
    TRANSFER_METHODS,
    Job,
    load_jobs,
    output_names,
)
from .runner import (
    EXIT_ON_SIGNAL,
    GRACE_SECONDS,
    KILL,
    Running,
    Stop,
    command_line,
    end_if_overdue,
    finish_job,
    job_progress,
    job_result,
    prepare_batch,
    progress_line,
    remove_partial,
    run_batch,
    signal_job,
    signal_name,
    start_job,
    stop_running,
    write_summary,
)

__all__ = [
    "EXIT_ON_SIGNAL", "EXPORT_FORMATS", "GRACE_SECONDS", "KILL", "MAX_TIMEOUT", "MAX_WORKERS", "METHODS", "RUNNERS",
    "TRANSFER_METHODS", "Job", "Running", "Stop", "command_line", "end_if_overdue", "finish_job", "job_progress",
    "job_result", "load_jobs", "output_names", "prepare_batch", "progress_line", "remove_partial", "run_batch",
    "signal_job", "signal_name", "start_job", "stop_running", "write_summary",
]
