"""Benchmark of the user calibration (DESIGN.md §3): joint-centre error against ground truth.

Synthetic part: >= 6 performers (child to tall, thin to heavy) x 3 tracker noise levels (0.5, 1,
2 mm, with soft-tissue wobble and 10% outlier frames), full calibration profile. Per joint group,
median and 95th percentile of the joint-centre error (mm) at the reference time for
- `calibrated`: calibrate_user as shipped (repeated 2-sigma passes),
- `no_2sigma`: the same fits without the 2-sigma passes (and without the residual gate),
- `no_robust`: neither the 2-sigma passes nor the glitch-frame rejection,
- `sphere_anchors`: the anchor joints from the paper's sphere fit instead of the rigid point,
- `fixed_offsets`: one fixed tracker-to-joint offset per joint for everybody (the average
  performer's T-pose offsets in body axes: left, forward, up), i.e. what AvatarGo's exact offsets
  replace.
Also the hinge axes' angular error (degrees, with the sign: a flipped axis counts 180°).
Targets at 1 mm noise: median <= 5 mm for shoulders, hips, elbows, knees; <= 3 mm for wrists and
MCP joints.

Real part: the kineticstoolkit `walk.c3d` (Vicon Plug-in Gait, 100 Hz). The knee hinge is fitted
from the lateral malleolus marker in a thigh frame built from raw markers (walk_part) and placed
along the axis from the lateral knee marker and the measured knee width (the `knee_in` /
`knee_out` touches of our protocol); the reference is the file's LKJC / RKJC.

Also, for information: the minimal (AvatarGo, 6-device) profile at 1 mm noise.

Prints ONE JSON line.
"""

from __future__ import annotations

import json
import sys
import time
import zipfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from bodycal_addon.calibration import calibrate_user  # noqa: E402
from bodycal_addon.core import geometry, paths  # noqa: E402
from bodycal_addon.core import transforms as tf  # noqa: E402
from bodycal_addon.core.errors import BodyCalError  # noqa: E402
from bodycal_addon.core.geometry import fit_circle  # noqa: E402

GROUPS = {
    "shoulders": ("shoulder_l", "shoulder_r"), "hips": ("hip_l", "hip_r"), "elbows": ("elbow_l", "elbow_r"),
    "knees": ("knee_l", "knee_r"), "wrists": ("wrist_l", "wrist_r"),
    "mcps": tuple(f"mcp_{f}_{s}" for s in "lr" for f in ("thumb", "index", "middle", "ring", "pinky")),
    "ankles": ("ankle_l", "ankle_r"), "skull_base": ("skull_base",), "spine_root": ("spine_root",),
}
TARGETS_1MM = {"shoulders": 5.0, "hips": 5.0, "elbows": 5.0, "knees": 5.0, "wrists": 3.0, "mcps": 3.0}
PERFORMERS = (("child", 1.25), ("thin", 1.70), ("average", 1.75), ("heavy", 1.72), ("tall", 1.95),
              ("long_arms", 1.80))
NOISES = (0.5, 1.0, 2.0)


def _stats(errors: list[float]) -> dict:
    e = np.asarray(errors, float)
    if e.size == 0:
        return {"n": 0}
    return {"median": round(float(np.median(e)), 2), "p95": round(float(np.percentile(e, 95)), 2), "n": int(e.size)}


def _body_axes(rec):
    from bodycal_addon.calibration.common import Session, State
    from bodycal_addon.calibration.defaults import BodyFrame

    session = Session(rec)
    body = BodyFrame(session, State())
    return session, np.stack([body.left, body.forward, np.array([0.0, 0.0, 1.0])], axis=1)


def fixed_offsets_from(ref_rec, ref_truth) -> dict[str, tuple[str, np.ndarray]]:
    """The reference performer's tracker-to-joint vectors at its T-pose, in body axes (left,
    forward, up): the one-size-fits-all offsets a system without calibration assumes."""
    session, axes = _body_axes(ref_rec)
    out = {}
    for name, j in ref_truth.body_model().joints.items():
        if j.frame is not None and session.has(j.frame):
            out[name] = (j.frame, axes.T @ (ref_truth.joints_world[name] - session.ref_pose(j.frame)[0]))
    return out


def _fixed_offset_model(offsets, rec) -> dict[str, np.ndarray]:
    session, axes = _body_axes(rec)
    return {name: session.ref_pose(role)[0] + axes @ v for name, (role, v) in offsets.items() if session.has(role)}


