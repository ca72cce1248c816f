"""`bodycal batch JOBS.toml`: many recordings x avatars, in parallel worker processes.

Each job is one self-contained `retarget` command line (the same one a person would type), so the
same jobs run unchanged on a render farm that runs `blender -b` commands (see README, "Batch jobs
and render farms"). A failed job is reported and the others finish.

JOBS.toml:

    [defaults]                  # optional
    method = "egocentric"       # or a list: ["egocentric", "rotations"]
    output_dir = "out/batch"    # relative to the JOBS.toml folder
    workers = 2                 # parallel worker processes, 1..1024 (default: CPU count)
    runner = "python"           # or "blender": `blender -b -c bodycal ...` (needs the extension installed)
    filter = "3,5"              # optional: One Euro filter on the devices (true = default parameters)
    plant_feet = true           # optional: false lets the feet follow the method
    placement = "object"        # optional: "performer" plays each avatar where the performer was
    root_motion = "root"        # optional: "pelvis" or "in-place" (as retarget --root-motion)
    rigify_target = "fk"        # optional: "def" keys a generated Rigify rig's DEF- bones (retarget --rigify-target)
    overwrite = false           # optional: true replaces outputs a previous run left (else those jobs fail)
    tolerance = 0.1             # optional: key reduction, degrees (as retarget --tolerance; 0 keys every sample)
    interpolation = "linear"    # optional: "bezier" keys (as retarget --interpolation)
    fps = 30                    # optional: output frame rate (as retarget --fps; default the recording's)
    export = ["blend", "fbx"]   # optional: the files each job writes (blend, fbx, glb, gltf, bvh)
    timeout = 600               # optional: seconds a job may run before it is ended and failed

    [[recordings]]
    path = "takes/take1.bcrec.json"
    user = "takes/performer.body.json"

    [[animations]]              # optional: characters' actions, transferred (`bodycal transfer`)
    path = "clips/walk.bvh"     # .blend, .bvh, .fbx, .glb or .gltf
    source_armature = "Walker"  # optional
    action = "Walk"             # optional (default: the armature's active action)

    [[avatars]]
    file = "avatars/ogre.blend" # or .fbx, .glb, .gltf, .vrm (`blend = ...` reads too)
    armature = "Ogre"           # optional
    bone_map = "avatars/ogre.bonemap.json"  # optional: a bone map preset (retarget --bone-map)

Every recording is retargeted onto every avatar with every method, and every animation source
transferred onto every avatar with every method transfer has (egocentric, rotations). Paths are
relative to the JOBS.toml folder. Every field is checked before any job starts (its type and allowed values; an
unknown key, a repeated entry or method, a control character in a string are errors); a bad one
is one line naming the file and the field.

Output names (docs/FORMATS.md §4.1): `<output_dir>/<recording>__<avatar>__<method>.blend`, where
<recording> is the recording's file name up to its first dot and <avatar> the armature name, else
the avatar file's name up to its first dot. Each part is made a safe file name: every character
other than a letter, digit, `.`, `+`, `-` or `_` becomes `_`, runs of `_` become one, `..` becomes
`_`, leading dots and dashes are dropped, and it is cut to 64 UTF-8 bytes (empty: `unnamed`). When
two jobs would get the same name (letter case ignored), those jobs' recording part becomes
`<recording folder>-<recording>`; any still clashing get `__<8 hex digits>` appended: the start of
the SHA-256 of `json.dumps([recording, user, avatar, armature or None, method])` with absolute,
normalised paths. The names depend only on the jobs file and where it is, and every output is
directly inside output_dir.

Stopping: on SIGINT (Ctrl-C) or SIGTERM no new job starts, running workers are sent SIGTERM and,
after GRACE_SECONDS, SIGKILL (a second signal kills at once); the summary lists what finished and
what was cancelled (status "cancelled"), and `bodycal batch` exits 130 (SIGINT) or 143 (SIGTERM).
A worker that fails or is ended can leave Blender's temporary save file `<output>@`; it is removed
and said in that job's error line. One left by an earlier killed batch is removed before the jobs
start and listed in the summary (`removed_stale`).

A job that runs longer than `timeout` seconds is ended (SIGKILL) and failed. On Linux every job
process is tied to the process that started it (PR_SET_PDEATHSIG): a batch or a cluster worker
that is killed outright takes its running jobs with it, so none is left writing an output that a
retry writes again. The same jobs run on a Dask cluster through `app/cluster.py`, and are
exported for farms by `app/openjd.py` and `app/flamenco.py` (docs/FARM.md).
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import tomllib
from collections import defaultdict, deque
from dataclasses import dataclass, replace
from glob import escape as glob_escape
from pathlib import Path

from ..body.bone_presets import load_preset
from ..core.errors import BodyCalError
from ..core.outputs import safe_part
from ..core.paths import ANIMATION_SUFFIXES, AVATAR_SUFFIXES, ROOT_DIR
from ..output.keyreduce import INTERPOLATIONS
from ..output.rigify import RIGIFY_TARGETS
from ..output.root_motion import ROOT_MOTIONS
from ..recording.filters import OneEuro
from ..retarget.methods import methods_for
from ..retarget.placement import PLACEMENTS

METHODS = methods_for("recording")  # every method, the default first (retarget/methods.py)
TRANSFER_METHODS = methods_for("animation")


RUNNERS = ("python", "blender")
MAX_WORKERS = 1024
MAX_TIMEOUT = 7 * 24 * 3600.0  # a week: anything longer is a typo for "no timeout" (leave the key out)
GRACE_SECONDS = 3.0  # between SIGTERM and SIGKILL for a running worker when the batch is stopped
EXIT_ON_SIGNAL = {signal.SIGINT: 130, signal.SIGTERM: 143}  # 128 + signal number, as shells do

_KEYS = {
    "": ("defaults", "recordings", "animations", "avatars"),
    "defaults": ("method", "output_dir", "workers", "runner", "filter", "plant_feet", "placement", "overwrite",
                 "tolerance", "fps", "export", "root_motion", "rigify_target", "interpolation", "timeout"),
    "recordings": ("path", "user"),
    "animations": ("path", "source_armature", "action"),
    "avatars": ("file", "blend", "armature", "bone_map"),
}
_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")
EXPORT_FORMATS = ("blend", "fbx", "glb", "gltf", "bvh")


@dataclass
class Job:
    name: str
    recording: Path  # the recording, or the animation source of a transfer job
    user: Path | None  # None: a transfer job (`bodycal transfer`)
    avatar: Path
    armature: str | None
    method: str
    output: Path
    filter: str | None = None
    plant_feet: bool = True
    overwrite: bool = False
    placement: str = "object"
    tolerance: float | None = None
    fps: float | None = None
    exports: tuple[Path, ...] = ()  # further outputs beside `output` (other formats)
    bone_map: Path | None = None
    source_armature: str | None = None  # transfer jobs
    action: str | None = None
    root_motion: str = "root"
    rigify_target: str = "fk"
    interpolation: str = "linear"
    timeout: float | None = None  # seconds the job may run (defaults.timeout); the runner enforces it
    review: bool = False  # `--review`: the job also writes its review (FORMATS.md §4.5)

    @property
    def outputs(self) -> list[Path]:
        return [self.output, *self.exports]

    @property
    def review_files(self) -> list[Path]:
        """The review's sheet and record beside the first output (`retarget --review`)."""
        if not self.review:
            return []
        base = self.output.with_suffix("").name
        return [self.output.with_name(f"{base}.review.png"), self.output.with_name(f"{base}.review.json")]

    def argv(self) -> list[str]:
        if self.user is None:
            args = ["transfer", str(self.recording), "--avatar", str(self.avatar), "--method", self.method]
            if self.source_armature:
                args += ["--source-armature", self.source_armature]
            if self.action:
                args += ["--action", self.action]
        else:
            args = ["retarget", str(self.recording), "--user", str(self.user), "--avatar", str(self.avatar),
                    "--method", self.method]
        for out in self.outputs:
            args += ["-o", str(out)]
        if self.tolerance is not None:
            args += ["--tolerance", repr(float(self.tolerance))]
        if self.fps is not None:
            args += ["--fps", repr(float(self.fps))]
        if self.armature:
            args += ["--armature", self.armature]
        if self.bone_map is not None:
            args += ["--bone-map", str(self.bone_map)]
        if self.user is not None and self.filter != "on":  # tracker smoothing (recordings): "on" is the default
            args += ["--filter", self.filter] if self.filter is not None else ["--no-filter"]
        if not self.plant_feet:
            args += ["--no-plant-feet"]
        if self.placement != "object":
            args += ["--placement", self.placement]
        if self.root_motion != "root":
            args += ["--root-motion", self.root_motion]
        if self.rigify_target != "fk":
            args += ["--rigify-target", self.rigify_target]
        if self.interpolation != "linear":
            args += ["--interpolation", self.interpolation]
        if self.overwrite:
            args += ["--overwrite"]
        if self.review:
            args += ["--review"]
        return args

    def leftovers(self) -> list[Path]:
        """What a worker ended while writing can leave beside its outputs: `<output>@`, and the
        hidden temporary `.<output name>.<hex>.tmp<suffix>` the command writes first (outputs.py),
        with Blender's `@` beside it."""
        found = []
        for out in [*self.outputs, *self.review_files]:
            found += [p for p in (out.with_name(out.name + "@"),) if p.exists()]
            found += sorted(out.parent.glob(f".{glob_escape(out.name)}.*.tmp{glob_escape(out.suffix)}*"))
        return found


