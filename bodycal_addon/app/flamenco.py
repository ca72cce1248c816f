"""`bodycal batch JOBS.toml --export-flamenco FILE.json`: the batch as a Flamenco 3 job of the
custom type `bodycal-batch` (farm/flamenco/bodycal_batch.js; docs/FARM.md), for the Manager's API
(`POST /api/v3/jobs`). Nothing runs and the jobs file is not changed.

The job's settings are the checked jobs file with absolute paths: the recordings, animations and
avatars as JSON lists, the methods and formats, the output folder and the bake options. The job
type's compileJob makes the same jobs from them as `load_jobs` (the cross product, the output
names of docs/FORMATS.md §4.1) and gives each one task running `blender -b -c bodycal ...` with
`command_line(job, "blender")`'s arguments. With `review` (the setting), every job reviews its
bake and a last task, depending on all of them, writes the review page (`bodycal review
OUTPUT_DIR`, FORMATS.md §4.5).
"""

from __future__ import annotations

import json
from pathlib import Path

from ..core.errors import BodyCalError
from .batch import Job, load_jobs

JOB_TYPE = "bodycal-batch"  # Flamenco names a job type after its file, bodycal_batch.js


def _unique(items) -> list:
    return list(dict.fromkeys(items))


def _optional_float(value: float | None) -> str:
    return "" if value is None else repr(float(value))  # as Job.argv writes it


def job_settings(jobs: list[Job], settings: dict, review: bool = False) -> dict:
    """The `bodycal-batch` job type's settings for these jobs (all share the bake options)."""
    first = jobs[0]
    recordings = _unique((str(j.recording), str(j.user)) for j in jobs if j.user is not None)
    animations = _unique((str(j.recording), j.source_armature, j.action) for j in jobs if j.user is None)
    avatars = _unique((str(j.avatar), j.armature, str(j.bone_map) if j.bone_map else None) for j in jobs)
    return {
        "recordings": json.dumps([{"path": p, "user": u} for p, u in recordings]),
        "animations": json.dumps([{"path": p, "source_armature": sa, "action": act} for p, sa, act in animations]),
        "avatars": json.dumps([{"file": f, "armature": arm, "bone_map": bm} for f, arm, bm in avatars]),
        "methods": ",".join(settings["methods"]),
        "output_dir": str(settings["output_dir"]),
        "export": ",".join(settings["formats"]),
        "filter": "off" if first.filter is None else first.filter,
        "plant_feet": first.plant_feet,
        "placement": first.placement,
        "root_motion": first.root_motion,
        "rigify_target": first.rigify_target,
        "tolerance": _optional_float(first.tolerance),
        "fps": _optional_float(first.fps),
        "overwrite": first.overwrite,
        "review": review,
    }


def export_flamenco(jobs_file, out_file, review: bool = False) -> Path:
    """Writes the job submission (JSON) to `out_file`; its path. `review`: the jobs review their
    bakes and a last task writes the review page."""
    jobs_file = Path(jobs_file).absolute()  # a farm needs absolute paths in every command
    jobs, settings = load_jobs(jobs_file)
    out_file = Path(out_file).absolute()
    if out_file.is_symlink() or (out_file.exists() and not out_file.is_file()) or out_file == jobs_file:
        raise BodyCalError("is the jobs file, a link or not a regular file; write the job elsewhere",
                           source=str(out_file))
    body = {"name": f"BodyCal batch {jobs_file.stem}", "type": JOB_TYPE, "priority": 50,
            "submitter_platform": "linux", "settings": job_settings(jobs, settings, review),
            "metadata": {"bodycal.jobs_file": str(jobs_file), "bodycal.jobs": str(len(jobs))}}
    try:
        out_file.parent.mkdir(parents=True, exist_ok=True)
        out_file.write_text(json.dumps(body, indent=1), encoding="utf-8")
    except OSError as exc:
        raise BodyCalError(f"cannot write: {exc.strerror or exc}", source=str(out_file)) from None
    return out_file