def synthetic_part(quick: bool = False) -> dict:
    from bodycal_dev import synthetic

    performers = PERFORMERS[:2] if quick else PERFORMERS
    ref_perf = synthetic.make_performer(height=1.75, build="average", seed=100)
    ref_rec, ref_truth = synthetic.record_session(ref_perf, profile="full", motions=(), noise_mm=0.0, wobble_mm=0.0,
                                                  seed=100)
    offsets = fixed_offsets_from(ref_rec, ref_truth)
    results, failures, axis_err = {}, [], {}
    for noise in NOISES:
        axis_err[noise] = []
        errs = {m: {g: [] for g in GROUPS} for m in ("calibrated", "no_2sigma", "no_robust", "sphere_anchors",
                                                     "fixed_offsets")}
        for k, (build, height) in enumerate(performers):
            perf = synthetic.make_performer(height=height, build=build, seed=k)
            rec, truth = synthetic.record_session(perf, profile="full", motions=(), noise_mm=noise, wobble_mm=2.0,
                                                  outlier_rate=0.10, seed=10 * k + int(noise * 10))
            worlds = {}
            variants = (("calibrated", {}), ("no_2sigma", {"robust": False}),
                        ("no_robust", {"robust": False, "despike": False}), ("sphere_anchors", {"anchor": "sphere"}))
            for method, kw in variants:
                gate = geometry.RESIDUAL_GATE
                if not kw.get("robust", True):
                    geometry.RESIDUAL_GATE = float("inf")
                try:
                    model = calibrate_user(rec, **kw)
                    worlds[method] = {n: j.world for n, j in model.joints.items()}
                    if method == "calibrated":
                        tm = truth.body_model()
                        for b in ("forearm_l", "forearm_r", "shin_l", "shin_r"):
                            c = float(np.dot(model.bones[b].extra["right_local"], tm.bones[b].extra["right_local"]))
                            axis_err[noise].append(float(np.degrees(np.arccos(np.clip(c, -1.0, 1.0)))))
                except BodyCalError as exc:
                    failures.append(f"{build} {noise} mm {method}: {exc.line()}")
                finally:
                    geometry.RESIDUAL_GATE = gate
            worlds["fixed_offsets"] = _fixed_offset_model(offsets, rec)
            for method, w in worlds.items():
                for g, names in GROUPS.items():
                    for n in names:
                        if n in w and n in truth.joints_world:
                            errs[method][g].append(1000.0 * float(np.linalg.norm(w[n] - truth.joints_world[n])))
        results[f"noise_{noise:g}mm"] = {m: {g: _stats(v) for g, v in d.items()} for m, d in errs.items()}
    at1 = results.get("noise_1mm", {}).get("calibrated", {})
    targets = {g: {"target_mm": t, "median_mm": at1.get(g, {}).get("median"),
                   "met": bool(at1.get(g, {}).get("median") is not None and at1[g]["median"] <= t)}
               for g, t in TARGETS_1MM.items()}
    return {"performers": [f"{b} {h} m" for b, h in performers], "noise_mm": list(NOISES), "wobble_mm": 2.0,
            "outlier_rate": 0.10, "results": results, "targets_1mm": targets,
            "hinge_axis_deg": {f"noise_{n:g}mm": _stats(v) for n, v in axis_err.items()}, "failures": failures}


def minimal_part(quick: bool = False) -> dict:
    """The 6-device AvatarGo profile (HMD, controllers, pelvis and feet trackers) at 1 mm noise:
    what the T-pose, the touches and the anthropometric defaults give (for information)."""
    from bodycal_dev import synthetic

    errs = {g: [] for g in GROUPS}
    failures = []
    for k, (build, height) in enumerate(PERFORMERS[:2] if quick else PERFORMERS):
        perf = synthetic.make_performer(height=height, build=build, seed=k)
        rec, truth = synthetic.record_session(perf, profile="minimal", motions=(), noise_mm=1.0, wobble_mm=2.0,
                                              outlier_rate=0.10, seed=10 * k + 7)
        try:
            model = calibrate_user(rec)
        except BodyCalError as exc:
            failures.append(f"{build}: {exc.line()}")
            continue
        for g, names in GROUPS.items():
            for n in names:
                errs[g].append(1000.0 * float(np.linalg.norm(model.world(n) - truth.joints_world[n])))
    return {"noise_mm": 1.0, "calibrated": {g: _stats(v) for g, v in errs.items()}, "failures": failures}


# --- walk.c3d ---------------------------------------------------------------------------------