# ---- the jobs file --------------------------------------------------------------------------------

def _describe(value) -> str:
    """A short, safe description of a value for an error line (never the repr of a deep structure)."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        text = value if len(value) <= 40 else value[:37] + "..."
        return json.dumps(text)
    if isinstance(value, dict):
        return "a table"
    if isinstance(value, list):
        return "a list" if value else "an empty list"
    return f"a {type(value).__name__}"


class _Checker:
    def __init__(self, path: Path):
        self.source = str(path)

    def error(self, field: str | None, message: str) -> BodyCalError:
        return BodyCalError(message, source=self.source, field=field)

    def table(self, value, field: str, keys: tuple[str, ...], what: str) -> dict:
        if not isinstance(value, dict):
            raise self.error(field, f"must be {what}, got {_describe(value)}")
        for key in value:
            if key not in keys:
                raise self.error(field, f"unknown key {_describe(key)}; allowed: {', '.join(keys)}")
        return value

    def text(self, value, field: str, what: str) -> str:
        if not isinstance(value, str) or not value.strip():
            raise self.error(field, f"must be {what} (a non-empty string), got {_describe(value)}")
        if _CONTROL.search(value):
            raise self.error(field, "contains a control character (such as a newline or NUL); remove it")
        return value


def _parse(path: Path) -> dict:
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as exc:
        raise BodyCalError(f"cannot read: {exc.strerror or exc}", source=str(path)) from None
    except UnicodeDecodeError:
        raise BodyCalError("not valid TOML (not UTF-8 text)", source=str(path)) from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise BodyCalError(f"not valid TOML ({exc})", source=str(path)) from None
    except RecursionError:
        raise BodyCalError("not valid TOML (nested too deeply); a jobs file needs only tables of strings, "
                           "numbers and lists", source=str(path)) from None


def _choices(check: _Checker, value, field: str, noun: str, allowed: tuple[str, ...]) -> list[str]:
    """One of `allowed` or a non-empty list of them, each once (`method`, `export`)."""
    names = ", ".join(allowed)
    chosen = [value] if isinstance(value, str) else value
    if not isinstance(chosen, list) or not chosen:
        raise check.error(field, f"must be a {noun} or a non-empty list of {noun}s ({names}), "
                                 f"got {_describe(value)}")
    for c in chosen:
        if c not in allowed:
            raise check.error(field, f"unknown {noun} {_describe(c)}; use one of {names}")
    if len(set(chosen)) != len(chosen):
        raise check.error(field, f"lists a {noun} twice; list each once")
    return chosen


def _workers(check: _Checker, value) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= MAX_WORKERS:
        raise check.error("defaults.workers", f"must be a whole number from 1 to {MAX_WORKERS} "
                                              f"(parallel worker processes), got {_describe(value)}")
    return value


def _runner(check: _Checker, value) -> str:
    if value not in RUNNERS:
        raise check.error("defaults.runner", f"must be \"python\" or \"blender\", got {_describe(value)}")
    if value == "blender" and shutil.which("blender") is None:
        raise check.error("defaults.runner", "\"blender\" needs the blender program on the PATH; put it there "
                                             "or use runner = \"python\"")
    return value


def _filter(check: _Checker, value) -> str | None:
    what = "true, false or \"MIN_CUTOFF,BETA[,ROT_MIN,ROT_BETA]\" (as retarget --filter)"
    if value is True:
        return "on"
    if value is False:
        return None
    if not isinstance(value, str):
        raise check.error("defaults.filter", f"must be {what}, got {_describe(value)}")

    try:
        OneEuro.parse(value)  # a bad value is reported here, before any job starts
    except BodyCalError as exc:
        raise check.error("defaults.filter", f"{exc.message}; use {what}") from None
    return value


def _number(check: _Checker, value, field: str, low: float, high: float, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not low <= value <= high:
        raise check.error(field, f"must be a number from {low:g} to {high:g} ({what}), got {_describe(value)}")
    return float(value)


def _entries(check: _Checker, data: dict, key: str) -> list[dict]:
    what = {"recordings": "[[recordings]] tables with path and user",
            "animations": "[[animations]] tables with path (and optionally source_armature and action)",
            "avatars": "[[avatars]] tables with file (and optionally armature and bone_map)"}[key]
    entries = data.get(key, [])
    if not isinstance(entries, list):
        raise check.error(key, f"must be {what}, got {_describe(entries)}")
    return [check.table(e, f"{key}[{i}]", _KEYS[key], f"a table ({what})") for i, e in enumerate(entries)]


def _bone_map(check: _Checker, base: Path, avatar: dict, j: int) -> Path | None:
    """An avatar's bone map preset, read and checked now (the bones it names are checked by the
    job, against the armature in the .blend)."""
    if "bone_map" not in avatar:
        return None
    field = f"avatars[{j}].bone_map"
    path = base / check.text(avatar["bone_map"], field, "a bone map preset file")
    try:
        load_preset(path)
    except BodyCalError as exc:
        raise check.error(field, exc.line()) from None
    return path


def _abs(path: Path) -> str:
    return os.path.normpath(os.path.abspath(path))


@dataclass
class _Defaults:
    """The `[defaults]` table, checked: what every job of the file shares."""
    methods: list[str]
    out_dir: Path
    workers: int
    filter: str | None
    plant_feet: bool
    overwrite: bool
    tolerance: float | None
    fps: float | None
    formats: list[str]
    placement: str
    rig_options: dict[str, str]  # root_motion, rigify_target and interpolation, as Job takes them
    runner: str
    timeout: float | None


def _flag(check: _Checker, defaults: dict, key: str, default: bool) -> bool:
    value = defaults.get(key, default)
    if not isinstance(value, bool):
        raise check.error(f"defaults.{key}", f"must be true or false, got {_describe(value)}")
    return value


def _one_of(check: _Checker, defaults: dict, key: str, allowed: tuple[str, ...]) -> str:
    """A setting with a few named values, the first the default (placement, root_motion, ...)."""
    value = defaults.get(key, allowed[0])
    if value not in allowed:
        raise check.error(f"defaults.{key}", f"must be {' or '.join(json.dumps(p) for p in allowed)}, "
                                             f"got {_describe(value)}")
    return value


def _read_defaults(check: _Checker, data: dict, base: Path) -> _Defaults:
    """Reads the document's `[defaults]` (every key optional) and checks each value, in the order
    the fields are listed here, so that the first bad one is the one reported. Paths are resolved
    against `base`, the jobs file's folder."""
    defaults = check.table(data.get("defaults", {}), "defaults", _KEYS["defaults"], "a table ([defaults])")
    methods = _choices(check, defaults.get("method", "egocentric"), "defaults.method", "method", METHODS)
    out_dir = base / check.text(defaults.get("output_dir", "out/batch"), "defaults.output_dir", "a folder")
    workers = _workers(check, defaults.get("workers", os.cpu_count() or 1))
    filt = _filter(check, defaults.get("filter", True))
    plant = _flag(check, defaults, "plant_feet", True)
    overwrite = _flag(check, defaults, "overwrite", False)
    tolerance = (_number(check, defaults["tolerance"], "defaults.tolerance", 0.0, 180.0, "degrees")
                 if "tolerance" in defaults else None)
    fps = (_number(check, defaults["fps"], "defaults.fps", 1.0, 1000.0, "frames per second")
           if "fps" in defaults else None)
    formats = _choices(check, defaults.get("export", ["blend"]), "defaults.export", "format", EXPORT_FORMATS)
    placement = _one_of(check, defaults, "placement", PLACEMENTS)
    rig_options = {key: _one_of(check, defaults, key, allowed)
                   for key, allowed in (("root_motion", ROOT_MOTIONS), ("rigify_target", RIGIFY_TARGETS),
                                        ("interpolation", INTERPOLATIONS))}
    runner = _runner(check, defaults.get("runner", "python"))
    timeout = (_number(check, defaults["timeout"], "defaults.timeout", 1.0, MAX_TIMEOUT, "seconds a job may run")
               if "timeout" in defaults else None)
    return _Defaults(methods, out_dir, workers, filt, plant, overwrite, tolerance, fps, formats, placement,
                     rig_options, runner, timeout)


