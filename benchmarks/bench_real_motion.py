"""Real human motion through the whole pipeline, as an outside tool would record it (DESIGN.md §7,
"Real motion").

Each CMU BVH clip (motion/cmu_bvh and motion/cmu_bvh_fast_arms of the sample data, plus any
given with --clips) becomes a FORMATS.md
recording through `evaluation/` (code that shares nothing with synthetic.py): the calibration
steps performed by the clip's own skeleton, then the clip; trackers at random mounting rotations
and offsets, the performer at a random facing and place in the play area, the file written Y up
(SteamVR) or Z up; tracker noise 0.5 mm / 0.3 degrees, soft-tissue motion 1.5 mm, dropouts. Two
profiles: `full` (15 devices, no touch steps: its limb trackers measure these joints from the motion)
and `six` (HMD, controllers, pelvis and feet) with the six-device protocol's controller pivots and
touches (evaluation/touching.py; DESIGN.md §3 "Touches with six devices"); and, calibration only,
`six_without_touches` (the same devices and seed without those steps: the anthropometric defaults).
The file goes through the public reader, `calibrate_user` and `retarget` onto shared avatars
calibrated in Blender, with every method.

Figures, per clip x profile (calibration) and per method x avatar x clip x profile (motion only):
- joint-centre error (mm) at the reference time, per joint;
- sole height during the source's stance (mm): median and worst of the avatar's lowest sole point;
- foot slide (mm per 90 Hz frame, p95) of the avatar's ankle over the source's stance frames, with
  the source's own;
- wrist / ankle acceleration p95 over the source's, scaled the way the method scales motion: by the
  avatar / source arm and leg ratios for egocentric and rotations (a rotation copy moves a longer
  limb's end faster), by AvatarGo's one eye-height ratio for offsets (eq. 2 at the user's size,
  divided by it: a child's legs, shorter for its height than an adult's, then move ~14% more than
  the leg ratio says, by the method's design; `accel_ratio_limb_scaled` keeps that figure too);
  and over the user's own joint as the trackers give it, scaled alike (`pipeline_gain`: what the
  pipeline adds);
- hip-line angle (degrees, p95 and max) between the avatar's and the source's.
The fast-arm clips' wrists (131_03: its hands move and turn fast) have their own target too
(`fast_arms_egocentric_wrist_accel_le_1_3x_source`: the egocentric method's, with the default
settings; the other methods' worst beside it).
Every retarget runs twice: on the recording as read (`raw`, `--no-filter`) and with the One Euro
filter's defaults on the devices (`filtered`: the default settings, DESIGN.md §6b): 0.5 mm of tracker
noise alone puts the raw controller at 1.5-2x the source's acceleration. The feet on the evaluated
mesh (`skin_figures`) are measured on the default. Targets are checked in `targets`.

`--seeds N ...`: every clip recorded in these sessions (the evaluation's seed: mounting, facing,
noise, dropouts) instead of one per clip (its index); `--only-clips`: the clips given with --clips
alone. A quick run through the sessions that lose a pelvis or thigh tracker mid-motion (DESIGN.md
§6 "Lost devices"): `--avatars child_10y --only-clips --clips sample_data/motion/cmu_bvh_held_out/05_06_dance.bvh
sample_data/motion/cmu_bvh/131_01_start_walk_stop.bvh --seeds 2 3`.

Prints ONE JSON line. Run: .venv/bin/python benchmarks/bench_real_motion.py [--quick] [--clips F ...]
[--only-clips] [--seeds N ...] [--avatars NAME ...] [--filter]
"""

from __future__ import annotations

import contextlib
import io
import json
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import bpy  # noqa: E402
import numpy as np  # noqa: E402

