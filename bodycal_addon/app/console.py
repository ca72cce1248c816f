"""Where a command's lines go (FORMATS.md §4): stdout carries BodyCal's own log, stderr its errors
and warnings, one line each; what Blender and its importers print while the command runs (the glTF
importer's `INFO:` lines, the BVH reader's, Blender's `Info: Saved copy as ...` reports, its
complaints about a file's drivers) goes to neither, unless `--verbose` sends it to stdout.

A long command shows one updating progress line (`progress`, drawn by tqdm, a wheel the extension
bundles) on stdout when stdout is a terminal, and nothing when it is not (a pipe, a file, a farm's
log); BodyCal's lines are printed above it."""

from __future__ import annotations

import contextlib
import ctypes
import io
import os
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field

from ..blender.process import stderr_to_stdout
from ..core.paths import ROOT_DIR


def _load_tqdm():
    """tqdm: installed (the extension's wheel, or requirements-dev.txt), else straight from the wheel
    the extension bundles (a checkout run by a Python without it: pure Python imports from the
    zip), else None (no progress line)."""
    try:
        from tqdm import tqdm as bar
    except ImportError:
        wheel = next(iter(sorted((ROOT_DIR / "wheels").glob("tqdm-*-py3-none-any.whl"))), None)
        if wheel is None:
            return None
        sys.path.append(str(wheel))
        try:
            from tqdm import tqdm as bar
        except ImportError:
            return None
    return bar


tqdm = _load_tqdm()


@dataclass
class _Streams:
    out: object | None = None  # None: sys.stdout / sys.stderr at the time of the call
    err: object | None = None
    status_open: bool = False  # a status line is on the terminal without its newline yet
    owned: bool = False  # inside own_lines_only, not verbose: nothing else writes to the terminal
    bars: list = field(default_factory=list)  # the progress lines on screen now


_streams = _Streams()


def stderr():
    """Where BodyCal's own error and warning lines go now."""
    return _streams.err or sys.stderr


def _print(line: str, stream) -> None:
    """`line` on `stream`, the progress line (if any) stepping aside for it and coming back below."""
    if _streams.bars:
        with tqdm.external_write_mode(file=_streams.out):
            print(line, file=stream, flush=True)
    else:
        print(line, file=stream, flush=True)


def say(line: str) -> None:
    """One line of the command's log, on stdout."""
    out = _streams.out or sys.stdout
    _end_status(out)
    _print(line, out)


def status(line: str) -> None:
    """A progress line (`bodycal record`, `bodycal stream`): on a terminal it replaces the previous
    one in place; elsewhere (a pipe, a log file) it is one more line of the log."""
    out = _streams.out or sys.stdout
    if not _is_terminal(out):
        print(line, file=out, flush=True)
        return
    print(f"\r{line}\033[K", end="", file=out, flush=True)
    _streams.status_open = True


def _end_status(out) -> None:
    if _streams.status_open:
        print(file=out, flush=True)
        _streams.status_open = False


def warn(command: str, line: str) -> None:
    """One `bodycal <command>: warning: ...` line on stderr."""
    _end_status(_streams.out or sys.stdout)
    _print(f"bodycal {command}: warning: {line}", _streams.err or sys.stderr)


def error(prog: str, line: str) -> None:
    """One `<prog>: error: ...` line on stderr (prog: `bodycal` or `bodycal <command>`)."""
    _end_status(_streams.out or sys.stdout)
    _print(f"{prog}: error: {line}", _streams.err or sys.stderr)


def _is_terminal(stream) -> bool:
    try:
        return bool(stream.isatty())
    except (AttributeError, ValueError, OSError):
        return False


STEPS = 1000  # the progress line's resolution


@contextlib.contextmanager
def progress(command: str) -> Iterator[Callable[[str, float], None]]:
    """For the block, `step(stage, fraction)` updates one progress line on stdout (`bodycal
    <command>: <stage>  42%|####      | 0:12<0:16`), when the command owns the terminal's stdout
    (`own_lines_only`, not verbose: Blender's own output would break the line) and it is a
    terminal; otherwise `step` does nothing. The line is erased when the block ends."""
    out = _streams.out
    if tqdm is None or not _streams.owned or not _is_terminal(out):
        yield lambda stage, fraction: None
        return
    bar = tqdm(total=STEPS, file=out, leave=False, dynamic_ncols=True, desc=f"bodycal {command}",
               bar_format="{desc}  {percentage:3.0f}%|{bar}| {elapsed}<{remaining}")
    _streams.bars.append(bar)

    def step(stage: str, fraction: float) -> None:
        desc = f"bodycal {command}: {stage}"
        if desc != bar.desc:  # a new stage is shown at once; the fraction at tqdm's pace
            bar.set_description_str(desc)
        bar.update(max(0, min(STEPS, round(fraction * STEPS))) - bar.n)

    try:
        yield step
    finally:
        _streams.bars.remove(bar)
        bar.close()


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
        _streams.owned = True
        sys.stdout = sys.stderr = sink
        yield
    finally:
        _flush_c_streams()  # what Blender printed with C's stdio, before the descriptors are restored
        sys.stdout, sys.stderr = out, err
        _streams.out = _streams.err = None
        _streams.owned = False
        for own in opened:
            own.close()
        for fd, dup in saved.items():
            os.dup2(dup, fd)
            os.close(dup)
        sink.close()
