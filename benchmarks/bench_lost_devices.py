"""Lost devices (DESIGN.md §6 "Lost devices"): how far a device's pose is from where it really was
during a gap, per way of filling it and per gap length, on recordings an outside tool made from
real motion (`evaluation/`: CMU clips, the full profile's 15 devices at random mountings, 0.5 mm /
0.3 degree noise, soft tissue, no dropouts of its own). Gaps of each length are cut into every
device at random places in the clip (never two in one device closer than 0.5 s, the carriers
tracked), and filled:

- bake (both ends known): `hold` (the last pose), `linear` (line and slerp), `hermite` (cubic
  Hermite at the device's own velocity, `gaps.fill_gaps`), `ride` (the device's pose in its
  carrier's frame blended from one end's to the other's, `gaps.ride_gaps`; carriers from
  `retarget.trackers.CARRIERS`: the thighs and the chest on the pelvis, the shins on the feet, the
  upper arms on the chest, the forearms on the hands, the pelvis on the HMD's heading);
- live (causal): `hold`, `extrapolate` (the last velocity decaying with 0.05 / 0.1 s,
  `gaps.extrapolate_gaps`), `ride` (the relation at the gap's start held).

Figures per gap length: position error (mm) and rotation error (degrees), mean over the gap's
frames and p95 over gaps, every device pooled; the limb trackers and the pelvis also apart.

Prints ONE JSON line. Run: .venv/bin/python benchmarks/bench_lost_devices.py [--quick]
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

import numpy as np  # noqa: E402

from bodycal_addon.core import paths  # noqa: E402
from bodycal_addon.core.transforms import matrix_to_quat, quat_angle, quat_conj, quat_mul  # noqa: E402
from bodycal_addon.recording import gaps  # noqa: E402
from bodycal_addon.retarget.trackers import carrier_poses  # noqa: E402
from evaluation import bvh, capture, performer, session  # noqa: E402

FPS = 90.0
GAPS_S = (0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.7, 1.0, 2.0)
LIMB = ("thigh", "shin", "upperarm", "forearm", "chest")


def _cut(rng, F: int, roles, lo: int, hi: int, n: int, gapped) -> np.ndarray:
    """(F, D) valid flags with gaps of `n` frames in the columns of `gapped` roles, spaced by at
    least 0.5 s, inside frames [lo, hi)."""
    valid = np.ones((F, len(roles)), bool)
    step = n + int(0.5 * FPS)
    for d, r in enumerate(roles):
        if not gapped(r):
            continue
        start = lo + int(rng.integers(0, step))
        while start + n + 1 < hi:
            valid[start:start + n, d] = False
            start += step + int(rng.integers(0, step))
    return valid


def _errors(pos, quat, true_pos, true_quat, valid, roles) -> dict:
    """Per role group: mean error over each gap's frames (mm, degrees), pooled as (mean, p95)."""
    out = {}
    miss = ~valid
    start = miss & ~np.concatenate([np.zeros((1, miss.shape[1]), bool), miss[:-1]])
    gap_id = np.cumsum(start, axis=0) * miss
    de = np.linalg.norm(pos - true_pos, axis=-1) * 1000
    ae = np.degrees(quat_angle(quat_mul(quat_conj(true_quat), quat)))
    groups = {"all": roles, "limb": [r for r in roles if r.rsplit("_", 1)[0] in LIMB], "pelvis": ["pelvis"]}
    for g, members in groups.items():
        cols = [roles.index(r) for r in members if r in roles]
        per_gap_d, per_gap_a = [], []
        for c in cols:
            ids = gap_id[:, c]
            k = ids[miss[:, c]]
            if not len(k):
                continue
            cnt = np.bincount(k)[1:]
            per_gap_d.append(np.bincount(k, de[miss[:, c], c])[1:][cnt > 0] / cnt[cnt > 0])
            per_gap_a.append(np.bincount(k, ae[miss[:, c], c])[1:][cnt > 0] / cnt[cnt > 0])
        if per_gap_d:
            d, a = np.concatenate(per_gap_d), np.concatenate(per_gap_a)
            out[g] = {"mm": [round(float(d.mean()), 1), round(float(np.percentile(d, 95)), 1)],
                      "deg": [round(float(a.mean()), 2), round(float(np.percentile(a, 95)), 2)], "gaps": len(d)}
    return out


def _fill(kind: str, t, pos, quat, valid, roles):
    p, q, v = pos.copy(), quat.copy(), valid.copy()
    if kind == "hold":
        gaps.hold_untracked(p, v, q)
    elif kind in ("linear", "hermite"):
        gaps.fill_gaps(t, p, v, np.inf, q, linear=kind == "linear")
    elif kind.startswith("ride"):
        cp, cq = carrier_poses(roles, p, q)
        gaps.ride_gaps(t, p, v, q, cp, cq, causal=kind == "ride_live")
    elif kind.startswith("extrapolate"):
        gaps.extrapolate_gaps(t, p, v, q, float(kind.split("_")[1]))
    return p, q


def main(quick: bool = False):
    t0 = time.time()
    d = paths.data_dir()
    clips = sorted((d / "motion" / "cmu_bvh").glob("*.bvh")) + [d / "motion" / "cmu_bvh_held_out" / "05_06_dance.bvh"]
    clips = clips[:1] if quick else clips
    kinds = {"bake": ("hold", "linear", "hermite", "ride"),
             "live": ("hold", "extrapolate_0.05", "extrapolate_0.1", "ride_live")}
    results = {}
    for ci, clip_path in enumerate(clips):
        perf = performer.Performer(bvh.read(clip_path).resampled(FPS))
        sess = session.build_session(perf, seed=ci)
        cap = capture.capture(sess, perf, "full", seed=ci, dropouts_per_s=0.0)
        roles = [m.role for m in cap.mounts]
        pos, quat = cap.positions, matrix_to_quat(cap.rotations)
        t = np.arange(len(pos)) / FPS
        lo, hi = cap.session.motion
        rng = np.random.default_rng(ci)
        for gap_s in GAPS_S:
            n = max(1, int(round(gap_s * FPS)))
            for part, gapped in (("limbs", lambda r: r.rsplit("_", 1)[0] in LIMB), ("pelvis", lambda r: r == "pelvis")):
                valid = _cut(rng, len(pos), roles, lo, hi, n, gapped)
                for mode, ks in kinds.items():
                    for k in ks:
                        p, q = _fill(k, t, pos, quat, valid, roles)
                        for g, e in _errors(p, q, pos, quat, valid, roles).items():
                            if g == "all" or (g == "limb") == (part == "limbs"):
                                results.setdefault(f"{mode}/{k}/{g}/{gap_s:g}", []).append(e)
    out = {}
    for key, es in results.items():  # pooled over clips: mean of means, worst p95
        out[key] = {"mm": [round(float(np.mean([e["mm"][0] for e in es])), 1), max(e["mm"][1] for e in es)],
                    "deg": [round(float(np.mean([e["deg"][0] for e in es])), 2), max(e["deg"][1] for e in es)],
                    "gaps": sum(e["gaps"] for e in es)}
    print(json.dumps({"bench": "lost_devices", "clips": [p.stem for p in clips], "gaps_s": list(GAPS_S),
                      "figures": "mean over a gap's frames: [mean over gaps, p95 over gaps]", "errors": out,
                      "seconds": round(time.time() - t0, 1)}))


if __name__ == "__main__":
    main(quick="--quick" in sys.argv[1:])