from bodycal_addon.blender import mesh_metrics  # noqa: E402
from bodycal_addon.calibration import calibrate_user  # noqa: E402
from bodycal_addon.core import paths  # noqa: E402
from bodycal_addon.core.errors import BodyCalError  # noqa: E402
from bodycal_addon.output import metrics  # noqa: E402
from bodycal_addon.recording import io as recording_io  # noqa: E402
from bodycal_addon.recording.filters import OneEuro, filter_recording  # noqa: E402
from bodycal_addon.retarget import offsets  # noqa: E402
from bodycal_addon.retarget import pipeline as pl  # noqa: E402
from bodycal_addon.retarget.avatar_pose import AvatarRig  # noqa: E402
from bodycal_addon.retarget.user_animation import animate_user  # noqa: E402
from evaluation import bvh, capture, measure, performer, session  # noqa: E402

AVATARS = ("child_10y", "long_arms_male")
PROFILES = ("full", "six")
FPS = 90.0
LIMB_JOINTS = tuple(f"{j}_{s}" for j in ("hip", "knee", "ankle", "shoulder", "elbow", "wrist") for s in "lr")
JOINT_TARGETS = {  # (profile, joints, mm); DESIGN.md §3 "Outside recordings", "Touches with six devices"
    "every_limb_joint_full": ("full", LIMB_JOINTS, 10.0),
    "hips_knees_ankles_shoulders_elbows_six": ("six", tuple(j for j in LIMB_JOINTS if not j.startswith("wrist")),
                                               20.0),
    "skull_base_full": ("full", ("skull_base",), 20.0),
    "skull_base_six": ("six", ("skull_base",), 20.0),
}


FAST_ARMS = "cmu_bvh_fast_arms"  # the clips whose hands move and turn fast (the egocentric hand's point)


def _clips(extra: list[str], only: bool = False) -> list[Path]:
    d = paths.data_dir()
    found = [p for folder in ("cmu_bvh", FAST_ARMS) for p in sorted((d / "motion" / folder).glob("*.bvh"))] \
        if d and not only else []
    return found + [Path(p) for p in extra]


def _avatars(names):
    from bodycal_addon.blender.avatar_calibration import calibrate_avatar
    from sample_rigs import load_glb_avatar

    out = []
    for n in names:
        f = next((p for p in paths.shared_avatar_files() if p.name.startswith(n)), None)
        if f is None:
            continue
        with contextlib.redirect_stdout(io.StringIO()):  # the glTF importer talks: one JSON line only
            arm, _ = load_glb_avatar(f)
        out.append((n, arm, calibrate_avatar(arm)))
    return out


def skin_figures(arm, avatar, anim, truth, leg_k: float) -> dict:
    """The feet as the animator sees them, on the evaluated mesh (mesh_metrics.foot_skin): the
    lowest foot skin while the source's heel or ball is on the ground (its ankle or toe joint low
    and slow, from the BVH), and the slide of the skin's heel and ball points while the source's
    heel, resp. ball, is down, against the source's ankle, resp. toe joint, scaled like the legs."""
    a, b = truth["motion"]
    fps = truth["fps"]
    J = {n: i for i, n in enumerate(truth["joints"])}
    T = truth["positions"][a:b]
    down = {s: {part: metrics.ground_contact(T[:, J[f"{joint}_{s}"]], fps) for part, joint in (("heel", "ankle"),
                                                                                     ("ball", "toe"))}
            for s in ("l", "r")}
    skin = mesh_metrics.foot_skin(arm, avatar, anim, np.arange(a, b))
    out = {"skin_height_mm": {}, "heel_slide_mm": {}, "ball_slide_mm": {}, "slide_ratio": {}}
    for s, sk_ in skin.items():
        on = down[s]["heel"] | down[s]["ball"]
        low = sk_["low"][on] * 1000
        out["skin_height_mm"][s] = {"median": round(float(np.median(low)), 1), "worst": round(float(low.min()), 1)} \
            if low.size else {"median": None, "worst": None}
        for part, joint in (("heel", "ankle"), ("ball", "toe")):
            mine = metrics.slide_p95_mm(sk_[part], down[s][part], fps)
            src = metrics.slide_p95_mm(T[:, J[f"{joint}_{s}"]], down[s][part], fps)
            scaled = None if src is None else round(src * leg_k, 2)
            out[f"{part}_slide_mm"][s] = {"avatar": mine, "source_scaled": scaled}
            if mine is not None and scaled:
                out["slide_ratio"][f"{part}_{s}"] = round(mine / scaled, 2)
    return out


