"""Device roles in the scene (FORMATS.md §2.5): a device's role is its empty's `bodycal_role`
custom property, and `bodycal_role_from` says where it came from ("file": the recording or the
source object gave it, "tpose": identified from the T-pose, "user": set in the Recording panel's
Devices list; "" with no role). The list edits them, Identify Roles rewrites them from the T-pose;
calibration, retargeting and a saved .blend read the role through `recording_from_scene`.
"""

from __future__ import annotations

from ..core.errors import BodyCalError
from ..recording.model import ROLES as ROLES  # re-exported: the Devices list's role menu
from ..recording.roles import identify_roles
from .recording_scene import (
    DEVICE_PROP,
    MARKER_PROP,
    ROLE_FROM_PROP,
    ROLE_PROP,
    device_role,
    recording_from_scene,
    scene_recording_collection,
)

ORIGINS = ("file", "tpose", "user")


def device_empties(coll) -> list:
    """The collection's device empties, in the collection's order."""
    return [o for o in coll.objects if DEVICE_PROP in o] if coll is not None else []


def marker_empties(coll) -> list:
    return [o for o in coll.objects if MARKER_PROP in o] if coll is not None else []


def role_of(obj) -> str:
    """The role the empty says ("" none), as written: possibly not a role (the list flags it)."""
    role = obj.get(ROLE_PROP, "")
    return role if isinstance(role, str) else repr(role)


def origin_of(obj) -> str:
    """Where the empty's role came from (`ORIGINS`), "" without a role; an empty imported before
    the origin was kept says "file" for the role it has."""
    if not role_of(obj):
        return ""
    origin = obj.get(ROLE_FROM_PROP, "")
    return origin if origin in ORIGINS else "file"


def set_role(obj, role: str) -> None:
    """The user's choice: `role`, or "" to have the T-pose identify it at calibration."""
    if role and role not in ROLES:
        raise BodyCalError(f"{role!r} is not a device role", source=obj.name, hint=f"use one of {', '.join(ROLES)}")
    obj[ROLE_PROP] = role
    obj[ROLE_FROM_PROP] = "user" if role else ""


def role_problems(coll) -> dict[str, str]:
    """{empty name: what is wrong} for roles that are not roles or that two devices hold: what
    `recording_from_scene` would refuse, shown in the list before anything is run."""
    out, holder = {}, {}
    for obj in device_empties(coll):
        role = role_of(obj)
        if role and role not in ROLES:
            out[obj.name] = f"{role!r} is not a role"
        elif role:
            holder.setdefault(role, []).append(obj.name)
    for role, names in holder.items():
        if len(names) > 1:
            for n in names:
                out[n] = f"'{role}' is also on {', '.join(m for m in names if m != n)}"
    return out


def identify_scene_roles(scene, *, everything: bool = False) -> tuple[dict[str, str], list[str]]:
    """Identify the roles of the scene's recording from its T-pose (roles.py) and write them on the
    device empties, keeping the roles the user set unless `everything`. Returns ({device: role}
    written, [devices left without a role]); raises BodyCalError when the T-pose cannot be read
    (no `bodycal:tpose` step, fewer than 4 devices)."""
    coll = scene_recording_collection(scene)
    if coll is None:
        raise BodyCalError("no recording in this scene", source=scene.name,
                           hint="File > Import > BodyCal recording, or Recording from Objects")
    kept = set() if everything else {o[DEVICE_PROP] for o in device_empties(coll) if origin_of(o) == "user"}

    def keep_user_roles(obj, imported):
        return device_role(obj, imported) if obj[DEVICE_PROP] in kept else None

    found = identify_roles(recording_from_scene(scene, role_of=keep_user_roles))
    written, missing = {}, []
    for obj in device_empties(coll):
        name = obj[DEVICE_PROP]
        if name in kept:
            continue
        role = found.get(name, "")
        obj[ROLE_PROP] = role
        obj[ROLE_FROM_PROP] = "tpose" if role else ""
        if role:
            written[name] = role
        else:
            missing.append(name)
    return written, missing
