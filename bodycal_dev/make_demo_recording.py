"""Regenerate the bundled sample recording `sample_rigs/recordings/demo_full.bcrec.json` and its
ground truth `demo_full.truth.json` (the synthetic performer, full profile).

The whole calibration protocol (FORMATS.md §2.4) at a brisk pace, then a few contact motions,
at 22 Hz so the file stays under 5 MB. Reproducible: the same seed gives the same bytes.

    .venv/bin/python bodycal_dev/make_demo_recording.py [-o DIR]

A development tool: the extension ships the recording, not the synthetic performer that made it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from bodycal_dev import synthetic  # noqa: E402

FPS = 22.0
PACE = 0.5
MOTIONS = ("clap", "hand_on_belly", "hand_on_head", "walk_in_place")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--output", type=Path, default=REPO / "sample_rigs" / "recordings")
    args = ap.parse_args(argv)
    perf = synthetic.make_performer(height=1.75, build="average", seed=0)
    rec, truth = synthetic.record_session(perf, profile="full", motions=MOTIONS, fps=FPS, noise_mm=1.0, wobble_mm=2.0,
                                          dropout_rate=0.0, outlier_rate=0.0, seed=0, pace=PACE)
    rec.name = "demo_full"
    paths = synthetic.write_session(args.output, "demo_full", rec, truth)
    for p in paths:
        print(f"{p}: {p.stat().st_size / 1e6:.2f} MB")
    print(f"{rec.frame_count} frames, {rec.time[-1]:.1f} s at {FPS:g} Hz, {len(rec.segments)} segments")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
