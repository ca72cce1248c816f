"""Characters no one on the project made (DESIGN.md §7, "Outside characters"): each file of
sample_data/avatars/outside (and any .glb/.gltf/.fbx given with --avatars, such as characters whose
terms forbid keeping them in the repository) opened as the `retarget` command opens it, calibrated
and retargeted on the sample take (sample_rigs/recordings/demo_full) with no option, baked (with
the bake's check on the evaluated rig), and measured against the take's ground truth.

Per rig: the detected naming scheme, bones, unmapped bones, what the calibration estimated instead
of measuring, the result ("ok" or the one line it was refused with), seconds (open, calibrate,
retarget, bake); contact gap (mm, the effector's skin to the evaluated body mesh in the
performer's contact frames: median and p95 of |gap|) and floor error (mm, the engine's lowest sole
point while a foot is planted: median and p95). Prints ONE JSON line.
Run: .venv/bin/python benchmarks/bench_avatars.py [--quick] [--avatars FILE ...]
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import numpy as np  # noqa: E402

from bodycal_addon.blender import avatar_rig, blendfile, demo, mesh_metrics, session  # noqa: E402
from bodycal_addon.calibration import calibrate_user  # noqa: E402
from bodycal_addon.core import paths  # noqa: E402
from bodycal_addon.core.errors import BodyCalError  # noqa: E402
from bodycal_addon.output import metrics  # noqa: E402
from bodycal_addon.recording.io import load_recording  # noqa: E402
from bodycal_addon.retarget.takes import RecordingTake  # noqa: E402

QUICK_WINDOW = (1800, 2400)  # --quick: these frames of the take (arms moving, no deep squat)


def _measure(path: Path, take, contacts, planted, quick: bool) -> dict:
    t0 = time.perf_counter()
    out = {"file": path.name}
    try:
        blendfile.open_avatar(path)
        arm = blendfile.find_armature(None, str(path))
        bm = avatar_rig.bone_map_for(arm)
        out |= {"scheme": bm.scheme, "bones": len(arm.data.bones), "unmapped": len(bm.unmapped)}
        target = session.prepare_target(arm)
        computed = session.compute(take, target, session.Settings())
        anim = computed.animation
        summary = session.bake(take, target, computed)
    except BodyCalError as exc:
        return out | {"result": str(exc), "seconds": round(time.perf_counter() - t0, 2)}
    seconds = time.perf_counter() - t0
    cal = target.avatar.calibration
    touching = [_effector_it_has(c, target.avatar, anim) for c in contacts
                if c["effector"].split("_")[0] in ("palm", "wrist", "tip")]
    touching = [c for c in touching if c is not None]
    gaps = mesh_metrics.contact_gaps(arm, target.avatar, anim, touching, max_frames=4 if quick else 8)
    ground = np.array([0.0, 0.0, float(np.array(arm.matrix_world)[2, 3])])  # its floor: the object origin's height
    floor = [metrics.floor_error(mesh_metrics.sole_points(target.avatar, anim, s) - ground, mask[:anim.frame_count])
             for s in ("l", "r") if (mask := planted.get(f"foot_{s}")) is not None and mask[:anim.frame_count].any()]
    return out | {
        "result": "ok", "seconds": round(seconds, 2), "frames": summary.frames,
        "estimated": sorted(k for k in cal.get("defaulted", {}) if not k.startswith("hinge:")),
        "derived_hinges": sum(k.startswith("hinge:") for k in cal.get("defaulted", {})),
        "reach_p95_mm": round(summary.figures.get("reach p95", float("nan")), 1),
        "contact_gap_mm": metrics.stats_mm(np.concatenate(gaps)) if gaps else metrics.stats_mm([]),
        "floor_error_mm": metrics.stats_mm(np.concatenate(floor)) if floor else metrics.stats_mm([])}


def _effector_it_has(contact: dict, avatar, anim) -> dict | None:
    """The contact as this rig can show it: a palm contact by the wrist when the rig has no
    fingers to place a palm (Cesium Man), a fingertip's only when it has that finger."""
    eff = contact["effector"]
    if eff.startswith("palm_"):
        has_palm = any(e.id == f"mesh:palm_{eff[-1]}" for e in avatar.surface)
        return contact if has_palm else dict(contact, effector=f"wrist_{eff[-1]}")
    return contact if eff in anim.joints_world else None


def main(quick: bool = False, extra: list[str] = ()):
    t0 = time.time()
    rec = load_recording(demo.DEMO_RECORDING)
    contacts, planted = demo.read_truth(demo.DEMO_RECORDING.with_name("demo_full.truth.json"), rec.frame_count)
    take = RecordingTake(rec, calibrate_user(rec))
    if quick:
        take = take.window(*QUICK_WINDOW)
        lo = QUICK_WINDOW[0] - 1
        contacts = [dict(c, frames=c["frames"][lo:]) for c in contacts]
        planted = {k: v[lo:] for k, v in planted.items()}
    files = [*paths.outside_avatar_files(), *(Path(f) for f in extra)]
    rigs = [_measure(f, take, contacts, planted, quick) for f in files]
    ok = [r for r in rigs if r["result"] == "ok"]

    def pooled(key, stat):
        vals = [r[key][stat] for r in ok if r[key]["count"]]
        return round(float(np.median(vals)), 3) if vals else None

    print(json.dumps({"benchmark": "avatars", "quick": quick, "take": rec.name, "frames": int(rec.frame_count),
                      "rigs": rigs, "ok": len(ok), "of": len(rigs),
                      "contact_gap_median_mm": pooled("contact_gap_mm", "median"),
                      "floor_error_median_mm": pooled("floor_error_mm", "median"),
                      "seconds": round(time.time() - t0, 1)}))


if __name__ == "__main__":
    args = sys.argv[1:]
    given = args[args.index("--avatars") + 1:] if "--avatars" in args else []
    main(quick="--quick" in args, extra=[a for a in given if not a.startswith("--")])
    from bodycal_addon.blender.process import exit_now

    exit_now(0)
