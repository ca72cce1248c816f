"""The Beat Saber replay reader (FORMATS.md §2.7): BeatLeader's open replay format, `.bsor` version 1
(github.com/BeatLeader/BS-Open-Replay), its header and its frames; checked and converted to the
internal frame. Why BodyCal reads it itself rather than through py-bsor: DESIGN.md §1, "Three-point
kits' own files".

Layout (little-endian; a string is an int32 byte count and UTF-8 bytes): the magic int32 0x442d3d69,
the version byte (1), the info block (byte 0, thirteen strings: mod version, game version, unix
timestamp, player id, player name, platform, tracking system, headset, controllers, map hash, song
name, mapper, difficulty; int32 score; strings mode, environment, modifiers; float32 jump distance;
bool left-handed; float32 player height; float32 start time, fail time, practice speed), then the
frames block (byte 1, int32 count, per frame: float32 song time, int32 fps, and head, left hand,
right hand, each float32 x, y, z, qx, qy, qz, qw). Notes, walls, height changes, pauses and what
follows are not read: a replay cut short after its frames still loads.

Axes: Unity's: Y up, left-handed, metres, the player facing +Z (FORMATS.md `coords` {"up": "Y",
"handedness": "left"}, as VMC). The hands are the sabers' poses. A device whose quaternion is all
zeros is untracked in that frame (the first frame of a replay is all zeros). Times are song time:
a frame whose time does not advance is dropped, and with a speed modifier (FS 1.2, SF 1.5, SS 0.85)
or a practice speed the times are divided by that speed, so they are the performer's seconds.
"""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np

from ...core.errors import BodyCalError
from ..coords import check_positions, check_quaternions, to_internal
from ..model import Device, Recording
from .hands import check_hands, choose_hands, right_share

MAGIC = 0x442D3D69
MAGIC_BYTES = struct.pack("<I", MAGIC)
VERSION = 1
FRAME = np.dtype([("time", "<f4"), ("fps", "<i4"), ("pose", "<f4", (3, 7))])  # 92 bytes a frame
DEVICES = (("head", "hmd", "head"), ("left_hand", "controller", "hand_l"), ("right_hand", "controller", "hand_r"))
_INFO_STRINGS = ("mod version", "game version", "timestamp", "player id", "player name", "platform",
                 "tracking system", "headset", "controllers", "map hash", "song name", "mapper", "difficulty")
# Strings some recorders wrote with a count in UTF-16 units, not bytes (py-bsor reads them the
# same way): the count can fall short of the bytes when the text is not ASCII.
_LOOSE_COUNTS = {"player name", "song name", "mapper"}
SPEED_MODIFIERS = {"FS": 1.2, "SF": 1.5, "SS": 0.85}  # Beat Saber's faster / super fast / slower song
MAX_STRING = 1 << 16  # longer than any header string a replay holds: a damaged count
_NEXT_STRING_MAX = 1024  # the strings after a loose one (platform, mapper, difficulty) are short


def is_bsor(head: bytes) -> bool:
    return head[:4] == MAGIC_BYTES


def read_bsor(path, hands: str = "geometry") -> Recording:
    """The head (kind hmd, role head) and the two sabers (kind controller, roles as `hands` says:
    recording/io/hands.py) of a replay's frames."""
    path = Path(path)
    source = path.name
    check_hands(hands, source)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise BodyCalError(f"cannot read: {exc.strerror}", source=source) from None
    r = _Reader(data, source)
    if r.u32("magic number") != MAGIC:
        raise BodyCalError("not a Beat Saber replay (no BSOR magic number)", source=source,
                           hint="a BeatLeader .bsor file starts with 0x442d3d69")
    version = r.byte("version")
    if version != VERSION:
        raise BodyCalError(f"BSOR version {version} is not known", source=source, field="version",
                           hint=f"this reader reads {VERSION}")
    info = _info(r)
    r.block(1, "frames")
    count = r.i32("frame count")
    room = (len(data) - r.at) // FRAME.itemsize
    if not 0 < count <= room:
        raise BodyCalError(f"{count} frames declared, the file holds {room}", source=source, field="frames",
                           hint="the replay is damaged or cut short")
    frames = np.frombuffer(data, FRAME, count, r.at)
    # checked in float32: widening a signalling NaN would warn before the one line
    bad = np.flatnonzero(~np.isfinite(frames["time"]) | ~np.isfinite(frames["pose"]).all(axis=(1, 2)))
    if bad.size:
        raise BodyCalError("not a finite number", source=source, field="frames", where=f"frame {bad[0]}")
    time, pose = frames["time"].astype(float), frames["pose"].astype(float)
    keep = np.ones(count, bool)
    keep[1:] = time[1:] > np.maximum.accumulate(time)[:-1]  # a frame whose time does not advance
    dropped = count - int(keep.sum())
    time, pose = time[keep], pose[keep]
    speed = _speed(info)
    positions, quat_xyzw = pose[:, :, :3], pose[:, :, 3:]
    valid = np.any(quat_xyzw != 0, axis=-1)  # all-zero quaternion: not tracked this frame
    rotations = np.where(valid[..., None], quat_xyzw[..., [3, 0, 1, 2]], 0.0)
    devices = [Device(n, k) for n, k, _ in DEVICES]
    # Each frame's index in the file, for the lines below (frames dropped above shift the count).
    file_frame = np.flatnonzero(keep)
    check_positions(positions, valid, 1.0, source, [f"frames.{n}" for n, _, _ in DEVICES],
                    lambda k, _i: f"frame {file_frame[k]}")
    check_quaternions(rotations, valid, time, devices, source, where_of=lambda k, _i: f"frame {file_frame[k]}")
    positions, rotations = to_internal(positions, rotations, "Y", "left", "m")
    rec = Recording(name=path.name.split(".")[0], time=(time - time[0]) / speed, devices=devices,
                    positions=positions, rotations=rotations, valid=valid, source=source)
    rec.notes.append(_describe(info, speed))
    if dropped:
        rec.notes.append(f"{dropped} frames dropped: their song time did not advance")
    _tell_hands(rec, hands, info)
    return rec