def motion_figures(anim, avatar, truth, k: dict, user_pose, limb_k: dict | None = None, arm=None) -> dict:
    """`k`: how the method scales the source's wrist and ankle motion; `limb_k`, when that is not
    the limb ratios, the limb ratios too (their figure is reported beside)."""
    a, b = truth["motion"]
    fps = truth["fps"]
    names = truth["joints"]
    T = truth["positions"][a:b]
    J = {n: i for i, n in enumerate(names)}
    out = {"sole_height_mm": {}, "slide_mm": {}, "source_slide_mm": {}, "accel_ratio": {}, "pipeline_gain": {}}
    for s in ("l", "r"):
        st = truth["stance"][s][a:b]
        soles = mesh_metrics.sole_points(avatar, anim, s)[a:b]
        out["sole_height_mm"][s] = measure.sole_height_mm(soles, st)
        out["slide_mm"][s] = metrics.slide_p95_mm(anim.joints_world[f"ankle_{s}"][a:b].astype(float), st, fps)
        out["source_slide_mm"][s] = metrics.slide_p95_mm(T[:, J[f"ankle_{s}"]], st, fps)
        for j in ("wrist", "ankle"):
            av = metrics.acceleration_p95(anim.joints_world[f"{j}_{s}"][a:b].astype(float), fps)
            src = metrics.acceleration_p95(T[:, J[f"{j}_{s}"]], fps) * k[j]
            out["accel_ratio"][f"{j}_{s}"] = round(av / max(src, 1e-9), 2)
            if limb_k is not None:
                limb = metrics.acceleration_p95(T[:, J[f"{j}_{s}"]], fps) * limb_k[j]
                out.setdefault("accel_ratio_limb_scaled", {})[f"{j}_{s}"] = round(av / max(limb, 1e-9), 2)
            # against the user's own joint, as the trackers give it (scaled): what the pipeline adds
            usr = metrics.acceleration_p95(user_pose.joint(f"{j}_{s}")[a:b], fps) * k[j]
            out["pipeline_gain"][f"{j}_{s}"] = round(av / max(usr, 1e-9), 2)
    if arm is not None:
        out.update(skin_figures(arm, avatar, anim, truth, k["ankle"]))
    out["hip_line_deg"] = measure.hip_line_deg(anim.joints_world["hip_l"][a:b], anim.joints_world["hip_r"][a:b],
                                               T[:, J["hip_l"]], T[:, J["hip_r"]])
    return out


