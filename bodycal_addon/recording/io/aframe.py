"""The A-Frame motion-capture reader (FORMATS.md §2.6): the JSON that aframe-motion-capture-components'
`avatar-recorder` saves (a WebVR headset and its tracked controllers), checked and converted to the
internal frame.

Layout: `{"camera": {"poses": [...], "events": [...]}, "<entity id>": {"poses": [...], "events": [...],
"gamepad": {"id", "hand", "index"}}, ...}`, one entry per tracked controller besides the camera; a
pose is `{"position": {x, y, z}, "rotation": {x, y, z}, "timestamp": ms}`. Positions are metres in
three.js's (WebVR standing) space: right-handed, Y up, -Z forward, floor at y = 0 (FORMATS.md's
`coords` default). Rotations are the A-Frame `rotation` attribute: degrees, three.js Euler order
'YXZ' (R = Ry(y) Rx(x) Rz(z)). Timestamps are the scene's clock (ms), the same tick for every
entity. Button events are not read.
"""

from __future__ import annotations

import itertools
import math
import re
from pathlib import Path

import numpy as np

from ...core import transforms as tf
from ...core.errors import BodyCalError, short_repr
from ..coords import check_positions, to_internal
from ..model import Device, Recording
from .hands import check_hands, choose_hands, right_share
from .header import load_json_file
from .json_format import check_time

CAMERA = "camera"  # the avatar-recorder's key for the headset
# The start of an A-Frame recording (its first key is the camera entity, as the recorder writes it).
SNIFF_RE = re.compile(rb'^\s*\{\s*"camera"\s*:\s*\{')
_AXES = ("x", "y", "z")
_WORD_RE = re.compile(r"[a-z]+|[A-Z][a-z]*")  # the words of an id: `leftHand`, `hand-left`, `left`


def looks_like_aframe(head: bytes) -> bool:
    """Whether a JSON file's first bytes are an A-Frame recording's (`{"camera": {`)."""
    return bool(SNIFF_RE.match(head))


def read_aframe(path, hands: str = "geometry") -> Recording:
    """The headset (`camera`, kind hmd, role head) and each controller entity (kind controller);
    the two controllers' roles are told as `hands` says (recording/io/hands.py)."""
    path = Path(path)
    source = path.name
    check_hands(hands, source)
    doc = load_json_file(path, source)
    if not isinstance(doc, dict) or not isinstance(doc.get(CAMERA), dict):
        raise BodyCalError('not an A-Frame motion capture (no "camera" entity)', source=source,
                           hint='an avatar-recorder file holds {"camera": {"poses": [...]}, ...}')
    names = [CAMERA] + [k for k in doc if k != CAMERA]
    if len(names) > 64:
        raise BodyCalError(f"{len(names)} entities: more than 64 devices", source=source)
    if any(not n.strip() for n in names):
        raise BodyCalError("an entity with an empty id", source=source, hint="each device needs a name")
    parsed = [_entity(doc[n], n, source) for n in names]
    time_ms = np.unique(np.concatenate([ts for ts, _, _ in parsed]))
    f, d = len(time_ms), len(names)
    positions, rotations = np.zeros((f, d, 3)), np.tile([1.0, 0.0, 0.0, 0.0], (f, d, 1))
    valid = np.zeros((f, d), bool)
    for i, (ts, pos, deg) in enumerate(parsed):
        rows = np.searchsorted(time_ms, ts)
        positions[rows, i], valid[rows, i] = pos, True
        # three.js 'YXZ': Z turns first, then X, then Y (R = Ry Rx Rz): euler_matrices' "ZXY"
        rotations[rows, i] = tf.matrix_to_quat(tf.euler_matrices(np.radians(deg), "ZXY"))
    check_positions(positions, valid, 1.0, source, [f"{n}.poses" for n in names],
                    lambda k, i: f"pose {int(np.searchsorted(parsed[i][0], time_ms[k]))}")
    positions, rotations = to_internal(positions, rotations, "Y", "right", "m")
    devices = [Device(CAMERA, "hmd", "head")] + [Device(n, "controller") for n in names[1:]]
    time = (time_ms - time_ms[0]) / 1000.0
    check_time(time, source, "timestamp", "sample")  # distinct milliseconds can round to one second's float
    rec = Recording(name=path.name.split(".")[0], time=time, devices=devices,
                    positions=positions, rotations=rotations, valid=valid, source=source)
    rec.notes.append("A-Frame motion capture: converted from three.js axes (Y up, right-handed, metres; "
                     "rotations as Euler 'YXZ' degrees) to Z up; times from the first sample")
    _tell_hands(rec, doc, hands)
    return rec


