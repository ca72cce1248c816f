"""Whether the processes a test started are still running (the batch and cluster tests)."""

from __future__ import annotations

import os
import time
from pathlib import Path


def alive(pid: int) -> bool:
    """Running: a process that was killed but not yet reaped by its new parent (a zombie) is not."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return False


def still_alive(pids, within: float = 5.0) -> list[int]:
    """The processes still running after up to `within` seconds: a kill, even on its parent's death
    (PR_SET_PDEATHSIG), is delivered and acted on asynchronously."""
    deadline = time.monotonic() + within
    while True:
        running = [pid for pid in pids if alive(pid)]
        if not running or time.monotonic() > deadline:
            return running
        time.sleep(0.05)