def _transfer_methods(check: _Checker, methods: list[str], recordings: list, animations: list,
                      avatars: list) -> list[str]:
    """Checks that the file has something to do (a source and an avatar) and, when it has
    animations, a method transfer has; returns those methods, in the file's order."""
    if not (recordings or animations) or not avatars:
        raise check.error(None, "needs at least one [[recordings]] or [[animations]] entry and one [[avatars]] entry")
    transfer_methods = [m for m in methods if m in TRANSFER_METHODS]
    if animations and not transfer_methods:
        raise check.error("defaults.method", f"animations transfer with {' or '.join(TRANSFER_METHODS)}, "
                                             f"not {' or '.join(methods)}")
    return transfer_methods


def _read_recordings(check: _Checker, base: Path, recordings: list[dict]) -> list[tuple[Path, Path]]:
    """The `[[recordings]]` tables as (recording, user model) paths; a missing key or the same pair
    twice is an error."""
    recs, seen = [], {}
    for i, rec in enumerate(recordings):
        if "path" not in rec or "user" not in rec:
            raise check.error(f"recordings[{i}]", f"missing '{'path' if 'path' not in rec else 'user'}'")
        rp = base / check.text(rec["path"], f"recordings[{i}].path", "a recording file")
        up = base / check.text(rec["user"], f"recordings[{i}].user", "a user body model file")
        identity = (_abs(rp), _abs(up))
        if identity in seen:
            raise check.error(f"recordings[{i}]", f"same path and user as recordings[{seen[identity]}]; remove one")
        seen[identity] = i
        recs.append((rp, up))
    return recs


