"""How much of a user body model was measured and what is estimated (DESIGN.md §3, "Measured or
guessed", "The device ladder"): every joint a recording cannot give is defaulted from the eye
height, and the devices a kit lacks below the hands are estimated (estimated_devices.py), so a
recording of any kit from HMD and two controllers up yields a complete model that every method
animates. These checks say so rather than let it pass quietly, and refuse only what no method can
animate.

- The devices every method animates from (`ANIMATED_ROLES`: HMD, both hands, pelvis, both feet):
  the HMD and both hands must be there (`REQUIRED_ROLES`, the ladder's bottom rung: a standalone
  headset's kit); the pelvis and the feet are estimated when the kit has none.
- The body joints (`bodymodel.REQUIRED_USER_JOINTS`): fewer than half of them measured is a body
  mostly guessed, said in a warning line (`Coverage.warnings`), never a refusal. **Decision**: a
  guessed body still retargets (the egocentric method keeps the hands' contacts on the avatar
  whatever the user's proportions), so refusing it refused the kit most VR owners have.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..body.bodymodel import REQUIRED_USER_JOINTS, BodyModel
from ..core.errors import BodyCalError
from ..recording.model import ROLES_LIST

# The devices every retargeting method animates the user from (retarget/user_animation.py).
ANIMATED_ROLES = ("head", "pelvis", "hand_l", "hand_r", "foot_l", "foot_r")
REQUIRED_ROLES = ("head", "hand_l", "hand_r")
BODY_JOINTS = REQUIRED_USER_JOINTS
KITS = {  # the ladder's rungs by the devices estimated (estimated_devices.ESTIMATED_ROLES)
    ("pelvis", "chest", "foot_l", "foot_r"): "3 devices (HMD and two controllers)",
    ("foot_l", "foot_r"): "4 devices (HMD, two controllers and a pelvis tracker)",
}


@dataclass(frozen=True)
class Coverage:
    """The body joints measured and defaulted, how many values were defaulted in all, and the
    devices estimated (role -> what it stands for)."""

    measured: tuple[str, ...]
    defaulted: tuple[str, ...]
    values_defaulted: int
    estimated_devices: tuple[str, ...] = ()

    @property
    def mostly_guessed(self) -> bool:
        return 2 * len(self.measured) < len(BODY_JOINTS)

    @property
    def kit(self) -> str | None:
        """The kit's rung when devices are estimated ("3 devices (...)"), None: none estimated."""
        if not self.estimated_devices:
            return None
        return KITS.get(self.estimated_devices, f"no {_and(list(self.estimated_devices))} device")

    def line(self) -> str:
        """`measured 4 of 14 body joints (...), 10 defaulted (...); 100 values defaulted in all`, and
        with estimated devices `; the pelvis and feet estimated from the head and hands (3 devices ...)`."""
        text = f"measured {len(self.measured)} of {len(BODY_JOINTS)} body joints"
        if self.measured and self.defaulted:
            text += f" ({_few(self.measured)})"
        if self.defaulted:
            text += f", {len(self.defaulted)} defaulted ({_few(self.defaulted)})"
        text += f"; {self.values_defaulted} values defaulted in all"
        if self.estimated_devices:
            parts = ["the pelvis" if "pelvis" in self.estimated_devices else None,
                     "the feet" if "foot_l" in self.estimated_devices else None]
            text += f"; {' and '.join(p for p in parts if p)} estimated from the head and hands ({self.kit})"
        return text

    def warnings(self) -> list[str]:
        """What the user should know before trusting the body: a body mostly guessed."""
        if not self.mostly_guessed:
            return []
        return [f"only {len(self.measured)} of {len(BODY_JOINTS)} body joints measured, the other "
                f"{len(self.defaulted)} guessed from the eye height: the user's proportions are a table's "
                "(the calibration steps of docs/FORMATS.md §2.4 measure them)"]


def _few(names, n: int = 6) -> str:
    names = list(names)
    return ", ".join(names[:n]) + (f" and {len(names) - n} more" if len(names) > n else "")


def coverage(calibration: dict, extra: dict | None = None) -> Coverage:
    """The coverage of a user model's `calibration` record (FORMATS.md §3) and `extra` (its
    estimated devices)."""
    defaulted = calibration.get("defaulted", {}) or {}
    given = (extra or {}).get("estimated_devices") or {}
    estimated = tuple(r for r in ("pelvis", "chest", "foot_l", "foot_r") if r in given)
    return Coverage(tuple(j for j in BODY_JOINTS if j not in defaulted),
                    tuple(j for j in BODY_JOINTS if j in defaulted), len(defaulted), estimated)


def missing_roles(model: BodyModel) -> list[str]:
    """The animated roles the model has no reference pose for, estimated or measured (the
    calibration recording had no such device, or never tracked it, and it was not estimated)."""
    poses = model.extra.get("tpose", {}) if isinstance(model.extra, dict) else {}
    return [r for r in ANIMATED_ROLES if r not in poses]


def check_usable(model: BodyModel, *, source: str | None = None) -> Coverage:
    """The model's coverage; raises one line when the recording lacks the HMD or a hand (below the
    ladder's bottom rung), or when the model predates the estimated devices."""
    missing = missing_roles(model)
    lacking = [r for r in missing if r in REQUIRED_ROLES]
    if lacking:
        raise BodyCalError(
            f"the recording has no {_and(lacking)} {'device' if len(lacking) == 1 else 'devices'}: every method "
            "needs at least the HMD and both hands (a 3-device kit), the rest can be estimated", source=source,
            hint=f"record with the HMD and both controllers, or assign these roles to the devices ({ROLES_LIST})")
    if missing:
        devices = "device" if len(missing) == 1 else "devices"
        raise BodyCalError(
            f"the body model has no reference pose for the {_and(missing)} {devices} "
            "(it was calibrated before the lower body could be estimated)", source=source,
            hint="calibrate the user again from the recording")
    return coverage(model.calibration, model.extra)


def _and(names: list[str]) -> str:
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " and " + names[-1]
