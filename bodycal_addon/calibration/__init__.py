"""User body calibration (DESIGN.md §3; Delahaye 2023, appendix B; AvatarGo §3.2-3.3).

`calibrate_user(recording) -> BodyModel` runs every step the recording allows, in the paper's
order (extremities first, then limbs toward the trunk, then the trunk), defaults what is missing
from anthropometric ratios of the eye height, and reports per step in `model.calibration`:
`steps_used`, `defaulted` {what: how}, `missing`, `warnings` (one line per step or touch whose
data could not be used, and why: such a step is left out and defaulted, never fatal) and
`quality` {step: {rms_mm, kept, of, range_deg, ...}}. The output follows the user-model contract
in bodymodel.py's docstring.
"""

from .user import CALIBRATION_STEPS, calibrate_user, natural_roles

__all__ = ["CALIBRATION_STEPS", "calibrate_user", "natural_roles"]
