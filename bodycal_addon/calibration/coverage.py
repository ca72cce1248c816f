"""How much of a user body model was measured, and whether it is worth writing (DESIGN.md §3,
"Measured or guessed"): every joint a recording cannot give is defaulted from the eye height, so a
recording without calibration steps still yields a complete model; these checks keep such a model
from passing quietly.

- The six devices every method animates from (`ANIMATED_ROLES`: HMD, both hands, pelvis, both
  feet): a recording without one of them is refused whatever the options (**Decision**: no
  upper-body mode; a 3-point recording, HMD and two controllers, is one clear refusal here rather
  than a model that fails at retarget).
- The body joints (`bodymodel.REQUIRED_USER_JOINTS`): fewer than half of them measured is a body
  mostly guessed, refused unless the caller accepts the defaults (`--allow-defaults`, the
  sidebar's Accept Defaults).
"""

from __future__ import annotations

from dataclasses import dataclass

from ..body.bodymodel import REQUIRED_USER_JOINTS, BodyModel
from ..core.errors import BodyCalError
from ..recording.model import ROLES_LIST

# The devices every retargeting method animates the user from (retarget/user_animation.py).
ANIMATED_ROLES = ("head", "pelvis", "hand_l", "hand_r", "foot_l", "foot_r")
BODY_JOINTS = REQUIRED_USER_JOINTS


@dataclass(frozen=True)
class Coverage:
    """The body joints measured and defaulted, and how many values were defaulted in all."""

    measured: tuple[str, ...]
    defaulted: tuple[str, ...]
    values_defaulted: int

    @property
    def mostly_guessed(self) -> bool:
        return 2 * len(self.measured) < len(BODY_JOINTS)

    def line(self) -> str:
        """`measured 4 of 14 body joints (...), 10 defaulted (...); 100 values defaulted in all`."""
        text = f"measured {len(self.measured)} of {len(BODY_JOINTS)} body joints"
        if self.measured and self.defaulted:
            text += f" ({_few(self.measured)})"
        if self.defaulted:
            text += f", {len(self.defaulted)} defaulted ({_few(self.defaulted)})"
        return text + f"; {self.values_defaulted} values defaulted in all"


def _few(names, n: int = 6) -> str:
    names = list(names)
    return ", ".join(names[:n]) + (f" and {len(names) - n} more" if len(names) > n else "")


def coverage(calibration: dict) -> Coverage:
    """The coverage of a user model's `calibration` record (FORMATS.md §3)."""
    defaulted = calibration.get("defaulted", {}) or {}
    return Coverage(tuple(j for j in BODY_JOINTS if j not in defaulted),
                    tuple(j for j in BODY_JOINTS if j in defaulted), len(defaulted))


def missing_roles(model: BodyModel) -> list[str]:
    """The animated roles the model has no reference pose for (the calibration recording had no such
    device, or never tracked it)."""
    poses = model.extra.get("tpose", {}) if isinstance(model.extra, dict) else {}
    return [r for r in ANIMATED_ROLES if r not in poses]


def check_usable(model: BodyModel, *, allow_defaults: bool, accept: str = "pass --allow-defaults",
                 source: str | None = None) -> Coverage:
    """The model's coverage; raises one line when the recording lacks a device every method needs,
    or when the body would be mostly guessed and `allow_defaults` is off (`accept`: how the caller
    accepts the defaults)."""
    missing = missing_roles(model)
    if missing:
        raise BodyCalError(
            f"the recording has no {_and(missing)} {'device' if len(missing) == 1 else 'devices'}: every method "
            "animates the body from the HMD, both hands, the pelvis and both feet, so a recording without them "
            "(such as a 3-point one, HMD and two controllers) cannot drive the hips and legs", source=source,
            hint=f"record with a pelvis tracker and two foot trackers, or assign these roles to the devices "
                 f"({ROLES_LIST})")
    cov = coverage(model.calibration)
    if cov.mostly_guessed and not allow_defaults:
        steps = [s for s in model.calibration.get("steps_used", []) if not s.endswith("from the motion")]
        why = ("the recording has no calibration steps" if not steps else
               "its calibration steps did not measure the rest (see the warnings)")
        raise BodyCalError(
            f"only {len(cov.measured)} of {len(BODY_JOINTS)} body joints measured, the other {len(cov.defaulted)} "
            f"would be guessed from the eye height: {why}", source=source,
            hint=f"record the calibration steps of docs/FORMATS.md §2.4, or {accept} to accept a guessed body")
    return cov


def _and(names: list[str]) -> str:
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]
