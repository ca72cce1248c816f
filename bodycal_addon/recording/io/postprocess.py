"""Post-processing shared by every reader: hold untracked values, fill short gaps, build LED hand
frames, identify missing roles (roles.py); what was done goes to `Recording.notes`."""

from __future__ import annotations

import numpy as np

from ..gaps import fill_gaps, hold_untracked
from ..led_gloves import add_led_hand_frames
from ..model import Recording
from ..roles import apply_roles

DEFAULT_FILL_GAPS_S = 0.1


def finish_recording(rec: Recording, *, fill_gaps_s: float = DEFAULT_FILL_GAPS_S,
                     identify_roles: bool = True) -> Recording:
    """Hold untracked values, fill short gaps, build LED hand frames, identify missing roles."""
    if rec.markers is None or rec.markers.size == 0 and rec.markers.shape[1:] != (len(rec.marker_names), 3):
        rec.markers = np.zeros((len(rec.time), len(rec.marker_names), 3))
        rec.marker_valid = np.zeros((len(rec.time), len(rec.marker_names)), bool)
    if fill_gaps_s and fill_gaps_s > 0:
        n_dev, frames_dev = fill_gaps(rec.time, rec.positions, rec.valid, fill_gaps_s, rec.rotations)
        n_mk, frames_mk = fill_gaps(rec.time, rec.markers, rec.marker_valid, fill_gaps_s)
        if n_dev or n_mk:
            rec.notes.append(f"filled {n_dev + n_mk} gaps shorter than {fill_gaps_s:g} s ({frames_dev + frames_mk} "
                             f"frames: cubic Hermite curves at each device's own velocity)")
    hold_untracked(rec.positions, rec.valid, rec.rotations)
    hold_untracked(rec.markers, rec.marker_valid)
    add_led_hand_frames(rec)
    unknown = [d.name for d in rec.devices if d.role is None]
    if identify_roles and unknown and rec.segments_of("tpose"):
        apply_roles(rec)
    elif unknown:
        rec.notes.append(f"no role for {', '.join(unknown)} and no tpose segment to identify them from "
                         "(mark the T-pose on the timeline or give roles in the file)")
    return rec
