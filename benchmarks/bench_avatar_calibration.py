"""Seconds per avatar of the surface calibration by raycasting (DESIGN.md §4; target: under 1 s for
a 13k-vertex avatar), for each shared MakeHuman avatar and the procedural one. Each figure is the
best of 3 runs of `calibrate_avatar` (BVH build on the evaluated mesh + every ray + the model),
excluding the import. Prints one JSON line."""

import contextlib
import io
import json
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("BLENDER_USER_RESOURCES", tempfile.mkdtemp(prefix="bodycal-bench-"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import bpy  # noqa: E402

from bodycal_addon.blender.avatar_calibration import calibrate_avatar  # noqa: E402
from bodycal_addon.core import paths  # noqa: E402
from sample_rigs import build_procedural_avatar, load_glb_avatar  # noqa: E402

REPEATS = 3


def measure(arm, mesh):
    best = float("inf")
    model = None
    for _ in range(REPEATS):
        t0 = time.perf_counter()
        model = calibrate_avatar(arm)
        best = min(best, time.perf_counter() - t0)
    q = model.calibration["quality"]
    return {"seconds": round(best, 4), "vertices": len(mesh.data.vertices), "rays": model.extra["rays_cast"],
            "hits": sum(v["hit"] for v in q.values()), "rejected": sum(v["rejected"] for v in q.values())}


def main():
    out = {"benchmark": "avatar_calibration", "repeats": REPEATS, "avatars": {}}
    bpy.ops.wm.read_homefile(use_empty=True)
    arm, mesh, _spec = build_procedural_avatar()
    out["avatars"]["procedural"] = measure(arm, mesh)
    for path in paths.shared_avatar_files():
        bpy.ops.wm.read_homefile(use_empty=True)
        with contextlib.redirect_stdout(io.StringIO()):  # the glTF importer logs to stdout
            arm, mesh = load_glb_avatar(path)
        out["avatars"][path.name.split(".")[0]] = measure(arm, mesh)
    secs = [v["seconds"] for v in out["avatars"].values()]
    out["max_seconds"] = max(secs)
    out["target_seconds"] = 1.0
    out["meets_target"] = max(secs) < 1.0
    print(json.dumps(out))
    from bodycal_addon.blender.process import exit_now

    exit_now(0)  # Blender 4.5 can hang at exit (BLENDER_NOTES.md)


if __name__ == "__main__":
    main()
