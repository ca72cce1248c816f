"""`bodycal calibrate-user REC -o USER.body.json` (FORMATS.md §4): every calibration step the
recording allows. stdout: a summary line (how many body joints were measured, how many defaulted,
which devices are estimated), one line per step with its quality and what was defaulted; stderr:
one `warning:` line per step or touch whose data could not be used (left out, never fatal) and
one for a body mostly guessed. Refused with one line (exit 2, nothing written): a recording
without the HMD or a hand (calibration/coverage.py). `--allow-defaults` is accepted and changes
nothing: a guessed body is no longer refused."""

from __future__ import annotations

from pathlib import Path

from ...calibration import calibrate_user, check_usable
from ...core.outputs import check_output, recording_inputs
from ...recording import io as recording_io
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
    return lines


def run(args) -> int:
    files_read = recording_inputs(args.recording)
    overwrite = getattr(args, "overwrite", False)
    check_output(args.output, inputs=files_read, overwrite=overwrite)  # before any work
    rec = recording_io.load_recording(args.recording, hands=getattr(args, "hands", "geometry"))
    model = calibrate_user(rec, name=Path(args.recording).name.split(".")[0])
    cov = check_usable(model, source=str(args.recording))
    out = model.save(args.output, inputs=files_read, overwrite=overwrite)
    for w in model.calibration.get("warnings", []) + cov.warnings():
        console.warn("calibrate-user", w)
    console.say(f"calibrated {out}: {cov.line()}, from {len(model.calibration['steps_used'])} steps "
                f"(reference: {model.calibration.get('reference')} at {model.reference_time:.3f} s)")
    for line in summary_lines(model):
        console.say(line)
    return 0