def _read_animations(check: _Checker, base: Path, animations: list[dict]) -> list[tuple[Path, str | None, str | None]]:
    """The `[[animations]]` tables as (source file, source armature, action); a file `bodycal
    transfer` cannot read, or the same source twice, is an error."""
    anims, seen = [], {}
    for i, an in enumerate(animations):
        if "path" not in an:
            raise check.error(f"animations[{i}]", "missing 'path'")
        what = f"an animation source ({', '.join(ANIMATION_SUFFIXES)})"
        sp = base / check.text(an["path"], f"animations[{i}].path", what)
        if sp.suffix.lower() not in ANIMATION_SUFFIXES:
            raise check.error(f"animations[{i}].path", f"must be {what}, got {_describe(an['path'])}")
        sa, act = (check.text(an[k], f"animations[{i}].{k}", "a name") if k in an else None
                   for k in ("source_armature", "action"))
        identity = (_abs(sp), sa, act)
        if identity in seen:
            raise check.error(f"animations[{i}]", f"same path, armature and action as animations[{seen[identity]}]; "
                                                  "remove one")
        seen[identity] = i
        anims.append((sp, sa, act))
    return anims


def _read_avatars(check: _Checker, base: Path, avatars: list[dict]) -> list[tuple[Path, str | None, Path | None]]:
    """The `[[avatars]]` tables as (avatar file, armature, bone map preset); the preset is read now.
    A file the avatar import cannot read, or the same avatar twice, is an error."""
    avs, seen = [], {}
    for j, av in enumerate(avatars):
        keys = [k for k in ("file", "blend") if k in av]
        if len(keys) != 1:
            raise check.error(f"avatars[{j}]", "missing 'file'" if not keys else "has both 'file' and 'blend'; "
                                                                                 "keep 'file'")
        what = f"an avatar file ({', '.join(AVATAR_SUFFIXES)})"
        ap = base / check.text(av[keys[0]], f"avatars[{j}].{keys[0]}", what)
        if ap.suffix.lower() not in AVATAR_SUFFIXES:
            raise check.error(f"avatars[{j}].{keys[0]}", f"must be {what}, got {_describe(av[keys[0]])}")
        arm = check.text(av["armature"], f"avatars[{j}].armature", "an armature name") if "armature" in av else None
        identity = (_abs(ap), arm)
        if identity in seen:
            raise check.error(f"avatars[{j}]", f"same file and armature as avatars[{seen[identity]}]; remove one")
        seen[identity] = j
        avs.append((ap, arm, _bone_map(check, base, av, j)))
    return avs


