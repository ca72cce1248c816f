"""The batch's jobs file (`bodycal batch JOBS.toml`, docs/FORMATS.md §4.1): reading and checking it,
and expanding it into jobs, many recordings x avatars, each one self-contained `retarget` (or
`transfer`) command line, the same one a person would type. Running them is `runner.py`'s.

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
"""

from __future__ import annotations

import hashlib
import json
import os
import re
import shutil
import tomllib
from collections import defaultdict
from dataclasses import dataclass
from glob import escape as glob_escape
from pathlib import Path

from ...body.bone_presets import load_preset
from ...core.errors import BodyCalError
from ...core.outputs import safe_part
from ...core.paths import ANIMATION_SUFFIXES, AVATAR_SUFFIXES
from ...output.keyreduce import INTERPOLATIONS
from ...output.rigify import RIGIFY_TARGETS
from ...output.root_motion import ROOT_MOTIONS
from ...recording.filters import OneEuro
from ...retarget.methods import methods_for
from ...retarget.placement import PLACEMENTS

METHODS = methods_for("recording")  # every method, the default first (retarget/methods.py)
TRANSFER_METHODS = methods_for("animation")


RUNNERS = ("python", "blender")
MAX_WORKERS = 1024
MAX_TIMEOUT = 7 * 24 * 3600.0  # a week: anything longer is a typo for "no timeout" (leave the key out)

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

