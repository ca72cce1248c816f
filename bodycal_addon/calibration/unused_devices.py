"""Devices a calibration leaves without a role, said aloud (DESIGN.md §3): a device the recording and
the T-pose left without a role is not used, and the joints its tracker would have measured are
defaulted from the eye height (5-46 mm off on the evaluation's real motion). Each such device is one warning line,
and so is each body joint defaulted that it may have measured (the T-pose places the device on a
limb or the trunk: roles.unused_devices); the lines go where every calibration warning goes
(`calibration["warnings"]`: stderr from `calibrate-user`, the Calibration panel)."""

from __future__ import annotations

from ..body.bodymodel import REQUIRED_USER_JOINTS
from ..recording.model import ROLES_LIST, Recording
from ..recording.roles import unused_devices

# The trackers a body joint is measured with (its own limb's, the flex and swing steps), by side.
_MEASURED_WITH = {"shoulder": ("upperarm", "chest"), "elbow": ("upperarm", "forearm"), "wrist": ("forearm", "hand"),
                  "hip": ("thigh", "pelvis"), "knee": ("thigh", "shin"), "ankle": ("shin", "foot")}


def measured_with(joint: str) -> tuple[str, ...]:
    """The roles whose trackers measure `joint` (a body joint of REQUIRED_USER_JOINTS)."""
    if joint == "skull_base":
        return ("head",)
    if joint == "spine_root":
        return ("pelvis", "chest")
    part, s = joint[:-2], joint[-1]
    return tuple(r if r in ("chest", "pelvis") else f"{r}_{s}" for r in _MEASURED_WITH[part])


def warning_lines(rec: Recording, defaulted: dict, has=None) -> list[str]:
    """One line per device without a role, then one per body joint in `defaulted` that such a
    device may have measured (its place in the T-pose holds a role that measures the joint and that
    no device holds)."""
    unused = unused_devices(rec, has)
    lines = []
    for name, (where, roles) in unused.items():
        could = f", where the {_or(roles)} role is free" if roles and not where.startswith(("the T-pose", "not")) \
            else ""
        lines.append(f"device {name} has no role and is not used ({where}{could}): give it its role (the device's "
                     f"\"role\" in the recording, or {ROLES_LIST})")
    for joint in REQUIRED_USER_JOINTS:
        if joint not in defaulted:
            continue
        missing = [r for r in measured_with(joint) if any(r in roles for _where, roles in unused.values())]
        names = [n for n, (_where, roles) in unused.items() if set(missing) & set(roles)]
        if names:
            devices = f"device {names[0]}" if len(names) == 1 else f"devices {_or(names)}"
            lines.append(f"{joint} defaulted: no {_or(missing)} tracker measured it, and "
                         f"{devices}, left without a role, may be that tracker")
    return lines


def _or(names) -> str:
    names = list(names)
    return names[0] if len(names) == 1 else ", ".join(names[:-1]) + " or " + names[-1]