def _entity(ent, name: str, source: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(timestamps ms (P,), positions (P, 3), Euler degrees (P, 3)) of one entity, every value
    checked: one line naming the entity and the pose otherwise."""
    fld = f"{name}.poses"
    if not isinstance(ent, dict) or not isinstance(ent.get("poses"), list):
        raise BodyCalError("not an entity {\"poses\": [...]}", source=source, field=name)
    poses = ent["poses"]
    if not poses:
        raise BodyCalError("no pose recorded", source=source, field=fld)
    rows = _fast_rows(poses)
    if rows is None:
        rows = _careful_rows(poses, source, fld)
    ts = rows[:, 6]
    back = np.flatnonzero(np.diff(ts) <= 0)
    if back.size:
        k = int(back[0]) + 1
        raise BodyCalError(f"timestamp must increase ({ts[k - 1]:g} then {ts[k]:g} ms)", source=source,
                           field=f"{fld}.timestamp", where=f"pose {k}")
    return ts, rows[:, :3], rows[:, 3:6]


def _fast_rows(poses: list) -> np.ndarray | None:
    """(P, 7) position, rotation, timestamp of clean poses in a few numpy calls; None when any is
    not (the careful path then names it)."""
    try:
        rows = [(p["position"]["x"], p["position"]["y"], p["position"]["z"], p["rotation"]["x"], p["rotation"]["y"],
                 p["rotation"]["z"], p["timestamp"]) for p in poses]
    except (KeyError, TypeError, IndexError):
        return None
    if not set(map(type, itertools.chain.from_iterable(rows))) <= {int, float}:  # bools, strings, nulls
        return None
    try:
        arr = np.array(rows, float)
    except OverflowError:
        return None
    with np.errstate(invalid="ignore"):
        return arr if (np.abs(arr) <= 1e300).all() else None


def _careful_rows(poses: list, source: str, fld: str) -> np.ndarray:
    rows = np.empty((len(poses), 7))
    for k, pose in enumerate(poses):
        if not isinstance(pose, dict):
            raise BodyCalError(f"expected {{position, rotation, timestamp}}, got {short_repr(pose)}", source=source,
                               field=fld, where=f"pose {k}")
        rows[k, :3] = _vector(pose.get("position"), source, f"{fld}.position", k)
        rows[k, 3:6] = _vector(pose.get("rotation"), source, f"{fld}.rotation", k)
        rows[k, 6] = _number(pose.get("timestamp"), source, f"{fld}.timestamp", k)
    return rows


def _vector(v, source: str, fld: str, k: int) -> list[float]:
    if not isinstance(v, dict):
        raise BodyCalError(f"expected {{x, y, z}}, got {short_repr(v)}", source=source, field=fld, where=f"pose {k}")
    return [_number(v.get(a), source, f"{fld}.{a}", k) for a in _AXES]


def _number(x, source: str, fld: str, k: int) -> float:
    # `type` rather than isinstance: JSON true / false are Python bools, which are ints.
    if type(x) not in (int, float) or not math.isfinite(x) or abs(x) > 1e300:
        raise BodyCalError(f"not a finite number: {short_repr(x)}", source=source, field=fld, where=f"pose {k}")
    return float(x)


def _label(name: str, ent: dict) -> str | None:
    """'left' / 'right' from the entity's id, else from its Gamepad API `hand`; None when neither says."""
    sides = {w.lower() for w in _WORD_RE.findall(name)} & {"left", "right"}
    if len(sides) == 1:
        return sides.pop()
    pad = ent.get("gamepad")
    hand = pad.get("hand") if isinstance(pad, dict) else None
    return hand.lower() if isinstance(hand, str) and hand.lower() in ("left", "right") else None


def _tell_hands(rec: Recording, doc: dict, hands: str) -> None:
    """Roles hand_l / hand_r for two controllers (as `hands` says); one controller takes its
    label's; more than two keep none (the Devices list assigns them)."""
    ctrl = [d for d in rec.devices if d.kind == "controller"]
    labels = [_label(d.name, doc[d.name]) for d in ctrl]
    if len(ctrl) == 1 and labels[0]:
        ctrl[0].role = "hand_l" if labels[0] == "left" else "hand_r"
        rec.notes.append(f"one controller, '{ctrl[0].name}': the {labels[0]} hand, as the file labels it")
        return
    if len(ctrl) != 2:
        if ctrl:
            rec.notes.append(f"{len(ctrl)} controllers: give each its role in the Devices list")
        return
    a, b = (rec.device_index(d.name) for d in ctrl)
    valid = rec.valid[:, 0] & rec.valid[:, a] & rec.valid[:, b]
    share, frames = right_share(rec.positions[:, 0], rec.rotations[:, 0], rec.positions[:, a], rec.positions[:, b],
                                valid)
    labelled = None
    if sorted(labels, key=str) == ["left", "right"]:
        labelled = labels.index("right")
    right, note = choose_hands(hands, labelled, share, frames, (ctrl[0].name, ctrl[1].name), "headset")
    if right is not None:
        ctrl[right].role, ctrl[1 - right].role = "hand_r", "hand_l"
    pads = [doc[d.name].get("gamepad", {}).get("hand") if isinstance(doc[d.name].get("gamepad"), dict) else None
            for d in ctrl]
    if all(isinstance(p, str) and p for p in pads) and [p.lower() for p in pads] != labels:
        note += f" (the gamepads say '{ctrl[0].name}' is {pads[0]}, '{ctrl[1].name}' {pads[1]}: not used)"
    rec.notes.append(note)
