"""A recording fed to the live side frame by frame, for tests and benchmarks: its frames as a live
source hands them out, its roles, and the calibration wizard run over a take's calibration part.
"""

from __future__ import annotations

from bodycal_addon.recording.live.recorder import LiveRecorder
from bodycal_addon.recording.live.source import LiveFrame
from bodycal_addon.recording.live.wizard import LiveWizard

OPERATOR_ENDED = ("tpose", "stand", "flex", "swing")  # steps `wizard_over_steps` ends at the take's times


def live_frame(rec, k: int, time_s: float | None = None) -> LiveFrame:
    """Frame k of a recording as a live source hands it out (the sender's clock = the take's)."""
    v, mv = rec.valid[k], rec.marker_valid[k]
    t = float(rec.time[k]) if time_s is None else time_s
    return LiveFrame(k, t, t, tuple(d.name for d, ok in zip(rec.devices, v, strict=True) if ok),
                     rec.positions[k, v], rec.rotations[k, v],
                     tuple(n for n, ok in zip(rec.marker_names, mv, strict=True) if ok), rec.markers[k, mv])


def roles_of(rec) -> dict[str, str]:
    return {d.name: d.role for d in rec.devices if d.role}


def wizard_over_steps(part, before_update=None):
    """The auto wizard over `part` (a take's calibration steps, its segments those steps), its steps
    in the take's order: each begun at its segment's start, the holds, flexes and swings ended at
    the segment's end (the operator), every other step (pivots, touches) left to end by itself.
    `before_update(wizard, step, t)` is called before each of those steps' `update()`. Returns the
    recorder, the wizard, whether it planned the take's steps, and per step it ended itself the
    time after its segment's start."""
    segs = {s.label: s for s in part.segments}
    recorder = LiveRecorder("live", roles_of(part))
    wizard = LiveWizard(recorder, roles_of(part), part.marker_names, auto=True)
    planned_as_performed = sorted(s.label for s in wizard.steps) == sorted(segs)
    wizard.steps.sort(key=lambda st: list(segs).index(st.label))
    took = {}
    for k in range(part.frame_count):
        recorder(live_frame(part, k))
        step, t = wizard.current, float(part.time[k])
        if step is None or t < segs[step.label].start:
            continue
        if not wizard.active:
            wizard.begin()
        if step.step.startswith(OPERATOR_ENDED):
            if t >= segs[step.label].end:
                wizard.end_step()
            continue
        if before_update is not None:
            before_update(wizard, step, t)
        wizard.update()
        if not wizard.active:
            took[step.label] = t - segs[step.label].start
    return recorder, wizard, planned_as_performed, took