def _hinge_from_markers(point, frame_pos, frame_rot, out_marker, width, other_side):
    """Hinge centre in a moving frame by our method: circle of `point` in the frame (axis), joint =
    the lateral marker projected on the axis and moved half the width (+ the 7 mm marker radius)
    toward the other leg: the mean of `knee_out` / `knee_in` touches."""
    local = tf.inverse_transform_points(frame_pos, frame_rot, point)
    fit = fit_circle(local, name="walk knee hinge")
    axis = fit.normal
    lat = np.mean(tf.inverse_transform_points(frame_pos, frame_rot, out_marker), axis=0)
    on_axis = fit.center + ((lat - fit.center) @ axis) * axis
    mid_local = np.mean(tf.inverse_transform_points(frame_pos, frame_rot, other_side), axis=0)
    toward = np.sign((mid_local - on_axis) @ axis) * axis
    return on_axis + toward * (0.5 * width + 0.007), fit


def walk_part() -> dict:
    """Knee centres on the real walk.c3d. The shank marker ANK is recorded in a thigh frame (the
    circle is the same whichever of the two bones carries the frame): either the three raw thigh
    markers (THI, THI2, KNE) as a rigid body, or the model's femur axes. The file's KJC is the
    reference. The ankle is not evaluated: our ankle is the mean of the two malleolus touches and
    the file has only the lateral malleolus marker (its AJC is built from the ankle width the same
    way, so comparing would be circular)."""
    from bodycal_addon.recording.io.c3d import read_c3d

    z = paths.data_dir() / "markers" / "kineticstoolkit" / "walk.c3d.zip"
    if not z.exists():
        return {"skipped": f"{z} not found"}
    tmp = Path("/tmp/bodycal_bench_walk")
    tmp.mkdir(exist_ok=True)
    with zipfile.ZipFile(z) as zf:
        zf.extract("walk.c3d", tmp)
    d = read_c3d(tmp / "walk.c3d")
    scale = 0.001 if d.units.lower() == "mm" else 1.0
    P = d.points * scale

    def m(name):
        return P[:, d.labels.index(name)]

    out = {"frames": int(d.frame_count), "rate_hz": float(d.rate),
           "ankle": "not evaluated: no medial malleolus marker (see docstring)"}
    for S in ("L", "R"):
        other = "R" if S == "L" else "L"
        knee_w = float(np.ravel(d.param(f"PROCESSING:{S}KNEEWIDTH"))[0]) * scale
        flex = np.ptp(m(f"{S}KneeAngles")[:, 0] / scale) if f"{S}KneeAngles" in d.labels else None
        a, b, c = m(f"{S}THI"), m(f"{S}THI2"), m(f"{S}KNE")
        frames = {
            # three raw thigh markers as a rigid body, like a thigh tracker (10-16 cm apart)
            "raw_cluster": (c, tf.matrix_to_quat(tf.frame_from_axes(b - c, a - c))),
            # the Plug-in Gait femur axes (hip to knee, a long lever) carried by the thigh marker;
            # rigid with the femur, so the fitted axis is still the physical one
            "femur_axes": (a, tf.matrix_to_quat(tf.frame_from_axes(m(f"{S}FEP") - m(f"{S}FEO"),
                                                                   m(f"{S}FEL") - m(f"{S}FEO")))),
        }
        res = {"vicon_knee_flexion_range_deg": None if flex is None else round(float(flex), 1)}
        for label, (pos, rot) in frames.items():
            try:
                local, fit = _hinge_from_markers(m(f"{S}ANK"), pos, rot, c, knee_w, m(f"{other}KNE"))
            except BodyCalError as exc:
                res[label] = {"error": exc.line()}
                continue
            est = tf.transform_points(pos, rot, local)
            err = 1000.0 * np.linalg.norm(est - m(f"{S}KJC"), axis=1)
            ref_local = tf.inverse_transform_points(pos, rot, m(f"{S}KJC"))
            off = ref_local - fit.center
            off = off - (off @ fit.normal)[:, None] * fit.normal
            res[label] = {
                "median_mm": round(float(np.median(err)), 1), "p95_mm": round(float(np.percentile(err, 95)), 1),
                "ref_to_axis_mm": round(float(np.median(np.linalg.norm(off, axis=1)) * 1000), 1),
                "fit_rms_mm": round(fit.rms * 1000, 2), "kept": fit.kept, "of": fit.of,
                "fit_arc_deg": round(float(fit.range_deg), 1), "fit_radius_mm": round(fit.radius * 1000, 1)}
        out[f"knee_{S.lower()}"] = res
    return out


def main() -> int:
    t0 = time.perf_counter()
    quick = "--quick" in sys.argv
    report = {"benchmark": "calibration", "synthetic": synthetic_part(quick), "minimal_profile": minimal_part(quick),
              "walk_c3d": walk_part()}
    report["seconds"] = round(time.perf_counter() - t0, 1)
    print(json.dumps(report, separators=(",", ":")))
    return 0


if __name__ == "__main__":

    code = main()
    from bodycal_addon.blender.process import exit_now

    exit_now(code)
