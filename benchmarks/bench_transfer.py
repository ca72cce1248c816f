"""Animation transfer between characters (DESIGN.md §8): sources are characters animated with the
contact motions and real CMU clips, targets the shared avatars, per method.

- Contact sources: the synthetic performer's contact motions (clap, hand on belly, hand on head,
  hands on thighs, squat) retargeted (egocentric) onto one shared avatar, the SOURCE; its action
  is then transferred onto every other shared avatar. Contact gap (mm): in the performer's
  contact frames, the effector's skin to the target's EVALUATED mesh (mesh_metrics, as
  bench_retarget_quality), median and p95 of |gap|, beside the same gap on the source itself.
- CMU sources: the BVH clips (bare skeletons, body estimated) onto every shared avatar.
- Floor error (mm): the lowest sole point's height while the source's foot is planted (synthetic:
  the performer's truth; CMU: the source's stances, feet.detect); foot slide (mm/s): the ankle's
  horizontal speed in those frames, median and p95.
- Speed: transfer frames per second (the pipeline alone, reading and baking apart) on one core
  (BLAS threads pinned to 1), and that over the source's frame rate (x real time).
Targets: egocentric contact gap p95 <= the source's own + 10 mm on every target and >= 3x better
than rotations; >= 20x real time at the source's rate on one core.

Prints ONE JSON line. Run: .venv/bin/python benchmarks/bench_transfer.py [--quick]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):  # one core, before numpy loads
    os.environ[_var] = "1"

import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import bpy  # noqa: E402
import numpy as np  # noqa: E402

from bodycal_addon.blender import character_source as ts  # noqa: E402
from bodycal_addon.blender import mesh_metrics  # noqa: E402
from bodycal_addon.blender.avatar_calibration import calibrate_avatar  # noqa: E402
from bodycal_addon.body import skeleton as sk  # noqa: E402
from bodycal_addon.core import paths  # noqa: E402
from bodycal_addon.output import metrics  # noqa: E402
from bodycal_addon.retarget import feet  # noqa: E402
from bodycal_addon.retarget import pipeline as pl  # noqa: E402
from bodycal_addon.retarget.methods import methods_for  # noqa: E402
from bodycal_addon.retarget.pose_source import AnimationSource  # noqa: E402
from bodycal_addon.retarget.transfer import transfer  # noqa: E402
from bodycal_dev import synthetic  # noqa: E402

CONTACT_MOTIONS = ("clap", "hand_on_belly", "hand_on_head", "hands_on_thighs", "squat")
SOURCE_AVATAR = "adult_male"


def _avatars():
    from sample_rigs import load_glb_avatar

    out = []
    for f in paths.shared_avatar_files():
        arm, _ = load_glb_avatar(f)
        out.append((f.name.split(".")[0], arm, calibrate_avatar(arm)))
    return out


def _floor_and_slide(model, anim, planted: dict, fps: float):
    floors, slides = [], []
    for s in sk.SIDES:
        floors.append(metrics.floor_error(mesh_metrics.sole_points(model, anim, s), planted[s]))
        ankle = np.asarray(anim.joints_world[f"ankle_{s}"], float)[:, :2]
        still = planted[s][1:] & planted[s][:-1]
        slides.append(np.linalg.norm(np.diff(ankle, axis=0), axis=1)[still] * fps)
    return metrics.stats_mm(np.concatenate(floors)), metrics.stats_mm(np.concatenate(slides))


def _timed(source, basis, locations, t, avatar, method):
    t0 = time.perf_counter()
    anim = transfer(source, basis, locations, t, avatar, method)
    return anim, len(t) / (time.perf_counter() - t0)


def main(quick: bool = False):
    t_start = time.time()
    avatars = _avatars()
    by_name = {n: (a, m) for n, a, m in avatars}
    meshes = {n: mesh_metrics.EvaluatedMesh(a) for n, a, _ in avatars}
    perf = synthetic.make_performer(height=1.75, build="average", seed=1)
    rec, truth = synthetic.record_session(perf, motions=CONTACT_MOTIONS, calibration=False, seed=1)
    contacts = [c for c in truth.contacts if c["effector"].split("_")[0] in ("palm", "wrist", "tip")]
    max_frames = 6 if quick else 12
    src_arm, src_model = by_name[SOURCE_AVATAR]
    src_anim = pl.retarget(rec, truth.body_model(), src_model, "egocentric")
    src_fps = float(rec.fps)
    planted = {s: np.asarray(truth.planted[f"foot_{s}"], bool) for s in sk.SIDES}
    src_gap = np.concatenate(mesh_metrics.contact_gaps(src_arm, src_model, src_anim, contacts, max_frames,
                                                       meshes[SOURCE_AVATAR]))
    src_floor, src_slide = _floor_and_slide(src_model, src_anim, planted, src_fps)
    contact = {m: {} for m in methods_for("animation")}
    speed = {m: [] for m in methods_for("animation")}
    for name, arm, model in avatars:
        if name == SOURCE_AVATAR:
            continue
        for method in methods_for("animation"):
            anim, fps = _timed(src_model, src_anim.rotations, src_anim.root_location, src_anim.time, model, method)
            speed[method].append(fps / src_fps)
            gap = np.concatenate(mesh_metrics.contact_gaps(arm, model, anim, contacts, max_frames, meshes[name]))
            floor, slide = _floor_and_slide(model, anim, planted, src_fps)
            contact[method][name] = {"contact_gap_mm": metrics.stats_mm(gap), "floor_error_mm": floor,
                                     "foot_slide_mm_per_s": slide, "frames_per_s": round(fps, 1)}
    # Real motion: the CMU clips, bare skeletons with estimated bodies.
    cmu = {m: {} for m in methods_for("animation")}
    clips = sorted((paths.data_dir() / "motion" / "cmu_bvh").glob("*.bvh"))
    for clip in clips[:1] if quick else clips:
        saved = bpy.context.scene
        ts.open_source(clip)
        src = ts.read_source(next(o for o in bpy.data.objects if o.type == "ARMATURE"))
        walker = AnimationSource(src.model, src.basis, src.locations, src.time)
        stance = {s: feet.detect(walker.ankle(s), src.time, float(src.model.joints[f"ankle_{s}"].world[2])).weight >= 1
                  for s in sk.SIDES}
        bpy.ops.wm.read_factory_settings(use_empty=True)
        del saved
        avatars = _avatars()
        for name, _arm, model in avatars:
            for method in methods_for("animation"):
                anim, fps = _timed(src.model, src.basis, src.locations, src.time, model, method)
                speed[method].append(fps / src.fps)
                floor, slide = _floor_and_slide(model, anim, stance, src.fps)
                cmu[method].setdefault(clip.stem, {})[name] = {
                    "finite": bool(np.isfinite(anim.rotations).all()), "floor_error_mm": floor,
                    "foot_slide_mm_per_s": slide, "frames_per_s": round(fps, 1), "source_fps": round(src.fps, 3)}
    ego, rot = contact["egocentric"], contact["rotations"]
    src_p95 = metrics.stats_mm(src_gap)["p95"]
    ratio = {a: round(rot[a]["contact_gap_mm"]["p95"] / max(ego[a]["contact_gap_mm"]["p95"], 1e-6), 2) for a in ego}
    out = {
        "bench": "transfer",
        "source_avatar": SOURCE_AVATAR,
        "motions": list(CONTACT_MOTIONS),
        "source_contact_gap_mm": metrics.stats_mm(src_gap),
        "source_floor_error_mm": src_floor,
        "source_foot_slide_mm_per_s": src_slide,
        "p95_contact_gap_mm": {m: {a: r["contact_gap_mm"]["p95"] for a, r in contact[m].items()} for m in contact},
        "median_contact_gap_mm": {m: {a: r["contact_gap_mm"]["median"] for a, r in contact[m].items()}
                                  for m in contact},
        "rotations_over_egocentric_p95": ratio,
        "target_p95_le_source_plus_10mm": all(r["contact_gap_mm"]["p95"] <= src_p95 + 10.0 for r in ego.values()),
        "target_3x_better_than_rotations": all(v >= 3.0 for v in ratio.values()),
        "x_real_time_min": {m: round(float(np.min(v)), 1) for m, v in speed.items()},
        "x_real_time_median": {m: round(float(np.median(v)), 1) for m, v in speed.items()},
        "target_20x_real_time": all(float(np.min(v)) >= 20.0 for v in speed.values()),
        "contact_details": contact,
        "cmu": cmu,
        "seconds": round(time.time() - t_start, 1),
    }
    print(json.dumps(out))
    return out


if __name__ == "__main__":
    bpy.ops.wm.read_factory_settings(use_empty=True)
    main(quick="--quick" in sys.argv)
