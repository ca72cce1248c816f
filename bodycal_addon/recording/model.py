"""`Recording`: a tracker recording as numpy arrays in the internal frame (FORMATS.md §2).

Internal frame = Blender's: right-handed, Z up, metres, floor at z = 0. Readers convert once, at
load; everything downstream sees only this. Arrays have a leading frame axis.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from ..core.errors import BodyCalError

DEVICE_KINDS = ("hmd", "controller", "tracker", "rigid_body")
ROLES = ("head", "hand_l", "hand_r", "pelvis", "chest", "upperarm_l", "upperarm_r", "forearm_l", "forearm_r",
         "thigh_l", "thigh_r", "shin_l", "shin_r", "foot_l", "foot_r")
# Where a user assigns device roles in Blender: the hint of every error about a missing role.
ROLES_LIST = "Sidebar > BodyCal > Recording > Devices"
STEPS = ("tpose", "stand", "palms_together", "touch", "flex_elbow_l", "flex_elbow_r", "flex_knee_l",
         "flex_knee_r", "swing_shoulder_l", "swing_shoulder_r", "swing_hip_l", "swing_hip_r", "pivot_tip_l",
         "pivot_tip_r", "motion")


@dataclass
class Device:
    name: str
    kind: str
    role: str | None = None
    identified: bool = False  # the role was found from the T-pose (roles.py), not given


@dataclass
class Segment:
    """A calibration step (FORMATS.md §2.4) between two times, in seconds."""

    step: str
    start: float
    end: float
    point: str | None = None  # touch: the body point touched
    by: str | None = None  # touch: the marker / device tip that touches

    @property
    def label(self) -> str:
        return ":".join(p for p in (self.step, self.point, self.by) if p)


@dataclass
class Recording:
    name: str
    time: np.ndarray  # (F,) seconds, strictly increasing
    devices: list[Device]
    positions: np.ndarray  # (F, D, 3) device origins
    rotations: np.ndarray  # (F, D, 4) unit quaternions w, x, y, z
    valid: np.ndarray  # (F, D) bool: tracked this frame
    marker_names: list[str] = field(default_factory=list)
    markers: np.ndarray | None = None  # (F, M, 3)
    marker_valid: np.ndarray | None = None  # (F, M) bool
    segments: list[Segment] = field(default_factory=list)
    source: str = ""
    notes: list[str] = field(default_factory=list)  # what the reader did (roles identified, gaps filled)

    def __post_init__(self):
        n = len(self.time)
        if self.markers is None:
            self.markers = np.zeros((n, 0, 3))
            self.marker_valid = np.zeros((n, 0), bool)

    @property
    def frame_count(self) -> int:
        return len(self.time)

    @property
    def fps(self) -> float:
        if len(self.time) < 2:
            return 0.0
        return float((len(self.time) - 1) / (self.time[-1] - self.time[0]))

    def device_index(self, name_or_role: str) -> int:
        for i, d in enumerate(self.devices):
            if d.role == name_or_role:
                return i
        for i, d in enumerate(self.devices):
            if d.name == name_or_role:
                return i
        raise BodyCalError(f"no device with role or name '{name_or_role}'", source=self.source or self.name,
                           hint=f"assign device roles ({ROLES_LIST}) or record a tpose segment")

    def has_role(self, role: str) -> bool:
        return any(d.role == role for d in self.devices)

    def pose(self, name_or_role: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(positions (F, 3), rotations (F, 4), valid (F,)) of one device."""
        i = self.device_index(name_or_role)
        return self.positions[:, i], self.rotations[:, i], self.valid[:, i]

    def marker(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """(points (F, 3), valid (F,)) of one marker."""
        try:
            i = self.marker_names.index(name)
        except ValueError:
            raise BodyCalError(f"no marker named '{name}'", source=self.source or self.name) from None
        return self.markers[:, i], self.marker_valid[:, i]

    def frames(self, start: float, end: float) -> np.ndarray:
        """Indices of the frames with start <= time <= end."""
        lo = np.searchsorted(self.time, start, side="left")
        hi = np.searchsorted(self.time, end, side="right")
        return np.arange(lo, hi)

    def window(self, lo: int, hi: int) -> Recording:
        """A copy holding frames lo..hi-1 (the arrays are views), the steps cut to its span and
        those outside it left out."""
        t0, t1 = float(self.time[lo]), float(self.time[hi - 1])
        segments = [replace(s, start=max(s.start, t0), end=min(s.end, t1)) for s in self.segments
                    if s.end > t0 and s.start < t1]
        return replace(self, time=self.time[lo:hi], positions=self.positions[lo:hi],
                       rotations=self.rotations[lo:hi], valid=self.valid[lo:hi], markers=self.markers[lo:hi],
                       marker_valid=self.marker_valid[lo:hi], segments=segments, notes=list(self.notes))

    def segments_of(self, step: str) -> list[Segment]:
        return [s for s in self.segments if s.step == step]