def main(quick: bool = False, clips_extra=(), avatar_names=AVATARS, seeds=(), only_clips: bool = False):
    t0 = time.time()
    clips = _clips(list(clips_extra), only_clips)
    if quick:
        clips = clips[:1]
    avatars = _avatars(avatar_names[:1] if quick else avatar_names)
    workdir = Path(tempfile.mkdtemp(prefix="bodycal-real-"))
    calib, motion, notes = {}, {}, []
    runs = [(clip_path, seed) for ci, clip_path in enumerate(clips) for seed in (seeds or [ci])]
    for clip_path, ci in runs:
        clip = bvh.read(clip_path).resampled(FPS)
        perf = performer.Performer(clip)
        sess = session.build_session(perf, seed=ci)
        touched = session.build_session(perf, seed=ci, touches=True)
        sessions = {"full": sess, "six": touched, "six_without_touches": sess}
        for profile in (*PROFILES, "six_without_touches"):
            cap = capture.capture(sessions[profile], perf, "six" if profile.startswith("six") else profile, seed=ci)
            up = "Y" if ci % 2 == 0 else "Z"
            path = cap.write(workdir / f"{clip.name}_{profile}.bcrec.json", up=up)
            truth = cap.truth()
            rec = recording_io.load_recording(path)
            key = f"{clip.name}/seed{ci}/{profile}" if seeds else f"{clip.name}/{profile}"
            try:
                user = calibrate_user(rec)
            except BodyCalError as exc:
                calib[key] = {"error": str(exc)}
                continue
            ref = int(round(user.reference_time * FPS))
            calib[key] = {"joint_error_mm": measure.joint_errors_mm({j: v.world for j, v in user.joints.items()},
                                                                    truth["joints"], truth["positions"][ref]),
                          "yaw_deg": round(float(np.degrees(truth["yaw"])), 1), "file_up": up,
                          "warnings": user.calibration.get("warnings", [])}
            if profile not in PROFILES:
                continue  # calibration only
            filtered = filter_recording(rec, OneEuro())
            user_poses = {"raw": animate_user(rec, user), "filtered": animate_user(filtered, user)}
            for name, _arm, avatar in avatars:  # noqa: B007 (the armature: the skin figures)
                limb_k = _size_ratios(AvatarRig.from_model(avatar), truth, ref)
                eye_k = offsets.eye_height(avatar) / offsets.eye_height(user)
                for method in pl.METHODS:
                    for variant, take in (("raw", rec), ("filtered", filtered)):
                        try:
                            # in the room: the figures compare the avatar with the source there
                            anim = pl.retarget(take, user, avatar, method, placement="performer")
                        except BodyCalError as exc:
                            motion[f"{method}/{name}/{key}/{variant}"] = {"error": str(exc)}
                            continue
                        by_eye = method == "offsets"  # AvatarGo scales every position by the eye height
                        k = metrics.motion_scale(method, limb_k, eye_k)
                        motion[f"{method}/{name}/{key}/{variant}"] = motion_figures(
                            anim, avatar, truth, k, user_poses[variant], limb_k if by_eye else None,
                            arm=_arm if variant == "filtered" else None)
    out = {"bench": "real_motion", "clips": [p.stem for p in clips], "seeds": list(seeds) or None,
           "avatars": [a for a, *_ in avatars],
           "profiles": list(PROFILES), "noise": {"mm": 0.5, "deg": 0.3, "wobble_mm": 1.5},
           "calibration": calib, "targets": _targets(calib, motion), "motion": motion, "notes": notes,
           "seconds": round(time.time() - t0, 1)}
    print(json.dumps(out))
    return out


def _size_ratios(rig, truth, frame: int) -> dict[str, float]:
    """How much larger the avatar's limbs are than the source's at `frame` (metrics.limb_ratios)."""
    return metrics.limb_ratios(rig, dict(zip(truth["joints"], truth["positions"][frame])))


