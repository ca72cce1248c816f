"""`bodycal batch JOBS.toml`: many recordings x avatars, in parallel worker processes.

Each job is one self-contained `retarget` command line (the same one a person would type), so the
same jobs run unchanged on a render farm that runs `blender -b` commands (see README, "Batch jobs
on a render farm"). A failed job is reported and the others finish.

JOBS.toml:

    [defaults]                  # optional
    method = "egocentric"       # or a list: ["egocentric", "rotations"]
    output_dir = "out/batch"    # relative to the JOBS.toml folder
    workers = 2                 # parallel worker processes (default: CPU count)
    runner = "python"           # or "blender": `blender -b -c bodycal ...` (needs the extension installed)
    filter = "3,5"              # optional: One Euro filter on the devices (true = default parameters)
    plant_feet = true           # optional: false lets the feet follow the method

    [[recordings]]
    path = "takes/take1.bcrec.json"
    user = "takes/performer.body.json"

    [[avatars]]
    blend = "avatars/ogre.blend"
    armature = "Ogre"           # optional

Every recording is retargeted onto every avatar with every method. Paths are relative to the
JOBS.toml folder. Output: `<output_dir>/<recording>__<avatar>__<method>.blend`.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
import tomllib
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass
from pathlib import Path

from .errors import BodyCalError
from .paths import ROOT_DIR

METHODS = ("egocentric", "offsets", "rotations")


@dataclass
class Job:
    name: str
    recording: Path
    user: Path
    avatar: Path
    armature: str | None
    method: str
    output: Path
    filter: str | None = None
    plant_feet: bool = True

    def argv(self) -> list[str]:
        args = ["retarget", str(self.recording), "--user", str(self.user), "--avatar", str(self.avatar),
                "--method", self.method, "-o", str(self.output)]
        if self.armature:
            args += ["--armature", self.armature]
        if self.filter is not None:
            args += ["--filter", self.filter]
        if not self.plant_feet:
            args += ["--no-plant-feet"]
        return args


def _stem(path: Path) -> str:
    return path.name.split(".")[0]


def load_jobs(path) -> tuple[list[Job], dict]:
    path = Path(path)
    try:
        data = tomllib.loads(path.read_text())
    except OSError as exc:
        raise BodyCalError(f"cannot read: {exc.strerror}", source=str(path)) from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise BodyCalError(f"not valid TOML ({exc})", source=str(path)) from None
    base = path.parent
    defaults = data.get("defaults", {})
    if not isinstance(defaults, dict):
        raise BodyCalError("expected a table", source=str(path), field="defaults")
    methods = defaults.get("method", "egocentric")
    methods = [methods] if isinstance(methods, str) else list(methods)
    for m in methods:
        if m not in METHODS:
            raise BodyCalError(f"unknown method {m!r}; use one of {', '.join(METHODS)}", source=str(path),
                               field="defaults.method")
    out_dir = base / defaults.get("output_dir", "out/batch")
    filt = defaults.get("filter", False)
    if filt is True:
        filt = "on"
    elif filt is False:
        filt = None
    elif not isinstance(filt, str):
        raise BodyCalError("filter must be true, false or \"MIN_CUTOFF,BETA[,ROT_MIN,ROT_BETA]\"", source=str(path),
                           field="defaults.filter")
    if filt is not None:
        from .filters import OneEuro

        OneEuro.parse(filt)  # a bad value is reported here, before any job starts
    plant = defaults.get("plant_feet", True)
    if not isinstance(plant, bool):
        raise BodyCalError("plant_feet must be true or false", source=str(path), field="defaults.plant_feet")
    recordings, avatars = data.get("recordings", []), data.get("avatars", [])
    if not recordings or not avatars:
        raise BodyCalError("needs at least one [[recordings]] and one [[avatars]] entry", source=str(path))
    jobs = []
    for i, rec in enumerate(recordings):
        for key in ("path", "user"):
            if not isinstance(rec, dict) or not isinstance(rec.get(key), str):
                raise BodyCalError(f"missing '{key}'", source=str(path), field=f"recordings[{i}]")
        for j, av in enumerate(avatars):
            if not isinstance(av, dict) or not isinstance(av.get("blend"), str):
                raise BodyCalError("missing 'blend'", source=str(path), field=f"avatars[{j}]")
            for m in methods:
                rp, ap = base / rec["path"], base / av["blend"]
                name = f"{_stem(rp)}__{av.get('armature') or _stem(ap)}__{m}"
                jobs.append(Job(name, rp, base / rec["user"], ap, av.get("armature"), m, out_dir / f"{name}.blend",
                                filt, plant))
    settings = {"workers": int(defaults.get("workers", os.cpu_count() or 1)),
                "runner": defaults.get("runner", "python"), "output_dir": out_dir}
    if settings["runner"] not in ("python", "blender"):
        raise BodyCalError("runner must be 'python' or 'blender'", source=str(path), field="defaults.runner")
    return jobs, settings


def command_line(job: Job, runner: str) -> list[str]:
    """The self-contained command for one job: what a farm worker runs."""
    if runner == "blender":  # the extension must be installed and enabled in that Blender
        return ["blender", "-b", "-c", "bodycal", *job.argv()]
    return [sys.executable, "-m", "bodycal_addon", *job.argv()]


def run_job(job: Job, runner: str) -> dict:
    job.output.parent.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(ROOT_DIR), env.get("PYTHONPATH", "")) if p)
    proc = subprocess.run(command_line(job, runner), capture_output=True, text=True, cwd=ROOT_DIR, env=env)
    err = proc.stderr.strip().splitlines()
    return {"job": job.name, "ok": proc.returncode == 0, "exit_code": proc.returncode,
            "seconds": round(time.perf_counter() - t0, 2), "output": str(job.output) if proc.returncode == 0 else None,
            "error": (err[-1] if err else f"exit code {proc.returncode}") if proc.returncode else None}


def run_batch(jobs_file, log=print) -> dict:
    jobs, settings = load_jobs(jobs_file)
    results = []
    workers = max(1, min(settings["workers"], len(jobs)))
    with ThreadPoolExecutor(max_workers=workers) as pool:  # each thread waits on one worker process
        futures = {pool.submit(run_job, job, settings["runner"]): job for job in jobs}
        for done, fut in enumerate(as_completed(futures), start=1):
            r = fut.result()
            results.append(r)
            status = "ok" if r["ok"] else f"FAILED: {r['error']}"
            log(f"[{done}/{len(jobs)}] {r['job']}: {status} ({r['seconds']} s)")
    results.sort(key=lambda r: r["job"])
    summary = {"jobs": len(jobs), "ok": sum(r["ok"] for r in results),
               "failed": sum(not r["ok"] for r in results), "results": results}
    summary_path = Path(settings["output_dir"]) / "summary.json"
    summary_path.parent.mkdir(parents=True, exist_ok=True)
    summary_path.write_text(json.dumps(summary, indent=1))
    summary["summary_file"] = str(summary_path)
    return summary
