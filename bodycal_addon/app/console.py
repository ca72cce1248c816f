"""Where a command's lines go (FORMATS.md §4): stdout carries BodyCal's own log, stderr its errors
and warnings, one line each; what Blender and its importers print while the command runs (the glTF
importer's `INFO:` lines, the BVH reader's, Blender's `Info: Saved copy as ...` reports, its
complaints about a file's drivers) goes to neither, unless `--verbose` sends it to stdout."""

from __future__ import annotations

import contextlib
import ctypes
import io
import os
import sys
from dataclasses import dataclass

from ..blender.process import stderr_to_stdout


@dataclass
class _Streams:
    out: object | None = None  # None: sys.stdout / sys.stderr at the time of the call
    err: object | None = None
    status_open: bool = False  # a status line is on the terminal without its newline yet


_streams = _Streams()


def stderr():
    """Where BodyCal's own error and warning lines go now."""
    return _streams.err or sys.stderr


def say(line: str) -> None:
    """One line of the command's log, on stdout."""
    out = _streams.out or sys.stdout
    _end_status(out)
    print(line, file=out, flush=True)


def status(line: str) -> None:
    """A progress line (`bodycal record`, `bodycal stream`): on a terminal it replaces the previous
    one in place; elsewhere (a pipe, a log file) it is one more line of the log."""
    out = _streams.out or sys.stdout
    if not _isatty(out):
        print(line, file=out, flush=True)
        return
    print(f"\r{line}\033[K", end="", file=out, flush=True)
    _streams.status_open = True


def _end_status(out) -> None:
    if _streams.status_open:
        print(file=out, flush=True)
        _streams.status_open = False


def _isatty(stream) -> bool:
    try:
        return stream.isatty()
    except (AttributeError, ValueError):
        return False


def warn(command: str, line: str) -> None:
    """One `bodycal <command>: warning: ...` line on stderr."""
    _end_status(_streams.out or sys.stdout)
    print(f"bodycal {command}: warning: {line}", file=_streams.err or sys.stderr, flush=True)


def error(prog: str, line: str) -> None:
    """One `<prog>: error: ...` line on stderr (prog: `bodycal` or `bodycal <command>`)."""
    _end_status(_streams.out or sys.stdout)
    print(f"{prog}: error: {line}", file=_streams.err or sys.stderr, flush=True)


def _flush_c_streams() -> None:
    """`fflush(NULL)`: C's buffered stdout (a pipe or a file is fully buffered) would otherwise be
    written after the descriptors are restored, onto BodyCal's stdout."""
    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError, TypeError):  # no C library to load by that name (Windows)
        pass


def _fileno(stream) -> int | None:
    try:
        return stream.fileno()
    except (AttributeError, ValueError, io.UnsupportedOperation):
        return None


@contextlib.contextmanager
def own_lines_only(verbose: bool = False):
    """For the block, BodyCal's lines (`say`, `warn`, `error`) go to the stdout and stderr the
    process had, and everything else printed (by Python's `print` or by Blender's C code, to file
    descriptors 1 and 2) is dropped. `verbose`: Blender's output goes to stdout, as Blender prints
    it, and stderr still carries BodyCal's lines only (process.stderr_to_stdout)."""
    if verbose:
        with stderr_to_stdout(python_stderr=False):
            yield
        return
    out, err = sys.stdout, sys.stderr
    for stream in (out, err):
        with contextlib.suppress(AttributeError, ValueError):
            stream.flush()
    saved, opened = {}, []
    sink = open(os.devnull, "w")  # noqa: SIM115 - closed in finally
    try:
        streams = {}
        for fd, stream in ((1, out), (2, err)):
            saved[fd] = os.dup(fd)
            if _fileno(stream) == fd:  # the process's own stream: keep writing to where it went
                own = open(os.dup(saved[fd]), "w", buffering=1, encoding=getattr(stream, "encoding", None) or "utf-8",
                           errors="backslashreplace")
                opened.append(own)
                streams[fd] = own
            else:  # a stream in Python only (a test capturing it)
                streams[fd] = stream
            os.dup2(sink.fileno(), fd)
        _streams.out, _streams.err = streams[1], streams[2]
        sys.stdout = sys.stderr = sink
        yield
    finally:
        _flush_c_streams()  # what Blender printed with C's stdio, before the descriptors are restored
        sys.stdout, sys.stderr = out, err
        _streams.out = _streams.err = None
        for own in opened:
            own.close()
        for fd, dup in saved.items():
            os.dup2(dup, fd)
            os.close(dup)
        sink.close()