def _targets(calib, motion) -> dict:
    out = {}
    for tname, (profile, joints, limit) in JOINT_TARGETS.items():
        worst = [max(c["joint_error_mm"].get(j, np.inf) for j in joints) for key, c in calib.items()
                 if key.endswith(f"/{profile}") and "joint_error_mm" in c]
        failed = [key for key, c in calib.items() if key.endswith(f"/{profile}") and "error" in c]
        out[tname] = {"worst_mm": max(worst) if worst else None, "limit_mm": limit,
                      "met": bool(worst) and max(worst) <= limit and not failed}
    # for comparison, no target: the six devices without the pivots and touches (the defaults)
    plain = [max(c["joint_error_mm"].get(j, np.inf) for j in JOINT_TARGETS["hips_knees_ankles_shoulders_elbows_six"][1])
             for key, c in calib.items() if key.endswith("/six_without_touches") and "joint_error_mm" in c]
    out["six_without_touches_worst_mm"] = max(plain) if plain else None
    raw = [m for k, m in motion.items() if "error" not in m and k.endswith("/raw")]
    filt = [m for k, m in motion.items() if "error" not in m and k.endswith("/filtered")]
    hip = [m["hip_line_deg"]["max"] for m in raw]
    med = [m["sole_height_mm"][s]["median"] for m in raw for s in "lr" if m["sole_height_mm"][s]["median"] is not None]
    worst = [m["sole_height_mm"][s]["worst"] for m in raw for s in "lr" if m["sole_height_mm"][s]["worst"] is not None]
    slide = [m["slide_mm"][s] for m in raw for s in "lr" if m["slide_mm"][s] is not None]
    out["hip_line_le_5deg"] = {"worst_deg": max(hip) if hip else None, "met": bool(hip) and max(hip) <= 5.0}
    lowest, p95 = metrics.FOOT_SKIN_LOWEST_MM, metrics.SLIDE_P95_MM
    out["sole_median_within_5mm"] = {"range_mm": [min(med), max(med)] if med else None,
                                     "met": bool(med) and max(abs(v) for v in med) <= 5.0}
    out["sole_worst_ge_minus_10mm"] = {"worst_mm": min(worst) if worst else None,
                                       "met": bool(worst) and min(worst) >= lowest}
    out["slide_p95_le_2mm"] = {"worst_mm": max(slide) if slide else None, "met": bool(slide) and max(slide) <= p95}
    for variant, runs in (("raw", raw), ("filtered", filt)):
        acc = [v for m in runs for v in m["accel_ratio"].values()]
        gain = [v for m in runs for v in m["pipeline_gain"].values()]
        out[f"accel_le_1_3x_source_{variant}"] = {
            "worst_ratio": max(acc) if acc else None, "median_ratio": float(np.median(acc)) if acc else None,
            "met": bool(acc) and max(acc) <= metrics.ACCEL_RATIO}
        out[f"pipeline_gain_over_user_{variant}"] = {"worst": max(gain) if gain else None,
                                                     "median": float(np.median(gain)) if gain else None}
    # What the animator sees (the evaluated mesh) with the default settings (the devices smoothed).
    skin = [m for m in filt if "skin_height_mm" in m]
    med = [m["skin_height_mm"][s]["median"] for m in skin for s in m["skin_height_mm"]
           if m["skin_height_mm"][s]["median"] is not None]
    worst = [m["skin_height_mm"][s]["worst"] for m in skin for s in m["skin_height_mm"]
             if m["skin_height_mm"][s]["worst"] is not None]
    ratio = [v for m in skin for v in m["slide_ratio"].values()]
    out["skin_median_within_5mm"] = {"range_mm": [min(med), max(med)] if med else None,
                                     "met": bool(med) and max(abs(v) for v in med) <= 5.0}
    out["skin_worst_ge_minus_10mm"] = {"worst_mm": min(worst) if worst else None,
                                       "met": bool(worst) and min(worst) >= lowest}
    out["heel_ball_slide_le_1_5x_source"] = {"worst_ratio": max(ratio) if ratio else None,
                                             "median_ratio": float(np.median(ratio)) if ratio else None,
                                             "met": bool(ratio) and max(ratio) <= metrics.SLIDE_RATIO}
    # The hands of the fast-arm clips (DESIGN.md §5 "The hand's point"), per method, the default settings.
    fast = {p.stem for p in _clips([]) if p.parent.name == FAST_ARMS}
    hands = {}
    for k, m in motion.items():
        if "error" not in m and k.endswith("/filtered") and k.split("/")[2] in fast:
            wrists = [v for j, v in m["accel_ratio"].items() if j.startswith("wrist_")]
            hands.setdefault(k.split("/")[0], []).extend(wrists)
    # (the target is the egocentric method's; the others' worst beside it, for comparison)
    out["fast_arms_egocentric_wrist_accel_le_1_3x_source"] = {
        "clips": sorted(fast), "worst_ratio": {m: max(v) for m, v in hands.items()},
        "met": bool(hands.get("egocentric")) and max(hands["egocentric"]) <= metrics.ACCEL_RATIO}
    out["runs_failed"] = [k for k, m in motion.items() if "error" in m]
    return out


if __name__ == "__main__":
    bpy.ops.wm.read_factory_settings(use_empty=True)
    args = sys.argv[1:]

    def values(flag):
        if flag not in args:
            return []
        i = args.index(flag) + 1
        out = []
        while i < len(args) and not args[i].startswith("--"):
            out.append(args[i])
            i += 1
        return out

    main(quick="--quick" in args, clips_extra=values("--clips"), avatar_names=tuple(values("--avatars")) or AVATARS,
         seeds=tuple(int(v) for v in values("--seeds")), only_clips="--only-clips" in args)
