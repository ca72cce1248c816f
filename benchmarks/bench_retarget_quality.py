"""Retargeting quality (DESIGN.md §7): synthetic performers doing the contact motions,
retargeted onto every shared avatar (calibrated in Blender by the avatar calibration; the
procedural avatar when none can be loaded) with each method.

Figures per method and avatar:
- contact gap (mm): in the performer's contact frames, the avatar's effector skin to the
  avatar's EVALUATED mesh of the touched body part (bodycal_addon.blender.mesh_metrics), median
  and 95th percentile of |gap|;
- floor error (mm): the avatar's lowest sole point above/below z = 0 while the performer's foot
  is planted (median |error|, p95);
- reach error (mm): the avatar's wrists, ankles and fingertips after IK against their targets.
Target for egocentric: p95 contact gap <= 10 mm on every avatar and >= 5x smaller than rotations.

The recordings go through the One Euro filter first, as a bake does by default (filters.py,
DESIGN.md §6b); `--filter=MIN_CUTOFF,BETA[,ROT_MIN,ROT_BETA]` gives other parameters, as
`retarget --filter` does, and `--no-filter` measures the devices as recorded.

Prints ONE JSON line. Run: .venv/bin/python benchmarks/bench_retarget_quality.py [--quick] [--filter=... | --no-filter]
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import bpy  # noqa: E402
import numpy as np  # noqa: E402

from bodycal_addon.blender import mesh_metrics  # noqa: E402
from bodycal_addon.body import skeleton as sk  # noqa: E402
from bodycal_addon.core import paths  # noqa: E402
from bodycal_addon.output import metrics  # noqa: E402
from bodycal_addon.recording.filters import DEFAULT_FILTER, OneEuro, filter_recording  # noqa: E402
from bodycal_addon.retarget import pipeline as pl  # noqa: E402
from bodycal_dev import synthetic  # noqa: E402

CONTACT_MOTIONS = ("clap", "hand_on_belly", "hand_on_head", "hands_on_thighs", "squat")
PERFORMERS = (("average", 1.75), ("heavy", 1.70), ("child", 1.35))


def _avatars():
    """[(name, armature, avatar BodyModel)]: the shared avatars calibrated in Blender, else the
    procedural avatar."""
    from sample_rigs import build_procedural_avatar, load_glb_avatar

    out, notes = [], []
    try:
        from bodycal_addon.blender.avatar_calibration import calibrate_avatar
    except ImportError as exc:  # the avatar calibration has not landed
        calibrate_avatar = None
        notes.append(f"avatar calibration unavailable ({exc}); procedural avatar")
    files = paths.shared_avatar_files() if calibrate_avatar else []
    for f in files:
        try:
            arm, _ = load_glb_avatar(f)
            out.append((arm.name, arm, calibrate_avatar(arm)))
        except Exception as exc:  # report, keep measuring the others
            notes.append(f"{Path(f).name}: {exc}")
    if not out:
        from bodycal_dev.retarget_fixtures import procedural_avatar
        from sample_rigs import procedural

        spec = procedural.build_spec()
        arm, _, _ = build_procedural_avatar(spec)
        out.append(("procedural", arm, procedural_avatar(spec)))
    return out, notes


def main(quick: bool = False, smooth: OneEuro | None = None):
    t0 = time.time()
    avatars, notes = _avatars()
    performers = PERFORMERS[:1] if quick else PERFORMERS
    sessions = []
    for build, height in performers:
        perf = synthetic.make_performer(height=height, build=build, seed=1)
        rec, truth = synthetic.record_session(perf, motions=CONTACT_MOTIONS, calibration=False, seed=1)
        if smooth is not None:
            rec = filter_recording(rec, smooth)
        sessions.append((build, rec, truth, truth.body_model()))
    res: dict = {m: {} for m in pl.METHODS}
    fps = {m: [] for m in pl.METHODS}
    for name, arm, avatar in avatars:
        mesh = mesh_metrics.EvaluatedMesh(arm)
        for method in pl.METHODS:
            gaps, floors, reach, model_gaps = [], [], [], []
            for _build, rec, truth, user in sessions:
                t = time.time()
                anim = pl.retarget(rec, user, avatar, method)
                fps[method].append(rec.frame_count / (time.time() - t))
                contacts = [c for c in truth.contacts if c["effector"].split("_")[0] in ("palm", "wrist", "tip")]
                for g in mesh_metrics.contact_gaps(arm, avatar, anim, contacts, max_frames=8 if quick else 12,
                                                   mesh=mesh):
                    gaps.append(g)
                model_gaps += metrics.model_contact_gaps(avatar, anim.rotations, anim.root_location, contacts,
                                                         anim.joints_world)
                for s in sk.SIDES:
                    soles = mesh_metrics.sole_points(avatar, anim, s)
                    floors.append(metrics.floor_error(soles, truth.planted[f"foot_{s}"]))
                for n, tg in anim.targets.items():
                    if n.split("_")[0] in ("wrist", "ankle", "tip"):
                        reach.append(metrics.reach_error(anim.joints_world[n], tg))
            g = np.concatenate(gaps) if gaps else np.array([np.nan])
            res[method][name] = {
                "contact_gap_mm": metrics.stats_mm(g),
                "contact_gap_signed_median_mm": round(float(np.nanmedian(g) * 1000), 2),
                "model_contact_gap_mm": metrics.stats_mm(np.concatenate(model_gaps)) if model_gaps else None,
                "floor_error_mm": metrics.stats_mm(np.concatenate(floors)),
                "reach_error_mm": metrics.stats_mm(np.concatenate(reach)) if reach else None,
            }
    ego, rot = res["egocentric"], res["rotations"]
    ratio = {a: (round(rot[a]["contact_gap_mm"]["p95"] / max(ego[a]["contact_gap_mm"]["p95"], 1e-6), 2))
             for a in ego}
    out = {
        "bench": "retarget_quality",
        "filter": None if smooth is None else [smooth.min_cutoff, smooth.beta, smooth.rot_min_cutoff, smooth.rot_beta],
        "performers": [b for b, *_ in sessions],
        "motions": list(CONTACT_MOTIONS),
        "avatars": [a for a, *_ in avatars],
        "p95_contact_gap_mm": {m: {a: r["contact_gap_mm"]["p95"] for a, r in res[m].items()} for m in res},
        "median_contact_gap_mm": {m: {a: r["contact_gap_mm"]["median"] for a, r in res[m].items()} for m in res},
        "rotations_over_egocentric_p95": ratio,
        "p95_contact_gap_vs_calibrated_model_mm": {m: {a: (r["model_contact_gap_mm"] or {}).get("p95")
                                                      for a, r in res[m].items()} for m in res},
        "target_p95_le_10mm_every_avatar": all(ego[a]["contact_gap_mm"]["p95"] <= metrics.CONTACT_GAP_P95_MM
                                               for a in ego),
        "target_5x_better_than_rotations": all(r >= 5.0 for r in ratio.values()),
        "details": res,
        "retarget_fps_median": {m: round(float(np.median(v)), 1) for m, v in fps.items()},
        "notes": notes,
        "seconds": round(time.time() - t0, 1),
    }
    print(json.dumps(out))
    return out


if __name__ == "__main__":
    bpy.ops.wm.read_factory_settings(use_empty=True)
    given = [a.partition("=")[2] for a in sys.argv[1:] if a.split("=")[0] == "--filter"]
    smoothing = None if "--no-filter" in sys.argv else OneEuro.parse(given[-1]) if given else DEFAULT_FILTER
    main(quick="--quick" in sys.argv, smooth=smoothing)
