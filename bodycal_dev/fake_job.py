"""A stand-in for a batch job's `retarget` command, for the batch and cluster tests and benchmarks:
it takes the same command line and acts by the name of its first output, in a fraction of the time
of a bake (tiny jobs by the thousand, jobs that hang, jobs that kill the worker running them).

    fast...        writes every output (-o) and exits 0
    nap...         sleeps $FAKE_NAP seconds (default 1), then writes like fast
    slow...        ignores SIGTERM, leaves `<output>@` (Blender's partial save) and sleeps
    killworker...  the first time (no marker in $FAKE_STATE): kills the process that started it with
                   SIGKILL and waits to be taken down with it; the next time: writes like fast

An existing output is refused unless --overwrite is given, as `retarget` refuses it. With
$FAKE_PIDS set, each run leaves an empty file named after its pid there.

Run it as `python -m bodycal_dev.fake_job ARGS...`; `command` is a drop-in for
`bodycal_addon.app.batch.runner.command_line`.
"""

from __future__ import annotations

import os
import signal
import sys
import time
from pathlib import Path


def command(job, runner: str) -> list[str]:
    """The fake job's command line for a batch Job (runner ignored: always this interpreter)."""
    return [sys.executable, "-m", "bodycal_dev.fake_job", *job.argv()]


def _write(outputs: list[str], overwrite: bool) -> int:
    for out in outputs:
        if os.path.exists(out) and not overwrite:
            print(f"bodycal retarget: error: {out}: exists; give --overwrite to replace it", file=sys.stderr)
            return 2
    for out in outputs:
        Path(out).write_bytes(b"fake bake\n")
    return 0


def _kill_my_starter(name: str) -> bool:
    """True the first time for this job name: the starter is killed and this process waits to die."""
    marker = Path(os.environ["FAKE_STATE"]) / f"{name}.killed"
    if marker.exists():
        return False
    marker.write_text(str(os.getpid()))
    os.kill(os.getppid(), signal.SIGKILL)
    time.sleep(60)  # PR_SET_PDEATHSIG ends it long before
    return True


def main(argv: list[str]) -> int:
    outputs = [argv[i + 1] for i, a in enumerate(argv) if a == "-o"]
    name = os.path.basename(outputs[0])
    if os.environ.get("FAKE_PIDS"):
        Path(os.environ["FAKE_PIDS"], str(os.getpid())).touch()
    if name.startswith("slow"):
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        Path(outputs[0] + "@").write_bytes(b"half a bake")
        time.sleep(600)
        return 1
    if name.startswith("killworker") and _kill_my_starter(name):
        return 1
    if name.startswith("nap"):
        time.sleep(float(os.environ.get("FAKE_NAP", "1")))
    return _write(outputs, "--overwrite" in argv)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
