"""Write Beat Saber replays (BeatLeader's `.bsor` version 1: the header and frames
`bodycal_addon.recording.io.bsor` reads, then empty notes, walls, heights and pauses blocks), so the
reader's tests can make any file, a damaged one included, and turn another real take into one.
Development only: not part of the extension."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from bodycal_addon.recording.coords import from_internal
from bodycal_addon.recording.io.bsor import FRAME, MAGIC
from bodycal_addon.recording.model import Recording

INFO_DEFAULTS = {
    "mod version": "0.5.4", "game version": "1.27.0", "timestamp": "1677526799", "player id": "0",
    "player name": "BodyCal test", "platform": "steam", "tracking system": "OpenVR", "headset": "Test HMD",
    "controllers": "Test controllers", "map hash": "0" * 40, "song name": "Test song", "mapper": "BodyCal",
    "difficulty": "Normal", "score": 0, "mode": "Standard", "environment": "The First", "modifiers": "",
    "jump distance": 18.0, "left-handed": False, "height": 1.8, "start time": 0.0, "fail time": 0.0, "speed": 0.0,
}
_ORDER = ("mod version", "game version", "timestamp", "player id", "player name", "platform", "tracking system",
          "headset", "controllers", "map hash", "song name", "mapper", "difficulty")


def _string(s: str, utf16_count: bool = False) -> bytes:
    raw = s.encode("utf-8")
    count = len(s.encode("utf-16-le")) // 2 if utf16_count else len(raw)
    return struct.pack("<i", count) + raw


def header_bytes(info: dict | None = None, *, version: int = 1, utf16_counts: bool = False) -> bytes:
    """Magic, version and the info block; `utf16_counts`: the player name, song name and mapper
    counted in UTF-16 units, as some recorders wrote them."""
    i = {**INFO_DEFAULTS, **(info or {})}
    out = struct.pack("<I", MAGIC) + bytes([version, 0])
    for k in _ORDER:
        out += _string(i[k], utf16_counts and k in ("player name", "song name", "mapper"))
    out += struct.pack("<i", i["score"])
    for k in ("mode", "environment", "modifiers"):
        out += _string(i[k])
    out += struct.pack("<f?ffff", i["jump distance"], i["left-handed"], i["height"], i["start time"], i["fail time"],
                       i["speed"])
    return out


def frames_bytes(time, poses, fps=90) -> bytes:
    """The frames block: `time` (F,) song seconds, `poses` (F, 3, 7) head, left, right as Unity's
    x, y, z, qx, qy, qz, qw."""
    frames = np.zeros(len(time), FRAME)
    frames["time"], frames["fps"], frames["pose"] = time, fps, poses
    return bytes([1]) + struct.pack("<i", len(time)) + frames.tobytes()


def write_bsor(path, time, poses, info: dict | None = None, *, fps=90, utf16_counts: bool = False) -> Path:
    path = Path(path)
    tail = b"".join(bytes([k]) + struct.pack("<i", 0) for k in (2, 3, 4, 5))  # no notes, walls, heights, pauses
    path.write_bytes(header_bytes(info, utf16_counts=utf16_counts) + frames_bytes(time, poses, fps) + tail)
    return path


def unity_poses(rec: Recording, roles=("head", "hand_l", "hand_r")) -> np.ndarray:
    """(F, 3, 7) of a recording's head and hands in a replay's axes (Unity's: FORMATS.md §2.7),
    untracked frames all zeros as the game writes them."""
    out = np.zeros((rec.frame_count, 3, 7))
    for k, role in enumerate(roles):
        p, q, ok = rec.pose(role)
        pos, rot = from_internal(p, q, "Y", "left", "m")
        out[:, k, :3] = pos
        out[:, k, 3:] = rot[:, [1, 2, 3, 0]]
        out[~ok, k] = 0.0
    return out
