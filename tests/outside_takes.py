"""Recordings made from real human motion by `evaluation/` (code that shares nothing with the
synthetic performer): a CMU clip's skeleton performs the calibration steps and the clip, trackers
strapped on at random, the file written and read back through the public reader."""

from __future__ import annotations

from bodycal_addon.recording import io as recording_io
from evaluation import bvh, capture, performer, session

FPS = 90.0


def clip_performer(data_dir, name: str, folder: str = "cmu_bvh", fps: float = FPS) -> performer.Performer:
    """The performer of the sample data's BVH clip `motion/<folder>/<name>`, resampled to `fps`."""
    return performer.Performer(bvh.read(data_dir / "motion" / folder / name).resampled(fps))


def outside_recording(perf, folder, profile: str = "full", seed: int = 0, up: str = "Y", cut=None, **session_kw):
    """(the recording as the reader gives it, the capture) of `perf` in session `seed` with the
    `profile`'s devices, written `up` in `folder`; `cut(capture)` changes what was tracked before it
    is written; `session_kw` go to `session.build_session` (e.g. the performer's facing, `yaw`)."""
    cap = capture.capture(session.build_session(perf, seed=seed, **session_kw), perf, profile, seed=seed)
    if cut is not None:
        cut(cap)
    path = cap.write(folder / f"{perf.clip.name}_{profile}_{seed}.bcrec.json", up=up)
    return recording_io.load_recording(path), cap
