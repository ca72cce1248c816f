"""Hand frames from LED gloves: three markers on the back of each hand (`hand_led1..3_<s>`) give a
position and an orientation, added to a recording as a rigid_body device with role hand_<s>
when the recording has no hand pose of its own."""

from __future__ import annotations

import numpy as np

from ..core import transforms as tf
from .gaps import hold_untracked
from .model import Device, Recording

LED_NAMES = tuple(f"hand_led{i}" for i in (1, 2, 3))


def led_hand_frame(led1, led2, led3):
    """Hand frame from the three LEDs on the back of the glove (arrays (..., 3)): origin = mean,
    Y = led1 -> led2 (toward the middle finger base), Z = (led2 - led1) x (led3 - led1) (out of the back
    of the hand), X = Y x Z. Returns (origin, quaternion, ok) where ok is False for degenerate LEDs."""
    led1, led2, led3 = (np.asarray(v, float) for v in (led1, led2, led3))
    a, b = led2 - led1, led3 - led1
    y = tf.normalize(a)
    z = np.cross(a, b)
    z = tf.normalize(z - (z * y).sum(-1, keepdims=True) * y)
    x = np.cross(y, z)
    ok = (np.linalg.norm(a, axis=-1) > 1e-6) & (np.linalg.norm(np.cross(a, b), axis=-1) > 1e-9)
    m = np.stack([x, y, z], axis=-1)
    m = np.where(ok[..., None, None], m, np.eye(3))
    return (led1 + led2 + led3) / 3.0, tf.matrix_to_quat(m), ok


def add_led_hand_frames(rec: Recording) -> None:
    """Add a rigid_body device with role hand_<s> built from hand_led1..3_<s> when no hand_<s> pose exists."""
    for s in ("l", "r"):
        role = f"hand_{s}"
        if rec.has_role(role):
            continue
        names = [f"{n}_{s}" for n in LED_NAMES]
        if not all(n in rec.marker_names for n in names):
            continue
        idx = [rec.marker_names.index(n) for n in names]
        origin, quat, ok = led_hand_frame(*(rec.markers[:, j] for j in idx))
        ok = ok & rec.marker_valid[:, idx].all(axis=1)
        name = role if all(d.name != role for d in rec.devices) else f"{role}_leds"
        rec.devices.append(Device(name=name, kind="rigid_body", role=role))
        rec.positions = np.concatenate([rec.positions, origin[:, None]], axis=1)
        rec.rotations = np.concatenate([rec.rotations, quat[:, None]], axis=1)
        rec.valid = np.concatenate([rec.valid, ok[:, None]], axis=1)
        hold_untracked(rec.positions[:, -1:], rec.valid[:, -1:], rec.rotations[:, -1:])
        rec.notes.append(f"built the {role} frame from LEDs {', '.join(names)} (device '{name}', "
                         f"{int(ok.sum())} of {len(ok)} frames)")