def _make_jobs(check: _Checker, settings: _Defaults, transfer_methods: list[str], recs: list, anims: list,
               avs: list) -> list[Job]:
    """Every recording onto every avatar with every method, then every animation source with every
    transfer method; names them (`output_names`) and checks the outputs stay inside output_dir."""
    methods, out_dir, formats = settings.methods, settings.out_dir, settings.formats
    specs = [(rp, up, ap, arm, m) for rp, up in recs for ap, arm, _bm in avs for m in methods]
    extra = [(bm, None, None) for _rp, _up in recs for _ap, _arm, bm in avs for _m in methods]
    # Animation sources (DESIGN.md §8): transferred onto every avatar, with the methods transfer has;
    # the action's name is part of the source's identity (one file may hold several).
    specs += [(sp, None, ap, arm, m) for sp, _sa, _act in anims for ap, arm, _bm in avs for m in transfer_methods]
    extra += [(bm, sa, act) for _sp, sa, act in anims for _ap, _arm, bm in avs for _m in transfer_methods]
    names = output_names(specs, [act for _bm, _sa, act in extra])
    jobs = [Job(name, rp, up, ap, arm, m, out_dir / f"{name}.{formats[0]}", settings.filter, settings.plant_feet,
                settings.overwrite, settings.placement, settings.tolerance, settings.fps,
                tuple(out_dir / f"{name}.{f}" for f in formats[1:]), bm, sa, act, **settings.rig_options,
                timeout=settings.timeout)
            for name, (rp, up, ap, arm, m), (bm, sa, act) in zip(names, specs, extra)]
    # The naming rule guarantees both; checked because a wrong path here would lose a user's file.
    if any(job.output.parent != out_dir for job in jobs) or len({n.casefold() for n in names}) != len(names):
        raise check.error(None, "internal error: output names are not unique inside output_dir; please report it")
    return jobs


