"""`bodycal batch JOBS.toml`: exit 0 when every job succeeded, 2 on a bad jobs file or a failed job,
130 when stopped by SIGINT (Ctrl-C) and 143 by SIGTERM (the summary is written in every case)."""

import json
import signal

from .. import console


def run(args) -> int:
    from ..batch import EXIT_ON_SIGNAL, run_batch

    summary = run_batch(args.jobs, log=console.say)
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
