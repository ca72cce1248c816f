"""The batch on a Dask cluster against the local batch (docs/FARM.md), on one machine. Prints one JSON line.

- identical: a 12-job file (2 recordings x 2 avatars x 3 methods, real bakes) run by the local batch
  and through `--cluster local:2` gives the same actions, every key of every action equal
  (differing_keys and worst_key_difference say by how much when not);
- overhead_per_job_s: on a 1-worker local cluster, (wall time from the first submit to the last
  result - the sum of the jobs' own run times) / jobs: what scheduling adds to each job (target
  <= 0.5 s);
- wall_ratio_2_to_1: the same 12 jobs' wall time on 2 workers over 1 worker, cluster start-up
  excluded (target <= 0.6; a ratio within this run);
- killed_worker: a worker process SIGKILLed while it runs a real bake, with one retry: the batch
  completes with every output (retried: how many jobs took a second attempt);
- memory_1000_jobs_mb: the client process's peak resident memory growth (the local cluster's
  scheduler runs in it) while 1,000 tiny jobs (bodycal_dev.fake_job) run on 2 workers
  (target <= 100 MB).
"""

import json
import os
import signal
import sys
import tempfile
import threading
import time
from pathlib import Path

os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="bodycal-bench-"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import psutil  # noqa: E402

from bodycal_addon.app import batch, cluster  # noqa: E402
from bodycal_addon.core import paths  # noqa: E402
from bodycal_dev import fake_job, synthetic  # noqa: E402

JOBS_TOML = """[defaults]
method = ["egocentric", "offsets", "rotations"]
output_dir = "{out}"
workers = 2
[[recordings]]
path = "takes/clap.bcrec.json"
user = "takes/performer.body.json"
[[recordings]]
path = "takes/belly.bcrec.json"
user = "takes/performer.body.json"
[[avatars]]
file = "procedural.blend"
[[avatars]]
file = "procedural_tall.blend"
"""


# bpy is imported inside the functions that use it: the local cluster's spawned workers import this
# file as their main module, and Blender's module does not load there.

def write_inputs(root: Path):
    import bpy

    perf = synthetic.make_performer(seed=5)
    for name, motion in (("clap", "clap"), ("belly", "hand_on_belly")):
        rec, truth = synthetic.record_session(perf, motions=(motion,), calibration=["tpose"], seed=5)
        rec.name = name
        synthetic.write_session(root / "takes", name, rec, truth)
    truth.body_model().save(root / "takes" / "performer.body.json")
    rigs = paths.sample_rigs()
    for name, kwargs in (("procedural", {}), ("procedural_tall", {"scale": 1.15, "belly": 0.08})):
        bpy.ops.wm.read_homefile(use_empty=True)
        rigs.build_procedural_avatar(**kwargs)
        bpy.ops.wm.save_as_mainfile(filepath=str(root / f"{name}.blend"))


def jobs_file(root: Path, out: str) -> Path:
    path = root / f"{out}.toml"
    path.write_text(JOBS_TOML.format(out=out))
    return path


def actions(blend: Path) -> dict:
    import bpy

    bpy.ops.wm.open_mainfile(filepath=str(blend), load_ui=False, use_scripts=False)
    return {a.name: {(fc.data_path, fc.array_index): [tuple(k.co) for k in fc.keyframe_points] for fc in a.fcurves}
            for a in bpy.data.actions}


def key_differences(a: dict, b: dict) -> tuple[int, float]:
    """How many keys differ between two files' actions, and by how much at most (a missing action or
    curve counts as every key of it, by infinity)."""
    count, worst = 0, 0.0
    for name in a.keys() | b.keys():
        curves_a, curves_b = a.get(name, {}), b.get(name, {})
        for curve in curves_a.keys() | curves_b.keys():
            keys_a, keys_b = curves_a.get(curve, []), curves_b.get(curve, [])
            if len(keys_a) != len(keys_b):
                count, worst = count + max(len(keys_a), len(keys_b)), float("inf")
                continue
            for ka, kb in zip(keys_a, keys_b):
                if ka != kb:
                    count, worst = count + 1, max(worst, abs(ka[0] - kb[0]), abs(ka[1] - kb[1]))
    return count, worst


