"""Bézier keys against linear ones (FORMATS.md §4.2, "Bézier keys"). Prints ONE JSON line.

The sample recording (`sample_rigs/recordings/demo_full.bcrec.json`) retargeted onto the procedural
avatar with each method, raw and with the One Euro filter; its rotations reduced at the default
0.1 degree for LINEAR keys, then:
- `same_keys`: those keys as Bézier keys with Blender's Auto Clamped handles (output/bezier.py, the
  curve Blender evaluates, checked against Blender in tests/blender/test_output.py): the rotation
  error at every frame (max, p99, share of bone-frames over the tolerance, degrees) and the joint
  deviation from the every-frame bake through the rig's FK (max, p99, mm), against the linear keys';
- `bezier_keys`: the Bézier-aware reduction (keyreduce's `bezier=True`): the keys it adds to
  bring every frame within the tolerance (share of the linear keys), its error and deviation, and
  the time it takes.

Run: .venv/bin/python benchmarks/bench_bezier.py
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import numpy as np  # noqa: E402

from bodycal_addon.calibration import calibrate_user  # noqa: E402
from bodycal_addon.core.transforms import continuous_quaternions  # noqa: E402
from bodycal_addon.output import bezier, keyreduce  # noqa: E402
from bodycal_addon.recording import io as recording_io  # noqa: E402
from bodycal_addon.recording.filters import OneEuro, filter_recording  # noqa: E402
from bodycal_addon.retarget import pipeline as pl  # noqa: E402
from bodycal_addon.retarget.avatar_pose import AvatarRig  # noqa: E402
from bodycal_dev import retarget_fixtures as rt  # noqa: E402

TOL_DEG = keyreduce.DEFAULT_TOLERANCE_DEG
SAMPLE = REPO / "sample_rigs" / "recordings" / "demo_full.bcrec.json"


def _linear(keep, values):
    frames = np.arange(keep.shape[0], dtype=float)
    return np.stack([keyreduce.interpolate(frames, keep[:, k], values[:, k]) for k in range(keep.shape[1])], axis=1)


def _figures(anim, rig, q, approx) -> dict:
    approx = approx / np.linalg.norm(approx, axis=-1, keepdims=True)
    err = np.degrees(keyreduce.rotation_error(q, approx))
    full = rig.fk(rig.basis_of(anim.bone_names, q), anim.root_location).joints
    drawn = rig.fk(rig.basis_of(anim.bone_names, approx), anim.root_location).joints
    dev = np.linalg.norm(full - drawn, axis=-1) * 1000
    return {"error_deg_max": round(float(err.max()), 3), "error_deg_p99": round(float(np.percentile(err, 99)), 3),
            "over_tolerance": round(float((err > TOL_DEG * (1 + 1e-6)).mean()), 4),
            "joint_deviation_mm_max": round(float(dev.max()), 2),
            "joint_deviation_mm_p99": round(float(np.percentile(dev, 99)), 2)}


def take_figures(anim, avatar) -> dict:
    rig = AvatarRig.from_model(avatar)
    q = continuous_quaternions(anim.rotations)
    keep, values = keyreduce.rotation_keys(q, np.radians(TOL_DEG))
    t0 = time.perf_counter()
    bkeep, bvalues = keyreduce.rotation_keys(q, np.radians(TOL_DEG), bezier=True)
    seconds = time.perf_counter() - t0
    refined = _figures(anim, rig, q, bezier.evaluate_keys(bkeep, bvalues))
    return {"frames": anim.frame_count, "bones": q.shape[1], "linear_keys": int(keep.sum()),
            "linear": _figures(anim, rig, q, _linear(keep, values)),
            "same_keys": _figures(anim, rig, q, bezier.evaluate_keys(keep, values)),
            "bezier_keys": {"keys": int(bkeep.sum()), "added": round(float(bkeep.sum() / keep.sum() - 1), 4),
                            "seconds": round(seconds, 2), **refined}}


def main() -> None:
    rec = recording_io.load_recording(SAMPLE)
    user = calibrate_user(rec)
    avatar = rt.procedural_avatar()
    out = {}
    for label, r in (("raw", rec), ("filtered", filter_recording(rec, OneEuro()))):
        for method in pl.METHODS:
            out[f"{method}_{label}"] = take_figures(pl.retarget(r, user, avatar, method), avatar)
    print(json.dumps({"benchmark": "bezier", "tolerance_deg": TOL_DEG, "sample": SAMPLE.name, **out}))


if __name__ == "__main__":
    main()
