"""`bodycal batch JOBS.toml`: exit 0 when every job succeeded, 2 on a bad jobs file or a failed job,
130 when stopped by SIGINT (Ctrl-C) and 143 by SIGTERM (the summary is written in every case).
`--cluster` runs the same jobs on a Dask cluster (app/cluster.py); `--export-openjd` and
`--export-flamenco` write them for a farm instead of running them (app/openjd.py, app/flamenco.py)."""

import json
import signal
from pathlib import Path

from ...core.errors import BodyCalError
from ...output.review_page import write_page
from .. import console
from ..batch import EXIT_ON_SIGNAL, run_batch
from ..flamenco import export_flamenco
from ..openjd import export_openjd

_FARM_PACKAGES = ("dask", "distributed", "tqdm", "cloudpickle", "msgpack", "tornado")


def _cluster_module():
    """app/cluster.py, which needs dask and distributed: a batch dependency, not the extension's."""
    try:
        from .. import cluster
    except ImportError as exc:
        if (exc.name or "").split(".")[0] not in _FARM_PACKAGES:
            raise
        package = exc.name.split(".")[0]
        raise BodyCalError(f"needs the Python package {package}; install the batch dependencies with "
                           "`pip install -r requirements-dev.txt` in this environment", source="--cluster") from None
    return cluster


def _export(args) -> int:
    if args.export_openjd:
        written = export_openjd(args.jobs, args.export_openjd, review=args.review)
    else:
        written = export_flamenco(args.jobs, args.export_flamenco, review=args.review)
    console.say(f"wrote {written}")
    return 0


def run(args) -> int:
    if args.retries and not args.cluster:
        raise BodyCalError("retries a job whose cluster worker died; give it with --cluster", source="--retries")
    if args.export_openjd or args.export_flamenco:
        return _export(args)
    with console.progress("batch") as step:
        if args.cluster:
            summary = _cluster_module().run_on_cluster(args.jobs, args.cluster, args.retries, log=console.say,
                                                       progress=step, review=args.review)
        else:
            summary = run_batch(args.jobs, log=console.say, progress=step, review=args.review)
    if args.review:  # the page is the batch's, made from its summary and the jobs' records
        console.say(f"saved {write_page(Path(summary['summary_file']).parent, summary)}")
    console.say(json.dumps({k: v for k, v in summary.items() if k not in ("results", "removed_stale")}))
    if summary["interrupted"]:
        print(f"bodycal batch: stopped by {summary['interrupted']}: {summary['ok']} ok, {summary['failed']} failed, "
              f"{summary['cancelled']} cancelled (see {summary['summary_file']})", file=console.stderr(), flush=True)
        return EXIT_ON_SIGNAL.get(getattr(signal.Signals, summary["interrupted"], None), 130)
    if summary["failed"]:
        print(f"bodycal batch: {summary['failed']} of {summary['jobs']} jobs failed (see {summary['summary_file']})",
              file=console.stderr(), flush=True)
        return 2
    return 0