def load_jobs(path) -> tuple[list[Job], dict]:
    """The jobs of a JOBS.toml (module docstring), every field checked before any job starts, and
    the batch's settings (workers, runner, output_dir). Raises BodyCalError naming the first bad
    field."""
    path = Path(path)
    check = _Checker(path)
    data = _parse(path)
    check.table(data, None, _KEYS[""], "a TOML document")
    base = path.parent
    settings = _read_defaults(check, data, base)
    recordings, avatars = _entries(check, data, "recordings"), _entries(check, data, "avatars")
    animations = _entries(check, data, "animations")
    transfer_methods = _transfer_methods(check, settings.methods, recordings, animations, avatars)
    recs = _read_recordings(check, base, recordings)
    anims = _read_animations(check, base, animations)
    avs = _read_avatars(check, base, avatars)
    jobs = _make_jobs(check, settings, transfer_methods, recs, anims, avs)
    return jobs, {"workers": settings.workers, "runner": settings.runner, "output_dir": settings.out_dir,
                  "methods": settings.methods, "formats": settings.formats, "timeout": settings.timeout}


# ---- output names ----------------------------------------------------------------------------------

def _stem(path: Path) -> str:
    return path.name.split(".")[0]


def _hash(rp: Path, up: Path | None, ap: Path, arm: str | None, method: str, action: str | None = None) -> str:
    # An animation job (no user) hashes [source, null, avatar, armature, method, action].
    items = [_abs(rp), _abs(up) if up is not None else None, _abs(ap), arm, method]
    text = json.dumps(items if up is not None else [*items, action])  # ASCII: \uXXXX escapes
    return hashlib.sha256(text.encode("ascii")).hexdigest()[:8]


def output_names(specs: list[tuple[Path, Path | None, Path, str | None, str]], actions=None) -> list[str]:
    """Unique (letter case ignored) file-name stems for jobs given as (recording, user, avatar,
    armature, method); the rule is in the module docstring, "Output names". An animation job (user
    None) is named after its source, or `<source>-<action>` when it picks an action (`actions`)."""
    parts = []
    actions = actions or [None] * len(specs)
    for (rp, up, ap, arm, m), act in zip(specs, actions):
        rec = safe_part(_stem(rp) if not act else f"{_stem(rp)}-{act}")
        parts.append((rec, f"{safe_part(rp.parent.name)}-{rec}", safe_part(arm or _stem(ap)), m,
                      _hash(rp, up, ap, arm, m, act)))
    level = [0] * len(specs)

    def name(k: int) -> str:
        rec, rec_in_folder, avatar, method, digest = parts[k]
        text = f"{rec if level[k] == 0 else rec_in_folder}__{avatar}__{method}"
        return f"{text}__{digest}" if level[k] == 2 else text

    while True:
        groups = defaultdict(list)
        for k in range(len(specs)):
            groups[name(k).casefold()].append(k)
        clashes = [ks for ks in groups.values() if len(ks) > 1]
        if not clashes:
            return [name(k) for k in range(len(specs))]
        for ks in clashes:
            if all(level[k] == 2 for k in ks):  # same hash for different inputs: never seen, but never silent
                raise BodyCalError(f"two jobs get the same output name {name(ks[0])!r}; rename one input")
            for k in ks:
                level[k] = min(level[k] + 1, 2)


# ---- running ---------------------------------------------------------------------------------------

def command_line(job: Job, runner: str) -> list[str]:
    """The self-contained command for one job: what a farm worker runs. Evaluated where the job runs
    (a cluster worker calls it itself), so `sys.executable` is that machine's interpreter."""
    if runner == "blender":  # the extension must be installed and enabled in that Blender
        return ["blender", "-b", "-c", "bodycal", *job.argv()]
    return [sys.executable, "-m", "bodycal_addon", *job.argv()]


# Run before the job's own command (Linux): the job gets SIGKILL when the process that started it
# dies, then becomes that command (execvp keeps the pid and the death signal). A batch or a cluster
# worker killed outright so never leaves a bake running on behind it.
_TIED_TO_PARENT = (
    "import ctypes, os, sys\n"
    "ctypes.CDLL(None).prctl(1, 9)\n"  # PR_SET_PDEATHSIG, SIGKILL
    "os.getppid() == int(sys.argv[1]) or os._exit(137)\n"  # the parent died before prctl: end as if killed
    "os.execvp(sys.argv[2], sys.argv[2:])\n")


def _tied_to_parent(command: list[str]) -> list[str]:
    if not sys.platform.startswith("linux"):
        return command
    return [sys.executable, "-c", _TIED_TO_PARENT, str(os.getpid()), *command]


