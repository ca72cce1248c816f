"""`bodycal batch JOBS.toml --export-openjd DIR`: the batch as an Open Job Description job (the job
format of AWS Deadline Cloud; `openjd run` from openjd-cli runs it locally). docs/FARM.md.

DIR gets two files:
- `bodycal_batch.commands.json`: every job's command line, exactly `batch.command_line`'s (absolute
  paths; the interpreter of a `python` runner left as null, the worker's own);
- `bodycal_batch.template.json`: one step whose parameter space is the job index 0..N-1, each task
  running one job's command through a small embedded script, with `defaults.timeout` as the
  action's timeout. Job parameters: `Python` (the interpreter with Blender's module, default the
  one exporting), `BodyCalRoot` (the folder holding `bodycal_addon`) and `Commands` (the table).

With `review` every job reviews its bake (`--review`) and a second step, `BodyCalReview`, run once
after the jobs' step, writes the batch's review page (`bodycal review OUTPUT_DIR`, FORMATS.md §4.5).

Nothing runs and the jobs file is not changed; existing files in DIR are replaced only when they
are this export's own (the same two names).
"""

from __future__ import annotations

import json
import math
import sys
from dataclasses import replace
from pathlib import Path

from ..core.errors import BodyCalError
from ..core.paths import ROOT_DIR
from .batch import command_line, load_jobs

TEMPLATE_NAME = "bodycal_batch.template.json"
COMMANDS_NAME = "bodycal_batch.commands.json"
STEP_NAME = "BodyCalJobs"
REVIEW_STEP = "BodyCalReview"

# The task's script: the job's command from the table, run as this task's process (execvpe keeps the
# pid, so the session's cancel and timeout signals reach the job itself).
RUN_ONE_JOB = """\
import json, os, sys
root, table, index = sys.argv[1], sys.argv[2], int(sys.argv[3])
with open(table, encoding="utf-8") as f:
    command = json.load(f)["commands"][index]
command = [sys.executable if part is None else part for part in command]
env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in (root, os.environ.get("PYTHONPATH")) if p))
os.chdir(root)
sys.stdout.flush()
os.execvpe(command[0], command, env)
"""


def _commands(jobs, runner: str) -> list[list[str | None]]:
    commands = []
    for job in jobs:
        command = command_line(job, runner)
        commands.append([None if runner == "python" and i == 0 else part for i, part in enumerate(command)])
    return commands


def _page_command(folder: Path, runner: str) -> list[str | None]:
    """The review page's command (`bodycal review OUTPUT_DIR`), as the jobs' runner runs it."""
    if runner == "blender":
        return ["blender", "-b", "-c", "bodycal", "review", str(folder)]
    return [None, "-m", "bodycal_addon", "review", str(folder)]


def template(name: str, count: int, commands_file: Path, timeout: float | None, review_dir: Path | None = None
             ) -> dict:
    """The job template (jobtemplate-2023-09) for `count` jobs whose commands are in `commands_file`;
    with `review_dir`, a last step writing that folder's review page."""
    on_run = {"command": "{{Param.Python}}",
              "args": ["{{Task.File.RunOneJob}}", "{{Param.BodyCalRoot}}", "{{Param.Commands}}", "{{Task.Param.Job}}"],
              "cancelation": {"mode": "NOTIFY_THEN_TERMINATE"}}
    if timeout is not None:
        on_run["timeout"] = math.ceil(timeout)
    steps = [{
        "name": STEP_NAME,
        "parameterSpace": {"taskParameterDefinitions": [{"name": "Job", "type": "INT", "range": f"0-{count - 1}"}]},
        "script": {"embeddedFiles": [{"name": "RunOneJob", "type": "TEXT", "data": RUN_ONE_JOB}],
                   "actions": {"onRun": on_run}},
    }]
    if review_dir is not None:
        steps.append({
            "name": REVIEW_STEP,
            "dependencies": [{"dependsOn": STEP_NAME}],
            "script": {"embeddedFiles": [{"name": "RunOneJob", "type": "TEXT", "data": RUN_ONE_JOB}],
                       "actions": {"onRun": {"command": "{{Param.Python}}",
                                             "args": ["{{Task.File.RunOneJob}}", "{{Param.BodyCalRoot}}",
                                                      "{{Param.Commands}}", str(count)]}}},
        })
    return {
        "specificationVersion": "jobtemplate-2023-09",
        "name": f"BodyCal batch {name}",
        "parameterDefinitions": [
            {"name": "Python", "type": "STRING", "default": sys.executable,
             "description": "Python 3.11 with the bpy module and BodyCal's requirements, as every worker sees it"},
            {"name": "BodyCalRoot", "type": "STRING", "default": str(ROOT_DIR),
             "description": "the folder holding bodycal_addon, as every worker sees it"},
            # a PATH default is relative to the template's folder (the table is written beside it)
            {"name": "Commands", "type": "PATH", "objectType": "FILE", "dataFlow": "IN",
             "default": commands_file.name, "description": "the jobs' command lines (bodycal batch --export-openjd)"},
        ],
        "steps": steps,
    }


def export_openjd(jobs_file, out_dir, review: bool = False) -> Path:
    """Writes the template and the commands table into `out_dir`; the template's path. `review`:
    every job reviews its bake, and the table's last command (after the jobs') writes the page."""
    jobs_file = Path(jobs_file).absolute()  # a farm needs absolute paths in every command
    jobs, settings = load_jobs(jobs_file)
    if review:
        jobs = [replace(job, review=True) for job in jobs]
    out_dir = Path(out_dir).absolute()
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise BodyCalError(f"cannot create the folder: {exc.strerror or exc}", source=str(out_dir)) from None
    commands_file, template_file = out_dir / COMMANDS_NAME, out_dir / TEMPLATE_NAME
    for path in (commands_file, template_file):
        if path.is_symlink() or (path.exists() and not path.is_file()):
            raise BodyCalError("is a link or not a regular file; remove it or export elsewhere", source=str(path))
    commands = _commands(jobs, settings["runner"])
    review_dir = Path(settings["output_dir"]) if review else None
    if review_dir is not None:
        commands.append(_page_command(review_dir, settings["runner"]))
    table = {"jobs_file": str(jobs_file), "names": [j.name for j in jobs], "commands": commands}
    commands_file.write_text(json.dumps(table, indent=1), encoding="utf-8")
    body = template(jobs_file.stem, len(jobs), commands_file, settings["timeout"], review_dir)
    template_file.write_text(json.dumps(body, indent=1), encoding="utf-8")
    return template_file
