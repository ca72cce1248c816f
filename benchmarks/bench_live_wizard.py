"""Live calibration wizard benchmark (recording/live/wizard.py; DESIGN.md "Live calibration wizard"):
one JSON line with two sections.

`demo`: the sample take (sample_rigs/recordings/demo_full.bcrec.json) fed frame by frame to a
LiveRecorder, each step begun at its segment's start and ended by the wizard itself: per step kind
the time it took against the take's segment (median and max of the ratio), the steps that did not
complete inside their segment, and the body model calibrated from the live recording against the
take's own (mm per joint: max and median).

`six`: the same with the take cut to AvatarGo's six devices (HMD, hands, pelvis, feet) and no
marker: the flexes and swings fitted from the end devices.

`six_touches`: an outside recording of the six devices with the controller pivots and touches
(evaluation/touching.py on CMU 02_01, session 0; DESIGN.md §3 "Touches with six devices"), its
calibration part fed frame by frame: the holds, flexes and swings ended at the take's times (their
six-device limit is the `six` section's; the performer does them in another order than the wizard
plans, which follows the take), each pivot and touch ended by the wizard itself: per kind the time
it took against its segment, the body from the live recording against the file's, the tips the
pivots found against the calibration's, and the CPU time of a pivot's `update()` after 2 s of it.

`cost`: the CPU time of one `update()` (process time, the mean of many calls) for each kind of step
after two seconds of it, early in a 90 Hz session (5 s in) and late (after `--minutes`, 10 by
default), and the late/early ratio, which should stay near 1 (update() reads only its window).

Run from the repository root: `.venv/bin/python benchmarks/bench_live_wizard.py [--minutes M]`.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import sys
import tempfile
import time
from dataclasses import replace

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from bodycal_addon.calibration import calibrate_user  # noqa: E402
from bodycal_addon.recording.io import load_recording  # noqa: E402
from bodycal_addon.recording.live.recorder import LiveRecorder  # noqa: E402
from bodycal_addon.recording.live.wizard import LiveWizard  # noqa: E402
from bodycal_dev.live_takes import live_frame, roles_of, wizard_over_steps  # noqa: E402

DEMO = ROOT / "sample_rigs" / "recordings" / "demo_full.bcrec.json"
FPS = 90.0
KINDS = {"hold": "tpose", "palms": "palms_together", "flex": "flex_elbow_l", "swing": "swing_hip_l",
         "touch": "touch:mcp_index_l:index_tip_r"}


SIX = ("head", "hand_l", "hand_r", "pelvis", "foot_l", "foot_r")


def six_devices(rec):
    """The take with only the six AvatarGo devices, no marker, and the steps they allow."""
    keep = [i for i, d in enumerate(rec.devices) if d.role in SIX]
    return replace(rec, devices=[rec.devices[i] for i in keep], positions=rec.positions[:, keep],
                   rotations=rec.rotations[:, keep], valid=rec.valid[:, keep], marker_names=[],
                   markers=rec.markers[:, :0], marker_valid=rec.marker_valid[:, :0], notes=[],
                   segments=[s for s in rec.segments if s.step not in ("touch", "palms_together")])


def demo_section(rec) -> dict:
    recorder = LiveRecorder("live", roles_of(rec))
    wizard = LiveWizard(recorder, roles_of(rec), rec.marker_names, auto=True)
    segs = [s for s in rec.segments if s.step != "motion"]
    took = {}
    for k in range(rec.frame_count):
        recorder(live_frame(rec, k))
        i = wizard.index
        if i < len(segs) and not wizard.active and rec.time[k] >= segs[i].start:
            wizard.begin()
        if wizard.active:
            wizard.update()
            if not wizard.active:
                took[i] = float(rec.time[k] - segs[i].start)
    by_kind: dict[str, list] = {}
    late = []
    for i, s in enumerate(segs):
        kind = s.step if s.step in ("tpose", "stand", "palms_together", "touch") else s.step.rsplit("_", 1)[0]
        length = s.end - s.start
        if i not in took or took[i] > length + 1e-9:
            late.append(s.label)
        by_kind.setdefault(kind, []).append((took.get(i, np.nan), length))
    kinds = {k: {"segment_s": round(float(np.median([b for _, b in v])), 3),
                 "took_s_median": round(float(np.nanmedian([a for a, _ in v])), 3),
                 "took_s_max": round(float(np.nanmax([a for a, _ in v])), 3), "steps": len(v)}
             for k, v in by_kind.items()}
    base = calibrate_user(rec, name="demo_full")
    live = calibrate_user(recorder.recording(), name="demo_full")
    diff = {j: float(np.linalg.norm(live.joints[j].world - base.joints[j].world)) * 1000 for j in base.joints}
    worst = max(diff, key=diff.get)
    return {"steps": len(segs), "completed_auto": sum(v == "auto" for v in wizard.completed.values()),
            "not_inside_segment": late, "kinds": kinds, "body_mm_max": round(diff[worst], 2), "body_mm_worst": worst,
            "body_mm_median": round(float(np.median(list(diff.values()))), 2),
            "warnings": len(live.calibration["warnings"])}


def touches_section(calls: int = 200) -> dict:
    from bodycal_addon.calibration import touches
    from bodycal_addon.calibration.common import Session, State
    from bodycal_addon.core import paths
    from evaluation import bvh, capture, performer, session

    perf = performer.Performer(bvh.read(paths.data_dir() / "motion" / "cmu_bvh" / "02_01_walk.bvh").resampled(FPS))
    cap = capture.capture(session.build_session(perf, seed=0, touches=True), perf, "six", seed=0)
    path = cap.write(pathlib.Path(tempfile.mkdtemp(prefix="bodycal-wizard-")) / "six.bcrec.json")
    rec = load_recording(path)
    part = rec.window(0, int(rec.frames(0.0, rec.segments_of("motion")[0].start)[-1]))
    part.segments = [s for s in rec.segments if s.step != "motion"]
    segs = {s.label: s for s in part.segments}
    pivot_ms = []

    def time_a_pivot(wizard, step, t):  # a pivot's update() after 2 s of it, once
        if not pivot_ms and step.step.startswith("pivot") and t - segs[step.label].start >= 2.0:
            t0 = time.process_time()
            for _ in range(calls):
                wizard.measure()
            pivot_ms.append((time.process_time() - t0) / calls * 1000)

    recorder, wizard, planned_as_performed, took = wizard_over_steps(part, time_a_pivot)
    kinds = {}
    for kind in ("pivot", "touch"):
        labels = [label for label in segs if label.startswith(kind)]
        ratio = [took.get(label, np.nan) / (segs[label].end - segs[label].start) for label in labels]
        kinds[kind] = {"steps": len(labels), "segment_s": round(float(np.median([segs[x].end - segs[x].start
                                                                               for x in labels])), 3),
                       "took_s_median": round(float(np.nanmedian([took.get(x, np.nan) for x in labels])), 3),
                       "took_s_max": round(float(np.nanmax([took.get(x, np.nan) for x in labels])), 3),
                       "not_inside_segment": [x for x, r in zip(labels, ratio, strict=True) if not r <= 1.0]}
    base = calibrate_user(part, name="six")
    live = calibrate_user(recorder.recording(), name="six")
    diff = {j: float(np.linalg.norm(live.joints[j].world - base.joints[j].world)) * 1000 for j in base.joints}
    worst = max(diff, key=diff.get)
    ses, state = Session(part), State()
    touches.controller_tips(ses, state)
    tips = {s: round(float(np.linalg.norm(wizard.tips[s] - state.extra["controller_tip_local"][s])) * 1000, 2)
            for s in wizard.tips}
    return {"planned_as_performed": planned_as_performed, "kinds": kinds, "body_mm_max": round(diff[worst], 2),
            "body_mm_worst": worst, "body_mm_median": round(float(np.median(list(diff.values()))), 2),
            "warnings": len(live.calibration["warnings"]), "tip_vs_calibration_mm": tips,
            "pivot_update_ms": round(pivot_ms[0], 3) if pivot_ms else None}


def cost_section(rec, minutes: float, calls: int = 200) -> dict:
    recorder = LiveRecorder("long", roles_of(rec))
    wizard = LiveWizard(recorder, roles_of(rec), rec.marker_names, auto=False)
    labels = [s.label for s in wizard.steps]
    j = 0

    def feed(seconds: float) -> None:
        nonlocal j
        for _ in range(int(round(seconds * FPS))):
            recorder(live_frame(rec, j % rec.frame_count, j / FPS))
            j += 1

    def measure() -> dict:
        out = {}
        for kind, label in KINDS.items():
            wizard.index, wizard.active = labels.index(label), False
            wizard.begin()
            feed(2.0)
            t0 = time.process_time()
            for _ in range(calls):
                wizard.update()
            out[kind] = (time.process_time() - t0) / calls * 1000
            wizard.skip_step()
        return out

    feed(5.0)
    early = measure()
    t0 = time.perf_counter()
    feed(minutes * 60.0 - recorder.duration)
    feed_s = time.perf_counter() - t0
    late = measure()
    return {"frames": recorder.frames, "session_s": round(recorder.duration, 1),
            "sink_us_per_frame": round(feed_s / max(recorder.frames, 1) * 1e6, 1),
            "update_ms_early": {k: round(v, 3) for k, v in early.items()},
            "update_ms_late": {k: round(v, 3) for k, v in late.items()},
            "late_over_early": {k: round(late[k] / early[k], 2) for k in early}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=10.0, help="the long session's length (default 10)")
    args = ap.parse_args(argv)
    rec = load_recording(DEMO)
    print(json.dumps({"demo": demo_section(rec), "six": demo_section(six_devices(rec)),
                      "six_touches": touches_section(), "cost": cost_section(rec, args.minutes)}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