class Stop:
    """Signal handler: the first SIGINT/SIGTERM stops the batch, a second one kills at once."""

    def __init__(self):
        self.signum: int | None = None
        self.force = False

    def __call__(self, signum, _frame):
        if self.signum is None:
            self.signum = signum
        else:
            self.force = True

    def install(self) -> dict:
        previous = {}
        for sig in EXIT_ON_SIGNAL:
            try:
                previous[sig] = signal.signal(sig, self)
            except ValueError:  # not the main thread: Ctrl-C reaches the caller as KeyboardInterrupt
                pass
        return previous

    @staticmethod
    def restore(previous: dict):
        for sig, handler in previous.items():
            signal.signal(sig, handler)


@dataclass
class Running:
    job: Job
    proc: subprocess.Popen
    stderr: object
    t0: float
    timed_out: bool = False

    def overdue(self) -> bool:
        return self.job.timeout is not None and time.perf_counter() - self.t0 > self.job.timeout


def signal_name(signum: int) -> str:
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


def remove_partial(job: Job) -> list[str]:
    """Remove the job's leftovers; the names of those removed (one left in place, e.g. for lack of
    permission, is not said to be removed)."""
    removed = []
    for path in job.leftovers():
        try:
            path.unlink()
            removed.append(path.name)
        except OSError:
            pass
    return removed


