"""`bodycal calibrate-user REC -o USER.body.json` (FORMATS.md §4): every calibration step the
recording allows; prints one line per step with its quality, what was defaulted, and one
`warning:` line per step or touch whose data could not be used (left out, never fatal)."""

from __future__ import annotations

from pathlib import Path

from .. import console


def summary_lines(model) -> list[str]:
    cal = model.calibration
    lines = []
    for step, q in cal.get("quality", {}).items():
        parts = [f"{k}={v}" for k, v in q.items() if not isinstance(v, dict)]
        lines.append(f"  {step}: {' '.join(parts)}")
    if cal.get("defaulted"):
        lines.append(f"  defaulted ({len(cal['defaulted'])}): {', '.join(sorted(cal['defaulted']))}")
    if cal.get("missing"):
        lines.append(f"  missing: {', '.join(cal['missing'])}")
    for w in cal.get("warnings", []):
        lines.append(f"  warning: {w}")
    return lines


def run(args) -> int:
    from ...calibration import calibrate_user
    from ...core.outputs import check_output, recording_inputs
    from ...recording.io import load_recording

    files_read = recording_inputs(args.recording)
    overwrite = getattr(args, "overwrite", False)
    check_output(args.output, inputs=files_read, overwrite=overwrite)  # before any work
    rec = load_recording(args.recording)
    model = calibrate_user(rec, name=Path(args.recording).name.split(".")[0])
    out = model.save(args.output, inputs=files_read, overwrite=overwrite)
    console.say(f"calibrated {len(model.joints)} joints from {len(model.calibration['steps_used'])} steps "
                f"(reference: {model.calibration.get('reference')} at {model.reference_time:.3f} s) -> {out}")
    for line in summary_lines(model):
        console.say(line)
    return 0
