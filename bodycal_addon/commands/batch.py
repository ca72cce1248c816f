"""`bodycal batch JOBS.toml`."""

import json
import sys


def run(args) -> int:
    from ..batch import run_batch

    summary = run_batch(args.jobs, log=lambda line: print(line, flush=True))
    print(json.dumps({k: v for k, v in summary.items() if k != "results"}))
    if summary["failed"]:
        print(f"bodycal batch: {summary['failed']} of {summary['jobs']} jobs failed (see {summary['summary_file']})",
              file=sys.stderr)
        return 2
    return 0
