"""Tracker recordings (FORMATS.md §2), numpy only.

- `model`: `Recording`, `Device`, `Segment`, `ROLES`: a recording in the internal frame.
- `io/`: `load_recording`, `save_recording` and the readers of every format.
- `live/`: live sources (VMC over OSC), the recorder and the calibration wizard.
- `filters`: `OneEuro`, the smoothing of device poses; `roles`: `identify_roles` from the T-pose.
- `coords`, `segments`, `gaps`, `led_gloves`, `from_matrices`: what the readers share.

The package re-exports nothing: `io` loads every reader and `live` python-osc, which a module that
needs only `model` should not pay for."""
