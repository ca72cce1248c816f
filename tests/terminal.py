"""Run a command with its stdout on a pseudo-terminal (Python's `pty`), as a person at a terminal
runs it: what BodyCal prints only when stdout is a terminal (the progress line) shows."""

from __future__ import annotations

import fcntl
import os
import pty
import select
import struct
import subprocess
import termios
import time


def run_in_terminal(argv, *, cwd=None, env=None, timeout: float = 600.0, columns: int = 120):
    """(exit code, what the terminal received (bytes), stderr (text)) of `argv` run with stdout on a
    `columns`-wide pseudo-terminal (a pty starts 0 columns wide, where tqdm draws nothing)."""
    master, slave = pty.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 40, columns, 0, 0))
    proc = subprocess.Popen(argv, cwd=cwd, env=env, stdin=subprocess.DEVNULL, stdout=slave, stderr=subprocess.PIPE)
    os.close(slave)
    received, deadline = b"", time.monotonic() + timeout
    try:
        while time.monotonic() < deadline:
            ready, _, _ = select.select([master], [], [], 0.5)
            if ready:
                try:
                    chunk = os.read(master, 65536)
                except OSError:  # the terminal's other end closed: the command is done
                    break
                if not chunk:
                    break
                received += chunk
            elif proc.poll() is not None:
                break
        else:
            proc.kill()
        proc.wait(timeout=30)
    finally:
        os.close(master)
    return proc.returncode, received, proc.stderr.read().decode(errors="replace")


def lines_left(received: bytes) -> list[str]:
    """The lines a terminal shows at the end: each `\\r` returns to the line's start, so only what
    was written after the last one stays (an erased progress line leaves blanks)."""
    text = received.decode(errors="replace").replace("\r\n", "\n")
    return [line.rsplit("\r", 1)[-1].rstrip() for line in text.split("\n") if line.rsplit("\r", 1)[-1].strip()]
