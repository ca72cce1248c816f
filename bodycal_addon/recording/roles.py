"""Identify tracker roles from the T-pose (AvatarGo §3.2: "fitting a plane through the
location of all tracking devices, to then automatically identify each tracker's role based on
their relative location on the plane").

In a T-pose every device lies near the performer's frontal plane. The plane's normal (made
horizontal) is the facing axis. Its sign: the HMD (in front of the face) and the foot trackers (on
top of the feet) lie ahead of the plane; when that margin is too small to trust, an upright HMD's
view direction decides (local -Z: OpenXR view space, also Blender's camera convention; see
coords.py for how device frames are converted). Left = up x forward. Then, on the plane:
highest = head, the two far lateral = hands, lowest per side = feet, and the rest by height and
lateral distance: central devices are pelvis (waist) and chest (above), lateral ones above the
waist are upper arm (nearer) and forearm (farther), below it thigh (higher) and shin (lower).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..core.errors import BodyCalError
from ..core.geometry import fit_plane
from ..core.transforms import rotate
from .model import ROLES, ROLES_LIST, Recording

HMD_FORWARD_LOCAL = np.array([0.0, 0.0, -1.0])
HMD_UP_LOCAL = np.array([0.0, 1.0, 0.0])
GEOMETRY_MARGIN = 0.03  # metres: HMD offset + mean foot offset ahead of the T-pose plane
UP = np.array([0.0, 0.0, 1.0])
WAIST = 0.55  # fraction of the head height: lateral devices above it are on the arms, below on the legs
CENTRAL = 0.09  # fraction of the head height: devices this near the middle are on the trunk (or the head)


def tpose_positions(rec: Recording) -> tuple[np.ndarray, np.ndarray, dict]:
    """Mean device positions over the middle half of the first tpose segment: (D, 3), (D,) tracked, info."""
    segs = rec.segments_of("tpose")
    if not segs:
        raise BodyCalError("no tpose segment: roles cannot be identified", source=rec.source or rec.name,
                           field="segments", hint=f"record a T-pose or give every device a role ({ROLES_LIST})")
    s = segs[0]
    quarter = 0.25 * (s.end - s.start)
    frames = rec.frames(s.start + quarter, s.end - quarter)
    if frames.size == 0:
        frames = rec.frames(s.start, s.end)
    if frames.size == 0:
        raise BodyCalError(f"the tpose segment {s.start:g}..{s.end:g} s holds no frame", source=rec.source or rec.name,
                           field="segments")
    valid = rec.valid[frames]
    count = valid.sum(axis=0)
    pos = (rec.positions[frames] * valid[..., None]).sum(axis=0) / np.maximum(count, 1)[:, None]
    return pos, count > 0, {"frames": frames, "segment": s}


def _facing(rec: Recording, pos: np.ndarray, tracked: np.ndarray, normal: np.ndarray, head: int,
            frames: np.ndarray) -> tuple[np.ndarray, str]:
    """Forward (horizontal unit vector) and how it was decided.

    Geometry first: the HMD sits in front of the face and foot trackers on top of the feet, so both
    are ahead of the plane through the devices (a few cm each; `GEOMETRY_MARGIN` in total). When that
    is unclear, an upright HMD (local +Y within 45 degrees of up) looks along its local -Z."""
    fwd = normal - (normal @ UP) * UP
    if np.linalg.norm(fwd) < 1e-6:
        raise BodyCalError("the devices do not span a vertical plane in the tpose segment",
                           source=rec.source or rec.name, field="segments",
                           hint="stand in a T-pose with arms spread")
    fwd /= np.linalg.norm(fwd)
    idx = np.flatnonzero(tracked)
    centre = pos[idx].mean(axis=0)
    offset = (pos - centre) @ fwd
    others = [i for i in idx if i != head]
    feet = sorted(others, key=lambda i: pos[i, 2])[:2] if len(others) >= 4 else []
    cue = offset[head] + (float(np.mean(offset[feet])) if feet else 0.0)
    if abs(cue) >= GEOMETRY_MARGIN:
        return (fwd if cue > 0 else -fwd), "HMD and feet ahead of the body plane"
    if rec.devices[head].kind == "hmd":
        ok = rec.valid[frames, head]
        if ok.any():
            q = rec.rotations[frames[ok], head]
            look = rotate(q, HMD_FORWARD_LOCAL).mean(axis=0)
            up_axis = rotate(q, HMD_UP_LOCAL).mean(axis=0)
            look_h = look - (look @ UP) * UP
            upright = up_axis @ UP > np.cos(np.radians(45)) * np.linalg.norm(up_axis)
            if upright and abs(look_h @ fwd) > 0.5 * np.linalg.norm(look):
                return (fwd if look_h @ fwd > 0 else -fwd), "HMD view direction"
    return (fwd if cue >= 0 else -fwd), "HMD and feet ahead of the body plane (weak)"


def identify_roles(rec: Recording) -> dict[str, str]:
    """Role of every device (name -> role) from the tpose segment, AvatarGo §3.2. Devices already
    holding a role keep it; their roles are not given to others. Raises BodyCalError when the
    T-pose cannot be read (no segment, fewer than 4 tracked devices, no vertical plane)."""
    return _classify(rec)[0]


@dataclass
class _Assignment:
    """What the role passes share: the T-pose positions (D, 3), the roles the devices already hold
    (`fixed`, role -> device), the roles found so far (device -> role, in the order found) and the
    tracked devices still without one (`free`). Once the facing is known (`orient`): each device's
    lateral coordinate `u` (+ = the performer's left), its height above the lowest device as a
    fraction of the head's (`z_rel`), the floor and that head height."""

    rec: Recording
    pos: np.ndarray
    fixed: dict[str, int]
    free: set[int]
    roles: dict[int, str] = field(default_factory=dict)
    tracked: set[int] = field(default_factory=set)  # the devices seen in the tpose segment

    def take(self, i: int, role: str) -> None:
        self.roles[i] = role
        self.free.discard(i)

    def orient(self, head: int, fwd: np.ndarray, idx: np.ndarray) -> None:
        left = np.cross(UP, fwd)
        self.u = (self.pos - self.pos[head]) @ left  # lateral coordinate, + = performer's left
        self.floor = self.pos[idx, 2].min()
        self.height = max(self.pos[head, 2] - self.floor, 0.5)  # head height above the lowest device
        self.z_rel = (self.pos[:, 2] - self.floor) / self.height


def _oriented(rec: Recording) -> tuple[_Assignment, str]:
    """The T-pose read as far as the facing: positions, given roles, the head taken, the lateral
    and height coordinates set; and how the facing was decided."""
    src = rec.source or rec.name
    pos, tracked, info = tpose_positions(rec)
    idx = np.flatnonzero(tracked)
    if idx.size < 4:
        raise BodyCalError(f"only {idx.size} devices tracked in the tpose segment, at least 4 needed (head, hands, "
                           "a foot or the pelvis)", source=src, field="segments")
    plane = fit_plane(pos[idx], name=f"{src}: tpose plane")
    fixed = {d.role: i for i, d in enumerate(rec.devices) if d.role}
    found = _Assignment(rec, pos, fixed, set(int(i) for i in idx), tracked=set(int(i) for i in idx))
    head = _take_head(found)
    fwd, how = _facing(rec, pos, tracked, plane.normal, head, info["frames"])
    found.orient(head, fwd, idx)
    return found, how


def _classify(rec: Recording) -> tuple[dict[str, str], str]:
    """(device name -> role, how the facing was decided) from the tpose segment: the passes below in
    the order AvatarGo §3.2 reads the T-pose, each taking devices the earlier ones left free."""
    found, how = _oriented(rec)
    fixed = found.fixed
    for role, i in fixed.items():  # keep given roles
        if i in found.free:
            found.take(i, role)
    _take_hands(found)
    _take_feet(found)
    _take_trunk(found)
    _take_limbs(found)
    # A single remaining device in the minimal profile is the waist tracker.
    if len(found.free) == 1 and "pelvis" not in fixed and "pelvis" not in found.roles.values():
        found.take(found.free.pop(), "pelvis")
    names = {rec.devices[i].name: r for i, r in found.roles.items()}
    return names, f"facing from the {how}, {len(found.free)} device(s) left unidentified"


def _take_head(found: _Assignment) -> int:
    """The head: the device given that role, else the HMD (the highest one), else the highest
    device. Takes it; returns its index."""
    if "head" in found.fixed:
        head = found.fixed["head"]
    else:
        hmds = [i for i in found.free if found.rec.devices[i].kind == "hmd"]
        head = max(hmds or found.free, key=lambda i: found.pos[i, 2])
    found.take(head, "head")
    return head


def _take_hands(found: _Assignment) -> None:
    """Hands: per side without a given hand, the farthest free device beyond a quarter of the head
    height (controllers and rigid bodies first); AvatarGo: "the two far lateral"."""
    u = found.u
    for s, sign in (("l", 1.0), ("r", -1.0)):
        if f"hand_{s}" in found.fixed:
            continue
        cands = [i for i in found.free if sign * u[i] > 0.25 * found.height]
        preferred = [i for i in cands if found.rec.devices[i].kind in ("controller", "rigid_body")]
        if preferred or cands:
            found.take(max(preferred or cands, key=lambda i: sign * u[i]), f"hand_{s}")


def _take_feet(found: _Assignment) -> None:
    """Feet: the lowest free devices near the floor, as many as feet are not given; two are told
    apart by the lateral coordinate, a single one by its side (or takes the one foot left)."""
    pos, u, fixed = found.pos, found.u, found.fixed
    feet_free = [r for r in ("foot_l", "foot_r") if r not in fixed]
    low = sorted((i for i in found.free if pos[i, 2] - found.floor < 0.15 * found.height),
                 key=lambda i: pos[i, 2])[:len(feet_free)]
    if len(low) == 2:
        a, b = sorted(low, key=lambda i: -u[i])
        found.take(a, "foot_l")
        found.take(b, "foot_r")
    elif len(low) == 1:
        role = f"foot_{'l' if u[low[0]] > 0 else 'r'}" if len(feet_free) == 2 else feet_free[0]
        found.take(low[0], role)


def _take_trunk(found: _Assignment) -> None:
    """Trunk: central free devices above the knees, highest first: chest then pelvis; one alone (or
    beside a given chest or pelvis) is the pelvis when low or when the chest is given."""
    fixed, z_rel = found.fixed, found.z_rel
    central = CENTRAL * found.height
    rest = sorted(found.free, key=lambda i: -found.pos[i, 2])
    trunk = [i for i in rest if abs(found.u[i]) < central and z_rel[i] > 0.4]
    if len(trunk) >= 2 and "chest" not in fixed and "pelvis" not in fixed:
        found.take(trunk[0], "chest")
        found.take(trunk[1], "pelvis")
    elif len(trunk) == 1 or (trunk and ("chest" in fixed) != ("pelvis" in fixed)):
        role = "pelvis" if "pelvis" not in fixed and (z_rel[trunk[0]] < 0.7 or "chest" in fixed) else "chest"
        if role not in fixed:
            found.take(trunk[0], role)


def _take_limbs(found: _Assignment) -> None:
    """Arms above the waist (upper arm nearer the middle, then forearm) and legs below it (thigh
    higher, then shin), per side, among the free devices; given roles are not taken again. With
    one role of a limb given, the free device takes the other by where it sits: beyond the given
    device (or before it) when that device is on this limb, else at the open role's place in the
    limb's order (the given device is elsewhere: a role given to the wrong device). Pairing the free
    devices with both roles and skipping the given one dropped a free forearm beside a given upper
    arm, and a free shin beside a given thigh."""
    for s, sign in (("l", 1.0), ("r", -1.0)):
        _take_limb(found, sign, True, (f"upperarm_{s}", f"forearm_{s}"))
        _take_limb(found, sign, False, (f"thigh_{s}", f"shin_{s}"))


def _take_limb(found: _Assignment, sign: float, arm: bool, roles: tuple[str, str]) -> None:
    """One limb of `_take_limbs`: the side `sign` (+1 left), the arm or the leg, its two roles."""
    u, z_rel = found.u, found.z_rel

    def along(i):  # outward along the arm, downward along the leg
        return sign * u[i] if arm else -found.pos[i, 2]

    def on_limb(i):
        return i in found.tracked and sign * u[i] > 0 and bool(z_rel[i] >= WAIST) == arm

    devices = sorted((i for i in found.free if on_limb(i)), key=along)
    open_roles = [r for r in roles if r not in found.fixed]
    if len(open_roles) == 2:
        for i, role in zip(devices, roles):
            found.take(i, role)
        return
    if not open_roles:
        return
    lower = open_roles[0] == roles[1]
    given = found.fixed[roles[0] if lower else roles[1]]
    if on_limb(given):
        beyond = [i for i in devices if (along(i) > along(given)) == lower]
        pick = min(beyond, key=lambda i: abs(along(i) - along(given))) if beyond else None
    else:
        pick = devices[int(lower)] if len(devices) > int(lower) else None
    if pick is not None:
        found.take(pick, open_roles[0])


def apply_roles(rec: Recording) -> dict[str, str]:
    """Fill in the missing roles of `rec` from its tpose segment and say so in rec.notes."""
    found, how = _classify(rec)
    assigned = {}
    for d in rec.devices:
        if d.role is None and d.name in found:
            d.role = found[d.name]
            d.identified = True
            assigned[d.name] = d.role
    missing = [d.name for d in rec.devices if d.role is None]
    text = ", ".join(f"{n}={r}" for n, r in assigned.items()) or "none"
    note = f"roles identified from the tpose segment (AvatarGo §3.2, {how}): {text}"
    if missing:
        note += f"; no role for {', '.join(missing)}"
    rec.notes.append(note)
    return assigned


def unused_devices(rec: Recording, has=None) -> dict[str, tuple[str, tuple[str, ...]]]:
    """The devices still without a role, each with where the T-pose places it and the roles it could
    carry there that no device holds (`has(role)`, default: a device holds it): name -> (where,
    roles). A device the T-pose cannot place (no tpose segment, not tracked in it) could carry any
    role no device holds. What a calibration says about a device it leaves unused."""
    has = has or rec.has_role
    unused = [i for i, d in enumerate(rec.devices) if d.role is None]
    if not unused:
        return {}
    open_roles = tuple(r for r in ROLES if not has(r))
    try:
        found, _how = _oriented(rec)
    except BodyCalError as exc:
        return {rec.devices[i].name: (f"the T-pose cannot place it: {exc.message}", open_roles) for i in unused}
    out = {}
    for i in unused:
        name = rec.devices[i].name
        if i not in found.free and found.roles.get(i) != "head":
            out[name] = ("not tracked in the tpose segment", open_roles)
            continue
        where, region = _region(found, i)
        out[name] = (where, tuple(r for r in region if r in open_roles))
    return out


def _region(found: _Assignment, i: int) -> tuple[str, tuple[str, ...]]:
    """Where device `i` sits in the T-pose and the roles of that part of the body."""
    u, z = found.u[i], found.z_rel[i]
    if abs(u) < CENTRAL * found.height and z > 0.4:  # as _take_trunk reads it
        return "on the trunk", ("head", "chest", "pelvis")
    s, side = ("l", "left") if u > 0 else ("r", "right")
    if z >= WAIST:
        return f"on the {side} arm", (f"upperarm_{s}", f"forearm_{s}", f"hand_{s}")
    return f"on the {side} leg", (f"thigh_{s}", f"shin_{s}", f"foot_{s}")