class _Reader:
    """Little-endian values from the start of `data`, each refused with one line naming the
    field when the file ends before it."""

    def __init__(self, data: bytes, source: str):
        self.data, self.source, self.at = data, source, 0

    def _take(self, n: int, what: str) -> bytes:
        if self.at + n > len(self.data):
            raise BodyCalError("the file ends here", source=self.source, field=what,
                               hint="the replay is damaged or cut short")
        out = self.data[self.at:self.at + n]
        self.at += n
        return out

    def u32(self, what):
        return struct.unpack("<I", self._take(4, what))[0]

    def i32(self, what):
        return struct.unpack("<i", self._take(4, what))[0]

    def f32(self, what):
        return struct.unpack("<f", self._take(4, what))[0]

    def byte(self, what):
        return self._take(1, what)[0]

    def block(self, marker: int, what: str) -> None:
        got = self.byte(what)
        if got != marker:
            raise BodyCalError(f"block starts with {got}, expected {marker}", source=self.source, field=what,
                               hint="the replay is damaged")

    def string(self, what: str) -> str:
        n = self.i32(what)
        if not 0 <= n <= MAX_STRING:
            raise BodyCalError(f"a string of {n} bytes", source=self.source, field=what, hint="the replay is damaged")
        raw = self._take(n, what)
        if what in _LOOSE_COUNTS:
            raw += self._loose_tail(n, what)
        return raw.decode("utf-8", errors="replace")

    def _loose_tail(self, n: int, what: str) -> bytes:
        """The bytes a UTF-16 count left out: taken one at a time until the next string's count
        is a plausible one (at most 3 bytes per counted unit: UTF-8's longest for one UTF-16 unit)."""
        start = self.at
        while self.at - start <= 2 * n:
            nxt = self.data[self.at:self.at + 4]
            if len(nxt) == 4 and 0 <= struct.unpack("<i", nxt)[0] <= _NEXT_STRING_MAX:
                break
            self.at += 1
        else:
            raise BodyCalError("unreadable text", source=self.source, field=what, hint="the replay is damaged")
        return self.data[start:self.at]


def _info(r: _Reader) -> dict:
    r.block(0, "info")
    info = {k: r.string(k) for k in _INFO_STRINGS}
    info["score"] = r.i32("score")
    for k in ("mode", "environment", "modifiers"):
        info[k] = r.string(k)
    info["jump distance"] = r.f32("jump distance")
    info["left-handed"] = r.byte("left-handed") == 1
    for k in ("height", "start time", "fail time", "speed"):
        info[k] = r.f32(k)
    return info


def _speed(info: dict) -> float:
    """How much faster than the performer's seconds the song time runs: the speed modifiers times
    the practice speed (0 in a replay that is not practice)."""
    speed = 1.0
    for m in info["modifiers"].split(","):
        speed *= SPEED_MODIFIERS.get(m.strip().upper(), 1.0)
    practice = info["speed"]
    if np.isfinite(practice) and 0.1 <= practice <= 10.0:
        speed *= practice
    return speed


def _describe(info: dict, speed: float) -> str:
    def short(s: str) -> str:
        s = " ".join(s.split())
        return s if len(s) <= 40 else s[:37] + "..."

    height = info["height"]
    tall = (f"player height {height:.2f} m (the game's setting)" if np.isfinite(height) and 0.5 < height < 3.0
            else "automatic player height")
    kit = f"{short(info['headset']) or 'a headset'} and {short(info['controllers']) or 'controllers'}"
    song = f"'{short(info['song name'])}' {short(info['difficulty'])}"
    line = (f"Beat Saber replay: {kit} ({short(info['tracking system']) or 'tracking unknown'}), {tall}, {song}; "
            "converted from Unity's axes (Y up, left-handed) to Z up")
    if speed != 1.0:
        line += f"; song time at {speed:g}x: times divided by {speed:g}"
    if info["left-handed"]:
        line += "; played left-handed"
    return line


def _tell_hands(rec: Recording, hands: str, info: dict) -> None:
    valid = rec.valid.all(axis=1)
    share, frames = right_share(rec.positions[:, 0], rec.rotations[:, 0], rec.positions[:, 2], rec.positions[:, 1],
                                valid)
    # controller 0 here is the replay's right hand (index 2), controller 1 its left (index 1)
    right, note = choose_hands(hands, 0, share, frames, ("right_hand", "left_hand"), "head")
    rec.devices[2 if right == 0 else 1].role = "hand_r"
    rec.devices[1 if right == 0 else 2].role = "hand_l"
    rec.devices[0].role = "head"
    rec.notes.append(note)
