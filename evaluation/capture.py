"""Devices strapped on a performer, and the recording an outside tool would write (FORMATS.md §2.1).

Profiles:
- `full`: HMD, two controllers, pelvis, chest, upper arms, forearms, thighs, shins and feet;
- `six`: AvatarGo's six devices (HMD, two controllers, pelvis and both feet), the usual home set;
- `four`: HMD, two controllers and a pelvis tracker;
- `three`: HMD and two controllers, what a standalone headset has.

Mountings (per seed): every tracker and controller at a uniformly random orientation; positions
on the body surface where people strap them (sizes of an adult scaled by the performer's leg):
the pelvis tracker on the lower back, the chest tracker on the sternum, limb trackers part way
down the limb a limb's radius off its axis, foot trackers on the instep (in front of the ankle,
on top of the foot), the controller's grip centre in the closed hand, the HMD's origin at the
eyes, its axes the OpenXR view's (x right, y up, -z forward) within a few degrees. The places
come from anatomy, not from the engine; the engine's defaults for what a recording does not
measure (bodycal_addon/calibration/defaults.py) rest on the same anatomy, so where the two agree
it says the defaults are consistent with it, not that they fit every body or controller.

Noise: white noise on every pose (`noise_mm` per axis, `noise_deg` RMS angle), soft-tissue motion
of strapped trackers (band-limited, `wobble_mm` RMS and a degree per 4 mm of it), and dropouts
(runs of untracked frames, written as null). The file is written in SteamVR's convention (Y up,
right-handed, -Z forward) or Z up, in metres or centimetres, by this module's own code.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from . import rot
from .performer import FORWARD, LEFT, UP, Performer, _smooth_noise
from .session import Session

PROFILES = {
    "full": ("head", "hand_l", "hand_r", "pelvis", "chest", "upperarm_l", "upperarm_r", "forearm_l", "forearm_r",
             "thigh_l", "thigh_r", "shin_l", "shin_r", "foot_l", "foot_r"),
    "six": ("head", "hand_l", "hand_r", "pelvis", "foot_l", "foot_r"),
    "four": ("head", "hand_l", "hand_r", "pelvis"),
    "three": ("head", "hand_l", "hand_r"),
}
ADULT_LEG_M = 0.85  # hip to knee to ankle of the adult the sizes below are for
# Lab (Z up) -> file conventions: points file = A @ lab.
TO_FILE = {"Y": np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]), "Z": np.eye(3)}
UNITS = {"m": 1.0, "cm": 100.0}


@dataclass
class Mount:
    role: str
    joint: int  # BVH joint whose frame the device rides on
    offset: np.ndarray  # (3,) in that frame, metres
    rotation: np.ndarray  # (3, 3) device axes in that frame
    kind: str
    name: str


@dataclass
class Capture:
    """A recording (lab frame, before it is written) and what it was made from."""

    session: Session
    profile: str
    mounts: list[Mount]
    positions: np.ndarray  # (F, D, 3) lab frame
    rotations: np.ndarray  # (F, D, 3, 3)
    valid: np.ndarray  # (F, D)
    params: dict = field(default_factory=dict)

    def write(self, path, *, up: str = "Y", units: str = "m", name: str | None = None) -> Path:
        """The FORMATS.md §2.1 JSON file."""
        A = TO_FILE[up]
        scale = UNITS[units]
        fps = self.session.fps
        F = self.positions.shape[0]
        devices, poses = [], {}
        for d, m in enumerate(self.mounts):
            devices.append({"name": m.name, "kind": m.kind, "role": m.role})
            p = self.positions[:, d] @ A.T * scale
            q = rot.to_quat(np.einsum("ij,fjk->fik", A, self.rotations[:, d]))
            rows = np.concatenate([p, q], axis=1)
            poses[m.name] = [None if not ok else [round(float(v), 7) for v in r]
                             for r, ok in zip(rows.tolist(), self.valid[:, d])]
        doc = {
            "format": "bodycal-recording", "version": 1,
            "coords": {"up": up, "handedness": "right", "units": units},
            "name": name or Path(path).name.split(".")[0],
            "devices": devices, "markers": [],
            "time": [round(k / fps, 9) for k in range(F)],
            "poses": poses, "points": {},
            "segments": [{**s, "start": round(s["start"], 6), "end": round(s["end"], 6)}
                         for s in self.session.segments],
        }
        path = Path(path)
        path.write_text(json.dumps(doc))
        return path

    def truth(self) -> dict:
        """What the benchmark compares against (lab frame = the engine's internal frame)."""
        s = self.session
        return {"fps": s.fps, "joints": s.notes["truth_joints"], "positions": s.truth,
                "segments": s.segments, "motion": s.motion, "stance": s.stance, "yaw": s.yaw,
                "origin": s.origin, "profile": self.profile, "params": self.params}


def _random_rotation(rng) -> np.ndarray:
    q = rng.normal(size=4)
    return rot.from_quat(q / np.linalg.norm(q))


def _axes(perf: Performer, joint: int):
    """(along the segment, its front, its lateral-left) in the segment's own frame: the rest
    pose's directions, the CMU rest facing -Y in the lab."""
    along = rot.unit(perf.child_offset(joint))
    ref = FORWARD if abs(along @ FORWARD) < 0.8 else UP
    front = rot.unit(ref - (ref @ along) * along)
    return along, front, np.cross(along, front) * (1.0 if np.cross(along, front) @ LEFT >= 0 else -1.0)


def mounts_for(perf: Performer, profile: str, rng) -> list[Mount]:
    k = perf.leg_length / ADULT_LEG_M
    out = []
    serial = iter(rng.choice(np.arange(0x1000, 0xFFFF), size=32, replace=False))

    def tracker_name():
        return f"LHR-{next(serial):04X}"

    def around(along, front, left, lateral_sign, angle_deg):
        a = np.radians(angle_deg)
        return np.cos(a) * front + np.sin(a) * left * lateral_sign

    for role in PROFILES[profile]:
        s = role[-1] if role[-2:] in ("_l", "_r") else None
        sign = 1.0 if s == "l" else -1.0
        R = _random_rotation(rng)
        if role == "head":
            j = perf.j("skull_base")
            off = FORWARD * rng.uniform(0.080, 0.092) * k + UP * rng.uniform(0.028, 0.042) * k
            R = np.stack([-LEFT, UP, -FORWARD], axis=1)  # OpenXR view axes: x right, y up, -z forward
            R = rot.axis_angle(LEFT, np.radians(rng.uniform(-6, 6))) @ rot.axis_angle(
                FORWARD, np.radians(rng.uniform(-2, 2))) @ R
            out.append(Mount(role, j, off, R, "hmd", "hmd"))
            continue
        if role.startswith("hand_"):
            j = perf.j(f"wrist_{s}")
            along = rot.unit(perf.child_offset(j))
            palm = perf.palm_normal_rest(s)
            # OpenXR's grip pose: the centre of the closed fist, part way along the palm and inside
            # the fist on the palm side (adult sizes; the wrist joint is ~1.5 cm above the crease)
            off = (along * rng.uniform(0.055, 0.070) + palm * rng.uniform(0.022, 0.032)
                   + np.cross(along, palm) * rng.uniform(-0.01, 0.01)) * k
            out.append(Mount(role, j, off, R, "controller", f"ctrl_{s.upper()}"))
            continue
        if role == "pelvis":
            j = perf.j("pelvis")
            off = (-FORWARD * rng.uniform(0.10, 0.13) + UP * rng.uniform(0.0, 0.08)
                   + LEFT * rng.uniform(-0.02, 0.02)) * k
        elif role == "chest":
            j = perf.j("chest")
            off = (FORWARD * rng.uniform(0.09, 0.12) + UP * rng.uniform(0.0, 0.06)
                   + LEFT * rng.uniform(-0.02, 0.02)) * k
        elif role.startswith("foot_"):
            j = perf.j(f"ankle_{s}")
            along = perf.child_offset(j)
            length = np.linalg.norm(along)
            along = along / length
            dorsal = rot.unit(UP - (UP @ along) * along)
            off = (along * rng.uniform(0.30, 0.55) * length + dorsal * rng.uniform(0.030, 0.045) * k
                   + np.cross(along, dorsal) * rng.uniform(-0.01, 0.01) * k)
        else:
            part = role[:-2]
            joint = {"upperarm": "shoulder", "forearm": "elbow", "thigh": "hip", "shin": "knee"}[part]
            j = perf.j(f"{joint}_{s}")
            length = np.linalg.norm(perf.child_offset(j))
            along, front, left = _axes(perf, j)
            frac, radius, angle = {
                "thigh": ((0.35, 0.60), (0.075, 0.095), (30, 90)),
                "shin": ((0.30, 0.60), (0.045, 0.060), (-40, 40)),
                "upperarm": ((0.35, 0.65), (0.050, 0.065), (50, 130)),
                "forearm": ((0.60, 0.85), (0.035, 0.050), (30, 150)),
            }[part]
            radial = around(along, front, left, sign, rng.uniform(*angle))
            off = along * rng.uniform(*frac) * length + radial * rng.uniform(*radius) * k
        out.append(Mount(role, j, off, R, "tracker", tracker_name()))
    return out


def _dropouts(rng, F: int, protect: tuple[int, int], rate_per_s: float, fps: float) -> np.ndarray:
    """(F,) valid flags with runs of 2-20 untracked frames (none inside `protect`)."""
    valid = np.ones(F, bool)
    n = rng.poisson(rate_per_s * F / fps)
    for _ in range(n):
        a = int(rng.integers(0, F))
        b = min(F, a + int(rng.integers(2, 21)))
        if b > protect[0] and a < protect[1]:
            continue
        valid[a:b] = False
    return valid


def capture(session: Session, perf: Performer, profile: str = "full", *, seed: int = 0, noise_mm: float = 0.5,
            noise_deg: float = 0.3, wobble_mm: float = 1.5, dropouts_per_s: float = 0.03) -> Capture:
    """Devices on the performer of `session`, with noise and dropouts."""
    rng = np.random.default_rng(seed + 7919)
    mounts = mounts_for(perf, profile, rng)
    F, D = session.frame_count, len(mounts)
    fps = session.fps
    pos = np.empty((F, D, 3))
    R = np.empty((F, D, 3, 3))
    valid = np.ones((F, D), bool)
    tpose = next(s for s in session.segments if s["step"] == "tpose")
    protect = (int(tpose["start"] * fps), int(tpose["end"] * fps) + 1)
    for d, m in enumerate(mounts):
        G, P = session.G[:, m.joint], session.P[:, m.joint]
        off = np.broadcast_to(m.offset, (F, 3)).copy()
        turn = np.broadcast_to(np.eye(3), (F, 3, 3))
        if m.kind == "tracker" and wobble_mm > 0:  # the strap slides and the flesh under it moves
            off = off + _smooth_noise(rng, F, fps, 3, wobble_mm / 1000.0 / np.sqrt(3), 0.3, 2.0)
            turn = rot.exp(_smooth_noise(rng, F, fps, 3, np.radians(wobble_mm / 4.0) / np.sqrt(3), 0.3, 2.0))
        pos[:, d] = P + np.einsum("fij,fj->fi", G, off)
        R[:, d] = G @ turn @ m.rotation
        pos[:, d] += rng.normal(scale=noise_mm / 1000.0, size=(F, 3))
        R[:, d] = R[:, d] @ rot.exp(rng.normal(scale=np.radians(noise_deg) / np.sqrt(3), size=(F, 3)))
        valid[:, d] = _dropouts(rng, F, protect, dropouts_per_s, fps)
    params = {"seed": seed, "noise_mm": noise_mm, "noise_deg": noise_deg, "wobble_mm": wobble_mm,
              "dropouts_per_s": dropouts_per_s}
    return Capture(session, profile, mounts, pos, R, valid, params)
