"""Three points drive a whole body (DESIGN.md §6 "A lower body from head and hands"): a kit of HMD
and two controllers, its pelvis and feet estimated from them.

Part 1, truth: CMU clips (a walk, start-walk-stop, start-hop-stop; the held-out dance reported
beside, not in the targets) through `evaluation/` (an outside tool's recording: its own skeleton,
mounting, noise, dropouts, facing) with only the HMD and the controllers, calibrated from those
three (the session's T-pose and arm circles) and solved; against the clip's full body:
- the pelvis (the user's skeleton, step 1) against the clip's: median and p95 (mm), and the median
  of its vertical part (the anthropometric table's hip height against the clip skeleton's); the
  same landmark on both sides, the middle of the hip joint centres (`PELVIS_POINT`, printed); the
  error over the floor, how far the vertical part strays from its median, and the hips' standing
  height as a fraction of the stature, ours and the clip's;
- the pelvis's error split in the clip's body frame (`measure.pelvis_split`): its constant part
  forward / left / up, the motion about it, and what its p95 tail is (the trunk's lean and side
  tilt the clip has there beyond ours, the share of those frames moving and turning), and the error
  by its source (`by_source`: with the clip's trunk length, what the path's lean leaves; with the
  clip's trunk direction, what the calibration's proportions leave);
- the hands on their devices: how far beyond its arm's reach from the shoulder a controller puts
  the wrist (p95 mm; the estimated arm must reach what the controller holds); and the user's skull
  base and wrists against the clip's (the calibration, median mm);
- the pelvis's error with the reference time's offset taken out (the model's motion alone);
- steps: the feet's landings against the clip's (the same rule for both, on the ankle and the
  ball together: `measure.landings`), and how much the clip's floor rises along the walk (ours is
  flat: `measure.floor_along`);
- knees within their range (flexion 0-155 degrees, bending forward) and the legs apart (the
  shins never closer than `LEGS_APART` x stature, the two ankle radii);
- the feet on the avatar's evaluated mesh (the default settings) while the estimated foot stands:
  the lowest skin's median and worst (mm), and the heel / ball slide p95 against the clip's own
  during its stance, scaled like the legs;
and the same figures for a VRIK-like baseline (bodycal_dev/vrik_baseline.py: the pelvis a fixed
offset under the head, a foot stepping when 25 cm from its place), side by side.
- Contacts: the synthetic performer's contact motions (clap, a hand on the belly, on the head, on
  the thighs, a squat) with three devices (its calibration with the controllers' touches), the
  egocentric method's contact gap p95 on the avatar's evaluated mesh (mm).

Each clip is judged on a level floor: a motion-capture floor is not always level (02_01's rises
44 mm along its walk, 1.6 %; 131_01 25 mm, 131_03 11 mm, the dance 35 mm), while a VR take's is (the
headset's guardian) and the engine's floor is the calibration's, level: judged as recorded, the
clip's slope reads as the walker rising off the floor, its pelvis ends higher over our floor, the
legs straighten and the strides shorten (02_01: 7 steps against the walker's 5). So before anything
else the take is turned rigidly, devices and truth alike (one recording moves as a whole: every
distance and relative orientation kept), about a horizontal axis through the session's origin
(where the calibration stands and the clip starts), by the tilt fitted from the clip's OWN feet
(their stance lows: the source's floor, never our solve): `evaluation/level.py`. Printed beside:
the tilt (`floor_tilt_pct`), the rise as recorded (`clip_floor_rise_mm`) and after the turn
(`levelled_floor_rise_mm`), and the figures the turn moves as recorded (`as_recorded`: steps,
pelvis median / p95); the targets read the levelled take.

Part 2, real: every take of sample_data/real_vr (HMD and two Vive wands, no calibration steps) is
read, calibrated, retargeted with every method and baked (the bake's verification on the evaluated
rig): no NaN, verified, the feet on the floor and still while they stand, the longest path a heel or
ball skin point travels over the floor in one stay on it (`metrics.floor_travel_mm`, whatever the
estimated stance says: a foot held down while it moves skates), the controllers within
5 mm of their arms' reach (the user's skeleton), the avatar's wrists' acceleration p95 against the
wrists the controllers carry (scaled by the arms).

Prints ONE JSON line with `targets`. Run: .venv/bin/python benchmarks/bench_three_point.py [--quick] [--real-only]
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
from bodycal_addon.body.skeleton import JOINT_INDEX as JI  # noqa: E402
from bodycal_addon.calibration import calibrate_user  # noqa: E402
from bodycal_addon.calibration.defaults import RADII  # noqa: E402
from bodycal_addon.core import paths  # noqa: E402
from bodycal_addon.output import metrics  # noqa: E402
from bodycal_addon.recording import io as recording_io  # noqa: E402
from bodycal_addon.recording.filters import DEFAULT_FILTER, filter_recording  # noqa: E402
from bodycal_addon.retarget import lower_body, offsets  # noqa: E402
from bodycal_addon.retarget import pipeline as pl  # noqa: E402
from bodycal_addon.retarget.avatar_pose import AvatarRig  # noqa: E402
from bodycal_addon.retarget.user_animation import animate_user  # noqa: E402
from bodycal_dev import synthetic, vrik_baseline  # noqa: E402
from evaluation import bvh, capture, level, measure, performer, session  # noqa: E402

FPS = 90.0
CLIPS = (("cmu_bvh", "02_01_walk", True), ("cmu_bvh", "131_01_start_walk_stop", True),
         ("cmu_bvh_fast_arms", "131_03_start_hop_stop", False))
HELD_OUT = (("cmu_bvh_held_out", "05_06_dance", False),)
AVATAR = "child_10y"
REAL_AVATAR = "adult_male"
KNEE_MAX_DEG = 155.0
LEGS_APART = 2 * RADII["ankle"]  # x stature
CONTACT_MOTIONS = ("clap", "hand_on_belly", "hand_on_head", "hands_on_thighs", "squat")
ESTIMATORS = {"bodycal": lower_body.complete, "vrik_like": vrik_baseline.complete}
PELVIS_POINT = ("the middle of the two hip joint centres on both sides: ours the user skeleton's pelvis joint "
                "(its hips beside it), the clip's the heads of its thigh bones (evaluation/performer.py "
                "truth_positions), not its root, which sits 96-111 mm above them")


def _avatar():
    from bodycal_addon.blender.avatar_calibration import calibrate_avatar
    from sample_rigs import load_glb_avatar

    f = next(p for p in paths.shared_avatar_files() if p.name.startswith(AVATAR))
    with contextlib.redirect_stdout(io.StringIO()):  # the glTF importer talks: one JSON line only
        arm, _ = load_glb_avatar(f)
    return arm, calibrate_avatar(arm)


def three_point_take(clip_path: Path, seed: int, workdir: Path):
    """(recording, truth) of the clip recorded with HMD and controllers only, written Y up."""
    clip = bvh.read(clip_path).resampled(FPS)
    perf = performer.Performer(clip)
    cap = capture.capture(session.build_session(perf, seed=seed), perf, "three", seed=seed)
    path = cap.write(workdir / f"{clip.name}_three.bcrec.json", up="Y" if seed % 2 == 0 else "Z")
    return recording_io.load_recording(path), cap.truth()


def _estimated_stance(full, side: str, a: int, b: int) -> np.ndarray:
    """(b - a,) the estimated foot device standing still (planted)."""
    p, _, _ = full.pose(f"foot_{side}")
    v = np.linalg.norm(np.gradient(p[a:b, :2], axis=0), axis=1) * FPS
    return v < 0.02


def _floor_rise_mm(T: np.ndarray, Jt: dict) -> float:
    """How many mm the clip's floor rises along its walk (`measure.floor_along`, the motion's stances)."""
    _, slope, extent = measure.floor_along([T[:, [Jt[f"ankle_{s}"], Jt[f"toe_{s}"]]] for s in "lr"], FPS)
    return round(slope * extent * 1000, 1)


def _as_recorded(rec, truth, complete) -> dict:
    """The figures the levelling moves, of the take as recorded (its floor sloped): the steps and
    the pelvis error (median, p95 mm)."""
    a, b = truth["motion"]
    T = truth["positions"][a:b]
    Jt = {n: i for i, n in enumerate(truth["joints"])}
    user = calibrate_user(rec)
    pose = animate_user(complete(filter_recording(rec, DEFAULT_FILTER), user), user)
    e = np.linalg.norm(pose.joints[a:b, JI["pelvis"]] - T[:, Jt["pelvis"]], axis=1) * 1000
    return {"steps": sum(measure.landings(pose.joints[a:b, [JI[f"ankle_{s}"], JI[f"toe_{s}"]]], FPS) for s in "lr"),
            "pelvis_mm": {"median": round(float(np.median(e)), 1), "p95": round(float(np.percentile(e, 95)), 1)}}


def _hands_in_reach(user, pose, a: int, b: int) -> float:
    """p95 (mm) of how far the controllers put the wrists beyond the arm's reach from its shoulder
    (the user's skeleton, step 1: an arm estimated too short for the controllers leaves the
    avatar's hands short of them; the wrists themselves ride on the controllers)."""
    over = []
    for s in "lr":
        arm = user.bones[f"upperarm_{s}"].length + user.bones[f"forearm_{s}"].length
        d = np.linalg.norm(pose.joints[a:b, JI[f"wrist_{s}"]] - pose.joints[a:b, JI[f"shoulder_{s}"]], axis=1)
        over.append(np.maximum(d - arm, 0.0))
    return round(float(np.percentile(np.concatenate(over), 95)) * 1000, 2)


def _knees_and_legs(pose, a: int, b: int, stature: float) -> dict:
    J = pose.joints[a:b]
    flex, forward_ok, gap = [], [], []
    for s in "lr":
        hip, knee, ankle, toe = (J[:, JI[f"{n}_{s}"]] for n in ("hip", "knee", "ankle", "toe"))
        u, v = knee - hip, ankle - knee
        cos = np.einsum("fi,fi->f", u, v) / np.maximum(np.linalg.norm(u, axis=1) * np.linalg.norm(v, axis=1), 1e-9)
        flex.append(np.degrees(np.arccos(np.clip(cos, -1, 1))))
        # the knee in front of the hip-ankle line, the way the foot points (no hyperextension)
        line = ankle - hip
        off = knee - hip - (np.einsum("fi,fi->f", knee - hip, line) / np.maximum(
            np.einsum("fi,fi->f", line, line), 1e-9))[:, None] * line
        along = toe - ankle
        forward_ok.append(np.einsum("fi,fi->f", off, along) >= -0.005)
    for t in np.linspace(0, 1, 5):
        pl_ = J[:, JI["knee_l"]] + t * (J[:, JI["ankle_l"]] - J[:, JI["knee_l"]])
        for u in np.linspace(0, 1, 5):
            pr_ = J[:, JI["knee_r"]] + u * (J[:, JI["ankle_r"]] - J[:, JI["knee_r"]])
            gap.append(np.linalg.norm(pl_ - pr_, axis=1))
    gap = np.min(gap, axis=0)
    return {"knee_flex_max_deg": round(float(np.max(flex)), 1),
            "knee_bent_backward_frames": int(np.sum(~np.all(forward_ok, axis=0))),
            "shins_apart_min_mm": round(float(gap.min()) * 1000, 1),
            "shins_apart_limit_mm": round(LEGS_APART * stature * 1000, 1)}


def _skin(arm, avatar, anim, full, truth, leg_k: float) -> dict:
    a, b = truth["motion"]
    Jt = {n: i for i, n in enumerate(truth["joints"])}
    T = truth["positions"][a:b]
    skin = mesh_metrics.foot_skin(arm, avatar, anim, np.arange(a, b))
    out = {"skin_mm": {}, "slide_ratio": {}}
    for s, sk_ in skin.items():
        on = _estimated_stance(full, s, a, b)
        low = sk_["low"][on] * 1000
        out["skin_mm"][s] = ({"median": round(float(np.median(low)), 1), "worst": round(float(low.min()), 1)}
                             if low.size else {"median": None, "worst": None})
        for part, joint in (("heel", "ankle"), ("ball", "toe")):
            mine = metrics.slide_p95_mm(sk_[part], on, FPS)
            src_on = metrics.ground_contact(T[:, Jt[f"{joint}_{s}"]], FPS)
            src = metrics.slide_p95_mm(T[:, Jt[f"{joint}_{s}"]], src_on, FPS)
            if mine is not None and src:
                out["slide_ratio"][f"{part}_{s}"] = round(mine / (src * leg_k), 2)
    return out


def truth_part(arm, avatar, workdir: Path, quick: bool) -> dict:
    data = paths.data_dir()
    clips = CLIPS[:1] if quick else CLIPS + HELD_OUT
    out = {}
    for seed, (folder, name, walk) in enumerate(clips):
        recorded = three_point_take(data / "motion" / folder / f"{name}.bvh", seed, workdir)
        # judged on a level floor, as every VR take's is: the take turned rigidly, devices and
        # truth alike, so that the clip's own feet stand level (evaluation/level.py)
        rec, truth, tilt = level.level_take(*recorded, FPS)
        user = calibrate_user(rec)
        a, b = truth["motion"]
        T = truth["positions"][a:b]
        Jt = {n: i for i, n in enumerate(truth["joints"])}
        leg_k = 1.0 / float(np.mean([np.linalg.norm(T[0, Jt[f"hip_{s}"]] - T[0, Jt[f"ankle_{s}"]]) for s in "lr"]))
        for est, complete in ESTIMATORS.items():
            full = complete(filter_recording(rec, DEFAULT_FILTER), user)
            pose = animate_user(full, user)
            d = pose.joints[a:b, JI["pelvis"]] - T[:, Jt["pelvis"]]
            e = np.linalg.norm(d, axis=1) * 1000
            # the same with the offset of the reference time taken out: the model's motion alone
            # (the offset is the calibration's anthropometric table against the clip's skeleton)
            ref = int(round(user.reference_time * FPS))
            moved = np.linalg.norm(d - (pose.joints[ref, JI["pelvis"]] - truth["positions"][ref, Jt["pelvis"]]),
                                   axis=1) * 1000
            floor = np.linalg.norm(d[:, :2], axis=1) * 1000
            stature = lower_body.LowerBodyShape.of(user).stature  # what the estimate scales by
            fig = {"pelvis_mm": {"median": round(float(np.median(e)), 1), "p95": round(float(np.percentile(e, 95)), 1),
                                 "vertical_median": round(float(np.median(d[:, 2])) * 1000, 1),
                                 # how far the height's error strays from its constant (the pelvis
                                 # dropping and rising with the walker's), and the error over the floor
                                 "vertical_spread_p95": round(float(np.percentile(
                                     np.abs(d[:, 2] - np.median(d[:, 2])), 95)) * 1000, 1),
                                 "over_floor_median": round(float(np.median(floor)), 1),
                                 "over_floor_p95": round(float(np.percentile(floor, 95)), 1),
                                 "motion_median": round(float(np.median(moved)), 1),
                                 "motion_p95": round(float(np.percentile(moved, 95)), 1)},
                   # the hip joints' height standing (the reference time), x the stature the HMD gives:
                   # ours the anthropometric table's, the clip's its skeleton's
                   "hips_height_x_stature": {
                       "ours": round(float(pose.joints[ref, JI["pelvis"], 2]) / stature, 3),
                       "clip": round(float(truth["positions"][ref, Jt["pelvis"], 2]) / stature, 3)},
                   "calibrated_mm": {j: round(float(np.median(np.linalg.norm(pose.joints[a:b, JI[j]] - T[:, Jt[j]],
                                                                             axis=1))) * 1000, 1)
                                     for j in ("skull_base", "wrist_l", "wrist_r")},
                   "steps": {"ours": sum(measure.landings(pose.joints[a:b, [JI[f"ankle_{s}"], JI[f"toe_{s}"]]], FPS)
                                         for s in "lr"),
                             "truth": sum(measure.landings(T[:, [Jt[f"ankle_{s}"], Jt[f"toe_{s}"]]], FPS)
                                          for s in "lr"),
                             "walk": walk},
                   # the pelvis's error split in the clip's body frame: its constant, its motion, its tail
                   "pelvis_split": measure.pelvis_split(
                       {j: pose.joints[a:b, JI[j]] for j in ("pelvis", "skull_base")},
                       {j: T[:, Jt[j]] for j in ("pelvis", "skull_base", "hip_l", "hip_r", "ankle_l", "ankle_r",
                                                 "toe_l", "toe_r")}, FPS),
                   # the clip's floor as recorded: how much it rises along the walk (its balls' lowest
                   # per stance), the tilt the levelling took out, and what is left of the rise after it
                   "clip_floor_rise_mm": _floor_rise_mm(recorded[1]["positions"][a:b], Jt),
                   "floor_tilt_pct": round(float(np.tan(tilt)) * 100, 2),
                   "levelled_floor_rise_mm": _floor_rise_mm(T, Jt),
                   "as_recorded": _as_recorded(*recorded, complete),
                   **_knees_and_legs(pose, a, b, stature)}
            anim = pl.retarget(full, user, avatar, "egocentric", placement="performer")
            fig.update(_skin(arm, avatar, anim, full, truth, AvatarRig.from_model(avatar).leg_length() * leg_k))
            fig["hands_beyond_reach_p95_mm"] = _hands_in_reach(user, pose, a, b)
            fig["held_out"] = (folder, name, walk) in HELD_OUT
            out[f"{name}/{est}"] = fig
    return out


def contact_part(arm, avatar, quick: bool) -> dict:
    """The synthetic performer's contact motions with HMD and controllers only."""
    perf = synthetic.make_performer(height=1.75, build="average", seed=1)
    rec, truth = synthetic.record_session(perf, profile="minimal", motions=CONTACT_MOTIONS, seed=1)
    keep = [i for i, d in enumerate(rec.devices) if d.role in ("head", "hand_l", "hand_r")]
    rec3 = _only(rec, keep)
    user = calibrate_user(rec3)
    anim = pl.retarget(filter_recording(rec3, DEFAULT_FILTER), user, avatar, "egocentric")
    contacts = [c for c in truth.contacts if c["effector"].split("_")[0] in ("palm", "wrist", "tip")]
    gaps = mesh_metrics.contact_gaps(arm, avatar, anim, contacts, max_frames=8 if quick else 12)
    by_motion = {}
    for c, g in zip(contacts, gaps):
        by_motion.setdefault(c["motion"], []).append(g)
    every = np.concatenate(gaps) if gaps else np.array([np.nan])
    return {"contact_gap_mm": metrics.stats_mm(every),
            "by_motion_p95_mm": {m: metrics.stats_mm(np.concatenate(v))["p95"] for m, v in by_motion.items()}}


def _only(rec, keep):
    from dataclasses import replace

    return replace(rec, devices=[rec.devices[i] for i in keep], positions=rec.positions[:, keep],
                   rotations=rec.rotations[:, keep], valid=rec.valid[:, keep])


def real_part(quick: bool) -> dict:
    """Every real three-point take of the sample data, onto the adult avatar with every method,
    computed and baked as a bake is (the verification on the evaluated rig included)."""
    from bodycal_addon.blender import session as sess
    from bodycal_addon.blender.avatar_calibration import calibrate_avatar
    from bodycal_addon.retarget.takes import RecordingTake
    from sample_rigs import load_glb_avatar

    takes = sorted((paths.data_dir() / "real_vr").glob("*/*.json")) + \
        sorted((paths.data_dir() / "real_vr").glob("*/*.bsor"))
    if quick:
        takes = takes[:1]
    out = {}
    for path in takes:
        bpy.ops.wm.read_factory_settings(use_empty=True)
        with contextlib.redirect_stdout(io.StringIO()):
            arm, _ = load_glb_avatar(next(p for p in paths.shared_avatar_files() if p.name.startswith(REAL_AVATAR)))
        avatar = calibrate_avatar(arm)
        target = sess.Target(arm, avatar, True)
        rec = recording_io.load_recording(path)
        user = calibrate_user(rec)
        take = RecordingTake(rec, user)  # the default settings: the devices smoothed
        full = lower_body.complete(filter_recording(rec, DEFAULT_FILTER), user)
        pose = animate_user(full, user)
        fig = {"frames": rec.frame_count, "seconds": round(float(rec.time[-1] - rec.time[0]), 1),
               "hmd_height_m": [round(float(v), 2) for v in np.percentile(rec.positions[:, 0, 2], [1, 99])],
               "steps": sum(measure.landings(pose.joints[:, [JI[f"ankle_{s}"], JI[f"toe_{s}"]]], rec.fps)
                            for s in "lr"),
               "hands_beyond_reach_p95_mm": _hands_in_reach(user, pose, 0, rec.frame_count), "methods": {}}
        arm_k = _arm(avatar) / float(np.mean([user.bones[f"upperarm_{s}"].length + user.bones[f"forearm_{s}"].length
                                             for s in "lr"]))
        eye_k = offsets.eye_height(avatar) / offsets.eye_height(user)
        user_wrists = [metrics.acceleration_p95(pose.joints[:, JI[f"wrist_{s}"]], rec.fps) for s in "lr"]
        for method in pl.METHODS:
            got = {}
            try:
                computed = sess.compute(take, target, sess.Settings(method))
                sess.bake(take, target, computed)  # raises when the evaluated rig does not show the keys
                got["verified"] = True
            except Exception as exc:  # the figure: what failed, the others still measured
                got["verified"], got["error"] = False, str(exc)[:200]
                out.setdefault(path.name, fig)["methods"][method] = got
                continue
            anim = computed.animation
            got["finite"] = bool(np.isfinite(anim.rotations).all() and np.isfinite(anim.root_location).all())
            skin = mesh_metrics.foot_skin(arm, avatar, anim, np.arange(rec.frame_count))
            for s, sk_ in skin.items():
                on = _estimated_stance(full, s, 0, rec.frame_count)
                low = sk_["low"][on] * 1000
                got[f"skin_{s}_mm"] = {"median": round(float(np.median(low)), 1), "worst": round(float(low.min()), 1)}
                got[f"slide_{s}_p95_mm"] = max(metrics.slide_p95_mm(sk_[part], on, rec.fps) or 0.0
                                               for part in ("heel", "ball"))
            # what the animator sees whatever the stance: a skin point's longest skate over the floor
            got["floor_travel_max_mm"] = max(metrics.floor_travel_mm(sk_[part]) for sk_ in skin.values()
                                             for part in ("heel", "ball"))
            # against the wrist as the controllers carry it (the user's, from the same smoothed devices;
            # the controller's own origin moves less than the wrist it turns about), scaled as the method
            # scales motion (metrics.motion_scale: offsets by the eye heights, the others by the arms)
            k = metrics.motion_scale(method, {"wrist": arm_k, "ankle": arm_k}, eye_k)["wrist"]
            ratios = [metrics.acceleration_p95(anim.joints_world[f"wrist_{s}"].astype(float), rec.fps) / (u * k)
                      for s, u in zip("lr", user_wrists, strict=True)]
            got["wrist_accel_ratio"] = round(float(max(ratios)), 2)
            got["wrist_accel_ratio_unscaled"] = round(float(max(r * k for r in ratios)), 2)
            fig["methods"][method] = got
        out[path.name] = fig
    return out


def _arm(avatar) -> float:
    rig = AvatarRig.from_model(avatar)
    a = rig.joint_world
    return float(np.mean([np.linalg.norm(a[JI[f"elbow_{s}"]] - a[JI[f"shoulder_{s}"]])
                          + np.linalg.norm(a[JI[f"wrist_{s}"]] - a[JI[f"elbow_{s}"]]) for s in "lr"]))


def targets(truth: dict, contacts: dict, real: dict | None = None) -> dict:
    ours = {k: v for k, v in truth.items() if k.endswith("/bodycal") and not v["held_out"]}
    out = {}
    if ours:
        med = max(v["pelvis_mm"]["median"] for v in ours.values())
        p95 = max(v["pelvis_mm"]["p95"] for v in ours.values())
        out["pelvis_median_le_60mm"] = med <= 60.0
        out["pelvis_p95_le_120mm"] = p95 <= 120.0
        walks = [v["steps"] for v in ours.values() if v["steps"]["walk"]]
        out["steps_within_20pct_on_walks"] = all(abs(s["ours"] - s["truth"]) <= 0.2 * s["truth"] for s in walks)
        out["knees_within_range"] = all(v["knee_flex_max_deg"] <= KNEE_MAX_DEG and v["knee_bent_backward_frames"] == 0
                                        for v in ours.values())
        out["legs_apart"] = all(v["shins_apart_min_mm"] >= v["shins_apart_limit_mm"] for v in ours.values())
        skin = [m for v in ours.values() for m in v["skin_mm"].values() if m["median"] is not None]
        out["skin_median_within_5mm"] = bool(skin) and all(abs(m["median"]) <= 5.0 for m in skin)
        ratio = [r for v in ours.values() for r in v["slide_ratio"].values()]
        out["heel_ball_slide_le_1_5x_source"] = bool(ratio) and max(ratio) <= 1.5
        out["hands_within_reach_5mm"] = all(v["hands_beyond_reach_p95_mm"] <= 5.0 for v in ours.values())
    if contacts:
        out["contact_p95_le_10mm"] = contacts["contact_gap_mm"]["p95"] <= 10.0
    if real:
        runs = [m for t in real.values() for m in t["methods"].values()]
        out["real_verified_every_method"] = all(m.get("verified") and m.get("finite") for m in runs)
        skins = [m[f"skin_{s}_mm"]["median"] for m in runs if m.get("verified") for s in "lr"]
        out["real_feet_on_the_floor_5mm"] = bool(skins) and max(abs(v) for v in skins) <= 5.0
        slides = [m[f"slide_{s}_p95_mm"] for m in runs if m.get("verified") for s in "lr"]
        out["real_no_slide_past_2mm"] = bool(slides) and max(slides) <= 2.0
        out["real_hands_within_reach_5mm"] = all(t["hands_beyond_reach_p95_mm"] <= 5.0 for t in real.values())
        acc = [m["wrist_accel_ratio"] for m in runs if m.get("verified")]
        out["real_wrist_accel_le_1_3x_controllers"] = bool(acc) and max(acc) <= 1.3
    return out


def main(quick: bool = False, real_only: bool = False):
    t0 = time.time()
    truth, contacts = {}, {}
    if not real_only:
        arm, avatar = _avatar()
        workdir = Path(tempfile.mkdtemp(prefix="bodycal-three-"))
        truth = truth_part(arm, avatar, workdir, quick)
        contacts = contact_part(arm, avatar, quick)
    real = real_part(quick)
    out = {"bench": "three_point", "avatar": AVATAR, "real_avatar": REAL_AVATAR, "pelvis_point": PELVIS_POINT,
           "truth": truth, "contacts": contacts,
           "real": real, "targets": targets(truth, contacts, real), "seconds": round(time.time() - t0, 1)}
    print(json.dumps(out))
    return out


if __name__ == "__main__":
    bpy.ops.wm.read_factory_settings(use_empty=True)
    main(quick="--quick" in sys.argv, real_only="--real-only" in sys.argv)
