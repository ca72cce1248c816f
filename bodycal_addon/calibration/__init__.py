"""User body calibration (DESIGN.md §3; Delahaye 2023, appendix B; AvatarGo §3.2-3.3).

`calibrate_user(recording) -> BodyModel` runs every step the recording allows, in the paper's
order (extremities first, then limbs toward the trunk, then the trunk), defaults what is missing
from anthropometric ratios of the eye height, and reports per step in `model.calibration`:
`steps_used`, `defaulted` {what: how}, `missing`, `warnings` (one line per step or touch whose
data could not be used, and why: such a step is left out and defaulted, never fatal) and
`quality` {step: {rms_mm, kept, of, range_deg, ...}}. The output follows the user-model contract
in bodymodel.py's docstring. `coverage` and `check_usable` (coverage.py) say how much of it was
measured and refuse a model that no method could animate or that is mostly guessed.

Its modules: `user` (the steps in order) over `common` (the state they share); one per part of
the body, `tpose`, `head`, `hands`, `feet`, `limbs`, `trunk`, with `touches`, `lengths` and
`effectors`; `defaults` (what a recording does not measure), `estimated_devices` (a kit without a
pelvis or foot trackers), `unused_devices` (devices left without a role), `coverage`.
"""

from .coverage import ANIMATED_ROLES, check_usable, coverage
from .user import CALIBRATION_STEPS, calibrate_user, natural_roles

__all__ = ["ANIMATED_ROLES", "CALIBRATION_STEPS", "calibrate_user", "check_usable", "coverage", "natural_roles"]
