"""What a bake's review costs against the bake (DESIGN.md §7 "Review"; issue 43's target: the sheet of
a 30 s take in at most 20 % of its bake's time).

A 30 s take (the synthetic performer's contact motions and walk at 90 Hz, 2,700 frames) is
retargeted onto a MakeHuman avatar of the sample data (the procedural avatar without it) by the
`retarget` command's own path (`session.retarget_files`) with `--review`, as a batch job runs it:
each round in a fresh process (a job's process pays the Workbench's start-up and matplotlib's
import once, and so does every batch job), the rounds one after another. In each run, measured on
the same clock in that one process (ratios only: this machine's speed swings 2x):
- the job: reading the take, opening and measuring the avatar, computing, baking (keys, the check
  on the evaluated rig) and saving the .blend, the review's own figures taken out;
- the bake: what its summary line says (`compute_s + bake_s`), the review's figures taken out;
- the review: its figures (source, contacts, feet, accelerations, the evaluated mesh at its
  frames), the Workbench render of its frames, the plots and the written sheet and record.
Targets: the review in at most 20 % of the job (`review_le_20pct_of_job`) and of the bake alone
(`review_le_20pct_of_bake`), medians over the rounds.

Prints ONE JSON line. Run: .venv/bin/python benchmarks/bench_review.py [--rounds N]
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

TAKE_SECONDS = 30.0
FPS = 90.0
LIMIT = 0.20


def one_run(workdir: Path) -> dict:
    """One job with its review, in this process: the phases' seconds."""

    from bodycal_addon.blender import session
    from bodycal_addon.core import paths
    from bodycal_addon.recording.io.writer import save_recording
    from bodycal_dev import synthetic

    perf = synthetic.make_performer(height=1.75, build="average", seed=1)
    rec, truth = synthetic.record_session(perf, calibration=False, seed=1, motion_seconds=TAKE_SECONDS, fps=FPS)
    rec = rec.window(0, int(TAKE_SECONDS * FPS))
    take, user = workdir / "take.bcrec.json", workdir / "user.body.json"
    save_recording(rec, take)
    truth.body_model().save(user)
    avatar = next((p for p in paths.shared_avatar_files() if p.name.startswith("adult_male")), None)
    if avatar is None:
        import bpy

        from sample_rigs import build_procedural_avatar

        build_procedural_avatar()
        avatar = workdir / "procedural.blend"
        bpy.ops.wm.save_as_mainfile(filepath=str(avatar))
    marks = {}

    def progress(stage, fraction):
        marks.setdefault(stage, time.perf_counter())

    t0 = time.perf_counter()
    summary = session.retarget_files(take, user, avatar, [workdir / "out.blend"], review=True, overwrite=True,
                                     log=lambda *a: None, progress=progress)
    end = time.perf_counter()
    record = json.loads((workdir / "out.review.json").read_text())
    reviewing = marks["reviewing"]
    job = (reviewing - t0) - summary.review_s
    review = (end - reviewing) + summary.review_s
    bake = summary.compute_s + summary.bake_s
    return {"frames": int(rec.frame_count), "avatar": Path(avatar).name, "job_s": round(job, 3),
            "bake_s": round(bake, 3), "review_s": round(review, 3),
            "review_figures_s": round(summary.review_s, 3), "sheet_s": record["seconds"]["sheet"],
            "flags": {f["name"]: f["over"] for f in record["flags"]},
            "plots": not any("matplotlib" in n for n in record["notes"]),
            "sheet_bytes": (workdir / "out.review.png").stat().st_size}


def main(rounds: int = 3) -> dict:
    runs = []
    for _ in range(rounds):
        done = subprocess.run([sys.executable, __file__, "--one"], capture_output=True, text=True, cwd=REPO)
        line = next((ln for ln in reversed(done.stdout.splitlines()) if ln.startswith("{")), None)
        if done.returncode != 0 or line is None:
            raise SystemExit(f"a round failed: {done.stderr.strip().splitlines()[-1:] or done.returncode}")
        runs.append(json.loads(line))
    import statistics

    of_job = statistics.median(r["review_s"] / r["job_s"] for r in runs)
    of_bake = statistics.median(r["review_s"] / r["bake_s"] for r in runs)
    out = {"benchmark": "review", "take_seconds": TAKE_SECONDS, "fps": FPS, "rounds": runs,
           "review_over_job": round(of_job, 3), "review_over_bake": round(of_bake, 3),
           "targets": {"review_le_20pct_of_job": of_job <= LIMIT, "review_le_20pct_of_bake": of_bake <= LIMIT}}
    print(json.dumps(out))
    return out


if __name__ == "__main__":
    if "--one" in sys.argv:
        with tempfile.TemporaryDirectory(prefix="bodycal-bench-review-") as tmp:
            result = one_run(Path(tmp))
        print(json.dumps(result), flush=True)
        from bodycal_addon.blender.process import exit_now

        exit_now(0)
    rounds = int(sys.argv[sys.argv.index("--rounds") + 1]) if "--rounds" in sys.argv else 3
    main(rounds)