def start_job(job: Job, command: list[str]) -> Running | dict:
    """Starts one job's command in its own process (never a fork of a process that loaded Blender);
    a result dict if it cannot start."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT_DIR), env.get("PYTHONPATH", "")) if p)
    err = tempfile.TemporaryFile()  # a file, not a pipe: a chatty worker can never block on it
    t0 = time.perf_counter()
    try:
        # Its own session (POSIX): the terminal's Ctrl-C reaches only the batch, which ends the
        # worker and everything it started (os.killpg).
        proc = subprocess.Popen(_tied_to_parent(command), stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                stderr=err, cwd=ROOT_DIR, env=env, start_new_session=os.name == "posix")
    except OSError as exc:
        err.close()
        return job_result(job, "failed", None, 0.0, f"cannot start the worker: {exc.strerror or exc}")
    return Running(job, proc, err, t0)


def signal_job(run: Running, sig: int):
    if run.proc.poll() is not None:
        return
    try:
        if os.name == "posix":
            os.killpg(run.proc.pid, sig)
        elif sig == signal.SIGTERM:
            run.proc.terminate()
        else:
            run.proc.kill()
    except (ProcessLookupError, PermissionError):
        pass


KILL = signal.SIGKILL if hasattr(signal, "SIGKILL") else signal.SIGTERM


def end_if_overdue(run: Running) -> bool:
    """Ends a job past its timeout (SIGKILL: a bake that overran gets no grace); True if it did."""
    if run.timed_out or not run.overdue():
        return False
    run.timed_out = True
    signal_job(run, KILL)
    return True


def job_result(job: Job, status: str, code: int | None, seconds: float, error: str | None) -> dict:
    return {"job": job.name, "status": status, "ok": status == "ok", "exit_code": code, "seconds": round(seconds, 2),
            "output": str(job.output) if status == "ok" else None,
            "outputs": [str(o) for o in job.outputs] if status == "ok" else [],
            "error": " ".join(error.split()) if error else None}


def finish_job(run: Running, stopped_by: str | None = None) -> dict:
    job, code = run.job, run.proc.wait()
    seconds = time.perf_counter() - run.t0
    run.stderr.seek(0)
    lines = [ln for ln in run.stderr.read().decode("utf-8", errors="replace").splitlines() if ln.strip()]
    run.stderr.close()
    removed = remove_partial(job)
    if code == 0 and not run.timed_out:
        error = f"removed a temporary save file {', '.join(removed)} the worker left" if removed else None
        return {**job_result(job, "ok", code, seconds, None), **({"note": error} if error else {})}
    if stopped_by:
        status, error = "cancelled", f"cancelled by {stopped_by} while running"
    else:
        status = "failed"
        if run.timed_out:
            error = f"timed out after {job.timeout:g} s (defaults.timeout) and was ended"
        elif code < 0:
            error = f"the worker was killed by {signal_name(-code)}"
        else:
            error = lines[-1] if lines else f"the worker ended with exit code {code}"
    if removed:
        error += f"; removed its partial save {', '.join(removed)}"
    return job_result(job, status, code, seconds, error)


def stop_running(running: list[Running], stop: Stop, grace: float):
    for run in running:
        signal_job(run, signal.SIGTERM)
    deadline = time.monotonic() + grace
    while any(r.proc.poll() is None for r in running) and time.monotonic() < deadline and not stop.force:
        time.sleep(0.05)
    for run in running:
        signal_job(run, KILL)


def prepare_batch(jobs_file, log=print, review: bool = False) -> tuple[list[Job], dict, list[str]]:
    """The checked jobs (each writing its review too with `review`), the settings, and the partial
    saves of an earlier killed batch, removed (said on `log`); the output folder is created."""
    jobs, settings = load_jobs(jobs_file)
    if review:
        jobs = [replace(job, review=True) for job in jobs]
    out_dir = Path(settings["output_dir"])
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise BodyCalError(f"cannot create the output folder {out_dir}: {exc.strerror or exc}", source=str(jobs_file),
                           field="defaults.output_dir") from None
    stale = [str(Path(job.output.parent, name)) for job in jobs for name in remove_partial(job)]
    for name in stale:
        log(f"removed {name}, a partial save left by an earlier batch that was killed")
    return jobs, settings, stale


def progress_line(r: dict, done: int, total: int) -> str:
    status = {"ok": "ok", "cancelled": r["error"]}.get(r["status"], f"FAILED: {r['error']}")
    where = f" on {r['worker']}" if r.get("worker") else ""
    return f"[{done}/{total}] {r['job']}: {status} ({r['seconds']} s{where})"


def write_summary(jobs: list[Job], settings: dict, results: list[dict], stop: Stop, stale: list[str],
                  **extra) -> dict:
    """`<output_dir>/summary.json` (docs/FORMATS.md §4.1), whole or absent; the summary, with
    `summary_file`."""
    results.sort(key=lambda r: r["job"])
    summary = {"jobs": len(jobs), "ok": sum(r["status"] == "ok" for r in results),
               "failed": sum(r["status"] == "failed" for r in results),
               "cancelled": sum(r["status"] == "cancelled" for r in results),
               "interrupted": signal_name(stop.signum) if stop.signum is not None else None,
               "removed_stale": stale, **extra, "results": results}
    summary_path = Path(settings["output_dir"]) / "summary.json"
    tmp = summary_path.with_name(summary_path.name + ".tmp")
    tmp.write_text(json.dumps(summary, indent=1))
    os.replace(tmp, summary_path)  # a summary is whole or absent, even if the batch is killed now
    summary["summary_file"] = str(summary_path)
    return summary


def _poll(running: list[Running], report):
    for run in running:
        end_if_overdue(run)
    for run in [r for r in running if r.proc.poll() is not None]:
        running.remove(run)
        report(finish_job(run))


def _run_all(jobs: list[Job], settings: dict, stop: Stop, report, grace: float):
    workers = max(1, min(settings["workers"], len(jobs)))
    pending, running = deque(jobs), []
    try:
        try:
            while (pending or running) and stop.signum is None:
                while pending and len(running) < workers and stop.signum is None:
                    job = pending.popleft()
                    started = start_job(job, command_line(job, settings["runner"]))
                    if isinstance(started, dict):
                        report(started)
                    else:
                        running.append(started)
                time.sleep(0.05)
                _poll(running, report)
        except KeyboardInterrupt:  # handlers could not be installed (not the main thread)
            stop.signum = signal.SIGINT
        if stop.signum is not None:
            name = signal_name(stop.signum)
            stop_running(running, stop, grace)
            for run in running:
                report(finish_job(run, stopped_by=name))
            for job in pending:
                report(job_result(job, "cancelled", None, 0.0, f"cancelled by {name} before it started"))
    finally:
        for run in running:  # only if something above raised: never leave a worker behind
            signal_job(run, KILL)


def job_progress(results: list[dict], total: int) -> tuple[str, float]:
    """(stage, fraction) of a batch's progress line: the jobs done, ok and failed."""
    failed = sum(r["status"] == "failed" for r in results)
    return (f"{len(results)}/{total} jobs" + (f", {failed} failed" if failed else ""),
            len(results) / max(total, 1))


def run_batch(jobs_file, log=print, *, grace: float = GRACE_SECONDS, progress=None, review: bool = False) -> dict:
    """Runs the jobs file's jobs in worker processes here (module docstring); `log` gets one line per
    finished job, `progress(stage, fraction)` how many are done; `review`: each job reviews its bake."""
    jobs, settings, stale = prepare_batch(jobs_file, log, review)
    results: list[dict] = []
    stop = Stop()
    previous = stop.install()
    step = progress or (lambda stage, fraction: None)
    step(*job_progress(results, len(jobs)))

    def report(r):
        results.append(r)
        log(progress_line(r, len(results), len(jobs)))
        step(*job_progress(results, len(jobs)))

    try:
        _run_all(jobs, settings, stop, report, grace)
    finally:
        Stop.restore(previous)
    return write_summary(jobs, settings, results, stop, stale)