def on_cluster(path: Path, workers: int, retries: int = 0, while_running=None) -> tuple[list[dict], float]:
    """The results and the wall time from the first submit to the last result (start-up excluded)."""
    jobs, settings, _stale = batch.prepare_batch(path, log=lambda line: None)
    results = []
    with cluster.connect(workers) as client:
        t0 = time.perf_counter()
        scheduling = cluster.Scheduling(client, jobs, settings, retries, results.append, lambda line: None)
        if while_running:
            threading.Thread(target=while_running, daemon=True).start()
        scheduling.run(batch.Stop())
        wall = time.perf_counter() - t0
    return results, wall


def kill_a_worker_mid_bake():
    """SIGKILLs the Dask worker process that runs the first real bake, half a second into it."""
    me = psutil.Process()
    for _ in range(1200):
        for proc in me.children(recursive=True):
            try:
                if "retarget" in proc.cmdline() and time.time() - proc.create_time() > 0.5:
                    os.kill(proc.ppid(), signal.SIGKILL)
                    return
            except psutil.Error:
                continue
        time.sleep(0.05)


def memory_of_1000_tiny_jobs(root: Path) -> float:
    text = '[defaults]\noutput_dir = "tiny"\n[[avatars]]\nfile = "procedural.blend"\n'
    (root / "tiny_inputs").mkdir()
    for i in range(1000):
        (root / "tiny_inputs" / f"fast{i}.bcrec.json").write_text("{}")
        text += f'[[recordings]]\npath = "tiny_inputs/fast{i}.bcrec.json"\nuser = "takes/performer.body.json"\n'
    (root / "tiny.toml").write_text(text)
    batch.runner.command_line = fake_job.command  # pickled by reference: the workers run the stand-in too
    me, peak, done = psutil.Process(), [0], threading.Event()

    def sample():
        while not done.is_set():
            peak[0] = max(peak[0], me.memory_info().rss)
            time.sleep(0.05)

    before = me.memory_info().rss
    threading.Thread(target=sample, daemon=True).start()
    results, _wall = on_cluster(root / "tiny.toml", 2)
    done.set()
    assert sum(r["ok"] for r in results) == 1000, [r for r in results if not r["ok"]][:3]
    return (max(peak[0], me.memory_info().rss) - before) / 1e6


def main():
    root = Path(tempfile.mkdtemp(prefix="bodycal-bench-batch-"))
    write_inputs(root)
    local = batch.run_batch(jobs_file(root, "local"), log=lambda line: None)
    assert local["ok"] == 12, local
    two, wall_2 = on_cluster(jobs_file(root, "two"), 2)
    one, wall_1 = on_cluster(jobs_file(root, "one"), 1)
    assert sum(r["ok"] for r in two) == sum(r["ok"] for r in one) == 12
    differences = [key_differences(actions(root / "local" / f"{r['job']}.blend"),
                                   actions(root / "two" / f"{r['job']}.blend")) for r in local["results"]]
    killed, _wall = on_cluster(jobs_file(root, "killed"), 2, retries=1, while_running=kill_a_worker_mid_bake)
    overhead = (wall_1 - sum(r["seconds"] for r in one)) / len(one)
    print(json.dumps({
        "jobs": 12, "identical": all(d == (0, 0.0) for d in differences),
        "differing_keys": sum(n for n, _worst in differences), "worst_key_difference": max(w for _n, w in differences),
        "overhead_per_job_s": round(overhead, 3), "overhead_target_s": 0.5,
        "wall_1_worker_s": round(wall_1, 2), "wall_2_workers_s": round(wall_2, 2),
        "wall_ratio_2_to_1": round(wall_2 / wall_1, 3), "wall_ratio_target": 0.6,
        "killed_worker": {"ok": sum(r["ok"] for r in killed), "retried": sum(r["attempts"] > 1 for r in killed),
                          "outputs": sum(Path(r["output"]).is_file() for r in killed if r["ok"])},
        "memory_1000_jobs_mb": round(memory_of_1000_tiny_jobs(root), 1), "memory_target_mb": 100,
        "cpus": os.cpu_count(),
    }))


if __name__ == "__main__":
    main()
