"""Small recordings with known answers for the reader, role and import tests (no Blender needed).

A 1.75 m performer in T-pose, facing `yaw` radians from Blender's -Y, with the devices of the
`full` or `minimal` profile at known places on the body, an HMD looking along its local -Z, and
LED-glove markers whose hand frame is known."""

from __future__ import annotations

import numpy as np

from bodycal_addon.core import transforms as tf
from bodycal_addon.recording.model import Device, Recording, Segment

# Body frame: x = performer's left, y = forward, z = up (metres).
FULL = {
    "head": ("hmd", (0.0, 0.08, 1.65)),
    "hand_l": ("controller", (0.85, 0.0, 1.42)), "hand_r": ("controller", (-0.85, 0.0, 1.42)),
    "pelvis": ("tracker", (0.0, -0.12, 1.0)), "chest": ("tracker", (0.0, 0.12, 1.30)),
    "upperarm_l": ("tracker", (0.32, 0.0, 1.40)), "upperarm_r": ("tracker", (-0.32, 0.0, 1.40)),
    "forearm_l": ("tracker", (0.58, 0.0, 1.41)), "forearm_r": ("tracker", (-0.58, 0.0, 1.41)),
    "thigh_l": ("tracker", (0.13, 0.08, 0.65)), "thigh_r": ("tracker", (-0.13, 0.08, 0.65)),
    "shin_l": ("tracker", (0.12, 0.06, 0.35)), "shin_r": ("tracker", (-0.12, 0.06, 0.35)),
    "foot_l": ("tracker", (0.11, 0.10, 0.08)), "foot_r": ("tracker", (-0.11, 0.10, 0.08)),
}
MINIMAL_ROLES = ("head", "hand_l", "hand_r", "pelvis", "foot_l", "foot_r")


def body_axes(yaw: float):
    """(left, forward, up) world vectors of a performer turned `yaw` from facing -Y."""
    c, s = np.cos(yaw), np.sin(yaw)
    rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    return rz @ np.array([1.0, 0, 0]), rz @ np.array([0, -1.0, 0]), np.array([0, 0, 1.0])


def tpose_recording(*, yaw: float = 0.0, profile: str = "full", fps: float = 90.0, seconds: float = 4.0,
                    seed: int = 0, roles: bool = True, shuffle: bool = False, leds: bool = False,
                    origin=(0.3, -0.2, 0.0), noise: float = 0.002) -> Recording:
    """T-pose for the first half (segment `tpose`), then a swaying `motion` segment."""
    rng = np.random.default_rng(seed)
    left, fwd, up = body_axes(yaw)
    f = int(round(seconds * fps))
    time = np.arange(f) / fps
    role_list = list(FULL) if profile == "full" else list(MINIMAL_ROLES)
    if leds:
        role_list = [r for r in role_list if r not in ("hand_l", "hand_r")]
    if shuffle:
        rng.shuffle(role_list)
    devices, pos, rot = [], [], []
    sway = np.where(time > seconds / 2, 0.05 * np.sin(2 * np.pi * 0.5 * time), 0.0)
    for k, role in enumerate(role_list):
        kind, (x, y, z) = FULL[role]
        base = np.asarray(origin) + x * left + y * fwd + z * up
        p = base + sway[:, None] * left + rng.normal(0, noise, (f, 3))
        devices.append(Device(name=f"LHR-{k:02d}" if shuffle else role, kind=kind, role=role if roles else None))
        pos.append(p)
        # Devices look forward (local -Z), local +Y up, local +X the performer's right.
        m = np.stack([-left, up, -fwd], axis=-1)
        q = tf.matrix_to_quat(m)
        wobble = tf.axis_angle_to_quat(np.array([0, 0, 1.0]), 0.05 * np.sin(time + k))
        rot.append(tf.quat_mul(wobble, q))
    rec = Recording(name="tpose_test", time=time, devices=devices, positions=np.stack(pos, 1),
                    rotations=np.stack(rot, 1), valid=np.ones((f, len(devices)), bool),
                    segments=[Segment("tpose", 0.05 * seconds, 0.45 * seconds),
                              Segment("motion", 0.5 * seconds, float(time[-1]))])
    if leds:
        names, pts = [], []
        for s, sign in (("l", 1.0), ("r", -1.0)):
            _kind, (x, y, z) = FULL[f"hand_{s}"]
            wrist = np.asarray(origin) + (x - sign * 0.05) * left + y * fwd + z * up
            out = sign * left  # along the arm, toward the fingers
            back_side = -fwd if s == "l" else fwd  # makes (led2 - led1) x (led3 - led1) point up (back of hand)
            led1 = wrist
            led2 = wrist + 0.07 * out
            led3 = wrist + 0.035 * out + 0.03 * back_side
            for nm, p in ((f"hand_led1_{s}", led1), (f"hand_led2_{s}", led2), (f"hand_led3_{s}", led3),
                          (f"index_tip_{s}", wrist + 0.17 * out + 0.02 * fwd)):
                names.append(nm)
                pts.append(np.tile(p, (f, 1)) + sway[:, None] * left)
        rec.marker_names = names
        rec.markers = np.stack(pts, 1)
        rec.marker_valid = np.ones((f, len(names)), bool)
    return rec


def recording_doc(rec: Recording) -> dict:
    """The JSON document of `rec` in the internal convention (Z up, right-handed, metres)."""
    doc = {
        "format": "bodycal-recording", "version": 1, "coords": {"up": "Z", "handedness": "right", "units": "m"},
        "devices": [{"name": d.name, "kind": d.kind, "role": d.role} for d in rec.devices],
        "markers": [{"name": n} for n in rec.marker_names],
        "time": rec.time.tolist(),
        "poses": {d.name: np.concatenate([rec.positions[:, i], rec.rotations[:, i]], 1).tolist()
                  for i, d in enumerate(rec.devices)},
        "points": {n: rec.markers[:, j].tolist() for j, n in enumerate(rec.marker_names)},
        "segments": [{"step": s.step, "start": s.start, "end": s.end} for s in rec.segments],
    }
    return doc
