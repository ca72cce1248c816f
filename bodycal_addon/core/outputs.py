"""Where the commands write: the output path is checked before any work, and written beside the
target then renamed over it only once complete, so nothing the user has is ever lost.

Refused, with one line naming the path and what to do: an output that is one of the inputs (also
through another spelling of the path, a hard link, or a CSV's sidecar JSON), a symbolic link
(replacing it would turn the link into a file and leave its target stale), anything but a regular
file (a folder, `/dev/null`, a device), a folder that cannot be written, and an existing file
unless replacing it was asked for. No numpy and no bpy: the engine and the Blender side share it.
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
import stat
import unicodedata
from collections.abc import Iterable, Iterator
from pathlib import Path

from .errors import BodyCalError


def recording_inputs(recording_path) -> list[tuple[str, Path]]:
    """Every file a recording is read from, named for `check_output`'s message: a CSV's sidecar
    (`take.csv` -> `take.json`) counts even when absent, since writing it would change how the
    CSV is read next time."""
    path = Path(recording_path)
    if path.suffix.lower() == ".csv":
        return [("the recording", path), ("the recording's sidecar JSON", path.with_suffix(".json"))]
    return [("the recording", path)]


def _same_file(a: Path, b: Path) -> bool:
    if a.resolve() == b.resolve():
        return True
    try:
        return os.path.samefile(a, b)  # hard links, case-insensitive file systems
    except OSError:  # one of them does not exist: then they cannot be the same file
        return False


def _nearest_existing_folder(path: Path, field: str) -> Path:
    folder = path.absolute().parent
    while not folder.exists():
        if folder.is_symlink():  # a dangling link where a folder should be
            raise BodyCalError(f"its folder {folder} is a broken symbolic link", source=str(path), field=field,
                               hint="choose another output path")
        folder = folder.parent
    if not folder.is_dir():
        raise BodyCalError(f"{folder} is not a folder", source=str(path), field=field,
                           hint="choose another output path")
    return folder


def _probe_writable(folder: Path, path: Path, field: str) -> None:
    """Create and remove a file in `folder`: the only honest test (root passes os.access
    everywhere, yet cannot create files under /proc or on a read-only mount)."""
    try:
        fd, probe = _temp_beside(folder / path.name)
        os.close(fd)
        os.unlink(probe)
    except OSError as exc:
        raise BodyCalError(f"cannot write in {folder} ({exc.strerror or exc})", source=str(path), field=field,
                           hint="choose a folder you can write to") from None


def check_output(path, *, inputs: Iterable[tuple[str, object]] = (), overwrite: bool = False,
                 field: str = "-o") -> Path:
    """Refuse, before any work, an output that would destroy something; `inputs` are
    (what, path) pairs such as ("the recording", REC). Returns the path to write."""
    path = Path(path)
    if path.is_symlink():
        raise BodyCalError("is a symbolic link; writing would replace the link with a file", source=str(path),
                           field=field, hint="give the file's own path or another path")
    for what, input_path in inputs:
        if input_path is not None and _same_file(path, Path(input_path)):
            raise BodyCalError(f"is {what}, an input of this command", source=str(path), field=field,
                               hint="choose another output path")
    if path.exists():
        mode = os.stat(path).st_mode
        if stat.S_ISDIR(mode):
            raise BodyCalError("is a folder", source=str(path), field=field,
                               hint=f"give a file name inside it, e.g. {path / 'out'}")
        if not stat.S_ISREG(mode):
            raise BodyCalError("is not a regular file (a device, pipe or socket)", source=str(path), field=field,
                               hint="give a path to a file")
        if not overwrite:
            raise BodyCalError("already exists", source=str(path), field=field,
                               hint="pass --overwrite to replace it, or choose another path")
    _probe_writable(_nearest_existing_folder(path, field), path, field)
    return path


def _temp_beside(path: Path) -> tuple[int, str]:
    """A new, hidden, uniquely named file in the target's folder (the same file system, so the
    final rename is atomic); it keeps the target's suffix for programs that look at it (Blender)."""
    return _create_exclusive(path.parent / f".{path.name}.{secrets.token_hex(4)}.tmp{path.suffix}")


def _create_exclusive(candidate: Path) -> tuple[int, str]:
    fd = os.open(candidate, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    return fd, str(candidate)


@contextlib.contextmanager
def replacing(path, *, inputs: Iterable[tuple[str, object]] = (), overwrite: bool = True,
              field: str = "-o") -> Iterator[Path]:
    """`with replacing(out) as tmp: write tmp` - the checks again (the path may have changed since
    the command started), then the content goes to `tmp` beside `out` and is renamed over `out`
    only if the block succeeds; `tmp` (and anything a writer left next to it) never survives."""
    path = check_output(path, inputs=inputs, overwrite=overwrite, field=field)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp_name = _temp_beside(path)
    except OSError as exc:
        raise BodyCalError(f"cannot write ({exc.strerror or exc})", source=str(path), field=field,
                           hint="choose a folder you can write to") from None
    os.close(fd)
    tmp = Path(tmp_name)
    # The replaced file's permissions, or those a plainly created file would get (not the temp's 0600).
    mode = stat.S_IMODE(os.stat(path).st_mode) if path.exists() else 0o666 & ~_umask()
    try:
        yield tmp
        if not tmp.is_file() or tmp.is_symlink():
            raise BodyCalError("the writer produced no file", source=str(path), field=field)
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    except OSError as exc:
        raise BodyCalError(f"cannot write ({exc.strerror or exc})", source=str(path), field=field,
                           hint="check the disk space and the folder's permissions") from None
    finally:
        for leftover in (tmp, Path(f"{tmp}@"), Path(f"{tmp}1")):  # Blender writes `name@`, backs up to `name1`
            with contextlib.suppress(OSError):
                leftover.unlink()


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def write_text(path, text: str, **checks) -> Path:
    """Write `text` to `path` as UTF-8 (JSON's encoding, whatever the locale) through `replacing`
    (same keyword arguments)."""
    with replacing(path, **checks) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def describe_os_error(exc: OSError, *, advice: bool = True) -> str:
    """One line for an OSError nothing more specific caught: the path, what failed and (`advice`)
    what to do. The sidebar's status bar leaves the advice out (operators/reporting.py)."""
    where = f"{exc.filename}: " if exc.filename else ""
    text = f"{where}{exc.strerror or exc}"
    return f"{text}; check the path exists and that you may read or write it" if advice else text


_UNSAFE = re.compile(r"[^\w.+-]")  # \w: letters and digits of any script, and _
PART_BYTES = 64


def safe_part(text: str) -> str:
    """One part of an output file name: no path separator, no `..`, no control or other special
    character, at most PART_BYTES bytes of UTF-8, never empty (app/batch/jobs.py's docstring, "Output names")."""
    s = _UNSAFE.sub("_", unicodedata.normalize("NFC", text))
    s = re.sub(r"\.{2,}", "_", s)
    s = re.sub(r"_{2,}", "_", s).lstrip(".-")
    s = s.encode("utf-8")[:PART_BYTES].decode("utf-8", errors="ignore").rstrip(".")
    return s or "unnamed"
