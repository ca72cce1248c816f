"""The VMC protocol (FORMATS.md §6), read and written with python-osc.

VMC (sh-akira's VirtualMotionCaptureProtocol, V3.1) is OSC over UDP, Marionettes listening on
port 39539. What BodyCal reads, in Unity's axes (Y up, left-handed, metres; quaternions x, y, z, w):

- `/VMC/Ext/Hmd/Pos`, `/VMC/Ext/Con/Pos`, `/VMC/Ext/Tra/Pos` (serial, p.x, p.y, p.z, q.x, q.y, q.z,
  q.w): an HMD, a controller, a tracker. The specification: these are "adjusted to the avatar's
  scale"; the `/Local` variants carry the raw device values. A device that has sent `/Local` is
  read from it only; one that never does is read from the scaled message and reported.
- `/VMC/Ext/T` (time): the sender's clock. VirtualMotionCapture sends it last in its per-frame
  bundle, so it closes a frame.
- BodyCal's own (the specification says receivers ignore addresses they do not know):
  `/BodyCal/Marker/Pos` (name, x, y, z) an optical marker (FORMATS.md §2.1 markers: VMC has none),
  `/BodyCal/Device` (name, kind, role) a device's kind and role, `/BodyCal/Marker` (name) a
  marker's name, `/BodyCal/Segment` (step, point, by, start, end) a calibration step.

Anything else (bones, blend shapes, `/VMC/Ext/OK`, ...) is counted and ignored, as the
specification asks. Frames: a frame closes at `/VMC/Ext/T`, or, for a sender without it, when a
device or marker already in the open frame arrives again (the message then opens the next frame).
Bundles (nested too) are read in order; a datagram's end closes nothing, as senders split a frame
into several bundles to keep each under 1500 bytes.
"""

from __future__ import annotations

import math
import struct
import time

import numpy as np
from pythonosc.osc_bundle import OscBundle
from pythonosc.osc_bundle import ParseError as BundleError
from pythonosc.osc_bundle_builder import IMMEDIATELY, OscBundleBuilder
from pythonosc.osc_message import OscMessage
from pythonosc.osc_message import ParseError as MessageError
from pythonosc.osc_message_builder import OscMessageBuilder
from pythonosc.parsing.osc_types import ParseError as TypeParseError

from ...core.errors import BodyCalError
from ..coords import MAX_POSITION_M, QUAT_TOLERANCE, from_internal, to_internal
from ..model import DEVICE_KINDS, ROLES
from ..segments import check_segment
from .source import LiveFrame, SourceStats

DEFAULT_PORT = 39539  # a Marionette's port (the specification)
UNITY = ("Y", "left", "m")  # Unity's axes as a `coords` convention (recording/coords.py)
DEVICE_ADDRESSES = {f"/VMC/Ext/{tag}/Pos{local}": (kind, bool(local))
                    for tag, kind in (("Hmd", "hmd"), ("Con", "controller"), ("Tra", "tracker"))
                    for local in ("", "/Local")}
ADDRESS_TAG = {"hmd": "Hmd", "controller": "Con", "tracker": "Tra", "rigid_body": "Tra"}  # kind -> address part
TIME = "/VMC/Ext/T"
AVAILABLE = "/VMC/Ext/OK"
ROOT = "/VMC/Ext/Root/Pos"
BONE = "/VMC/Ext/Bone/Pos"
MARKER = "/BodyCal/Marker/Pos"
DEVICE_INFO = "/BodyCal/Device"
MARKER_INFO = "/BodyCal/Marker"
SEGMENT = "/BodyCal/Segment"
_BUNDLE = b"#bundle\x00"
MAX_DATAGRAM = 1400  # bytes per bundle sent: within one Ethernet frame (the specification: 1500)
MAX_DEVICES = 64  # distinct devices a stream may name; more are refused (a flood of serials)
MAX_MARKERS = 256
MAX_NAME = 128  # characters of a serial or marker name
# python-osc on untrusted bytes: its parse errors, and what its decoders raise on a cut datagram
PARSE_ERRORS = (BundleError, MessageError, TypeParseError, IndexError, struct.error, UnicodeDecodeError,
                ValueError, OverflowError, RecursionError)


def _framed(dgram: bytes) -> bool:
    """Every OSC packet is a whole number of 4-byte words, and a bundle's elements fill it exactly:
    python-osc pads what is missing at the end of a datagram with zeros (a cut float would read as
    another number), so a cut or overrunning datagram is refused here first."""
    spans = [(0, len(dgram))]
    while spans:
        lo, hi = spans.pop()
        if (hi - lo) % 4:
            return False
        if dgram.startswith(_BUNDLE, lo):
            i = lo + 16
            if i > hi:
                return False
            while i < hi:
                size = int.from_bytes(dgram[i:i + 4], "big", signed=True)
                if size <= 0 or i + 4 + size > hi:
                    return False
                spans.append((i + 4, i + 4 + size))
                i += 4 + size
    return True


def osc_messages(dgram: bytes) -> list[tuple[str, list]]:
    """(address, arguments) of every message of a datagram, bundles opened in order (nested ones
    too). Raises one of PARSE_ERRORS for what is not OSC."""
    if not _framed(dgram):
        raise ValueError("cut short or overrunning")
    if OscBundle.dgram_is_bundle(dgram):
        out: list[tuple[str, list]] = []
        stack = [iter(OscBundle(dgram))]
        while stack:
            item = next(stack[-1], None)
            if item is None:
                stack.pop()
            elif isinstance(item, OscBundle):
                stack.append(iter(item))
            else:
                out.append((item.address, item.params))
        return out
    if OscMessage.dgram_is_message(dgram):
        msg = OscMessage(dgram)
        return [(msg.address, msg.params)]
    raise ValueError("neither an OSC message nor a bundle")


def _name(value) -> str | None:
    """A serial or marker name: a non-empty string of printable characters, at most MAX_NAME."""
    if isinstance(value, str) and 0 < len(value) <= MAX_NAME and value.isprintable() and value.strip() == value:
        return value
    return None


def _floats(args, start: int, count: int) -> list[float] | None:
    """args[start:start + count] when they are all finite floats (OSC f or d), else None."""
    vals = args[start:start + count]
    if len(vals) != count:
        return None
    for v in vals:
        if type(v) is not float:
            return None
    total = sum(vals)
    # inf or NaN anywhere makes the sum's difference with itself NaN (so does an overflow of the
    # sum, which only values far beyond any position or quaternion can reach)
    return vals if total - total == 0.0 else None


def _pose(args, known=frozenset()) -> tuple[str | None, list[float] | None, str]:
    """(serial, [px, py, pz, qx, qy, qz, qw] with q renormalised, why not) of a device message;
    `known` serials need no second look at their text."""
    serial = args[0] if args and type(args[0]) is str and args[0] in known else _name(args[0]) if args else None
    if serial is None:
        return None, None, "the serial is not a name"
    vals = _floats(args, 1, 7)
    if vals is None:
        return serial, None, "needs 7 finite floats after the serial"
    px, py, pz, qx, qy, qz, qw = vals
    if not (abs(px) < MAX_POSITION_M and abs(py) < MAX_POSITION_M and abs(pz) < MAX_POSITION_M):
        return serial, None, f"position {MAX_POSITION_M:g} m or more from the origin"
    norm = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw)
    if abs(norm - 1.0) > QUAT_TOLERANCE:
        return serial, None, f"quaternion not unit length (|q| = {norm:.6g})"
    return serial, [px, py, pz, qx / norm, qy / norm, qz / norm, qw / norm], ""


class FrameAssembler:
    """Datagrams in, frames out (module docstring): `feed` returns the frames a datagram
    completed, `flush` the frame still open (at the end of a stream). Keeps the stream's device
    kinds and roles, and `stats`."""

    def __init__(self, stats: SourceStats | None = None):
        self.stats = stats or SourceStats()
        self.kinds: dict[str, str] = {}
        self.roles: dict[str, str | None] = {}
        self.marker_names: set[str] = set()
        self._local: set[str] = set()  # devices that send /Local: their scaled messages are ignored
        self._index = 0
        self._open()

    def _open(self) -> None:
        self._poses: dict[str, list[float]] = {}
        self._points: dict[str, list[float]] = {}
        self._seen: set[tuple[str, str]] = set()
        self._sender_time: float | None = None
        self._events: list = []

    def feed(self, dgram: bytes, arrival: float) -> list[LiveFrame]:
        self.stats.datagrams += 1
        try:
            messages = osc_messages(dgram)
        except PARSE_ERRORS as exc:
            self._bad("datagram", f"not OSC ({type(exc).__name__})")
            return []
        done: list[LiveFrame] = []
        for address, args in messages:
            self._message(address, args, arrival, done)
        return done

    def flush(self, arrival: float) -> LiveFrame | None:
        return self._close(arrival) if (self._poses or self._points) else None

    # --- messages -------------------------------------------------------------------------------

    def _bad(self, what: str, why: str) -> None:
        if what == "datagram":
            self.stats.bad_datagrams += 1
        else:
            self.stats.bad_messages += 1
        self.stats.last_error = f"{what}: {why}"

    def _message(self, address: str, args: list, arrival: float, done: list) -> None:
        if address in DEVICE_ADDRESSES:
            self._device(address, args, arrival, done)
        elif address == MARKER:
            self._marker(args, arrival, done)
        elif address == TIME:
            t = _floats(args, 0, 1)
            if t is None:
                self._bad(address, "needs a finite float")
                return
            self._sender_time = t[0]
            if self.kinds or self.marker_names:  # an empty frame is every known device untracked
                done.append(self._close(arrival))
        elif address in (DEVICE_INFO, MARKER_INFO, SEGMENT):
            self._announcement(address, args)
        else:
            self.stats.ignored_messages += 1

    def _repeat(self, key: tuple[str, str], arrival: float, done: list) -> None:
        """A device or marker already in the open frame: a sender without /VMC/Ext/T began the next."""
        if key in self._seen:
            done.append(self._close(arrival))
        self._seen.add(key)

    def _known(self, name: str, table, limit: int) -> bool:
        if name in table:
            return True
        if len(table) >= limit:
            self.stats.refused_names += 1
            return False
        return True

    def _device(self, address: str, args: list, arrival: float, done: list) -> None:
        kind, local = DEVICE_ADDRESSES[address]
        if not local and args and type(args[0]) is str and args[0] in self._local:
            return  # the raw values of this device come in its /Local message: this one is not read
        serial, pose, why = _pose(args, self.kinds.keys())
        if pose is None:
            self._bad(address, why)
            return
        if not self._known(serial, self.kinds, MAX_DEVICES):
            return
        self._repeat((address, serial), arrival, done)
        if serial not in self.kinds:
            self.kinds[serial] = kind
            self.roles[serial] = None
            self._events.append(("device", serial, kind, None))
        if local:
            self._local.add(serial)
            self.stats.scaled_devices.discard(serial)
        else:
            self.stats.scaled_devices.add(serial)
        self._poses[serial] = pose

    def _marker(self, args: list, arrival: float, done: list) -> None:
        name = _name(args[0]) if args else None
        point = _floats(args, 1, 3)
        if name is None or point is None or max(abs(v) for v in point) >= MAX_POSITION_M:
            self._bad(MARKER, "needs a name and 3 finite floats (metres)")
            return
        if not self._known(name, self.marker_names, MAX_MARKERS):
            return
        self._repeat((MARKER, name), arrival, done)
        if name not in self.marker_names:
            self.marker_names.add(name)
            self._events.append(("marker", name))
        self._points[name] = point

    def _announcement(self, address: str, args: list) -> None:
        if not all(isinstance(a, str) for a in args[:3]):
            self._bad(address, "needs text arguments")
        elif address == MARKER_INFO:
            name = _name(args[0]) if args else None
            if name is None:
                self._bad(address, "needs a marker name")
            elif name not in self.marker_names and self._known(name, self.marker_names, MAX_MARKERS):
                self.marker_names.add(name)
                self._events.append(("marker", name))
        elif address == DEVICE_INFO:
            self._device_info(args)
        else:
            self._segment(args)

    def _device_info(self, args: list) -> None:
        name = _name(args[0]) if args else None
        kind, role = (args[1:3] + ["", ""])[:2]
        if name is None or kind not in DEVICE_KINDS or (role and role not in ROLES):
            self._bad(DEVICE_INFO, "needs a device name, a kind and a role or \"\"")
            return
        if not self._known(name, self.kinds, MAX_DEVICES):
            return
        if self.kinds.get(name) != kind or self.roles.get(name) != (role or None):
            self.kinds[name], self.roles[name] = kind, role or None
            self._events.append(("device", name, kind, role or None))

    def _segment(self, args: list) -> None:
        times = _floats(args, 3, 2)
        if len(args) < 5 or times is None:
            self._bad(SEGMENT, "needs step, point, by and two finite times")
            return
        try:
            self._events.append(("segment", check_segment(args[0], args[1], args[2], *times)))
        except BodyCalError as exc:
            self._bad(SEGMENT, exc.line())

    # --- frames ---------------------------------------------------------------------------------

    def _close(self, arrival: float) -> LiveFrame:
        names = tuple(self._poses)
        raw = np.array([self._poses[n] for n in names], float).reshape(-1, 7)
        pos, rot = to_internal(raw[:, :3], raw[:, [6, 3, 4, 5]], *UNITY)
        markers = tuple(self._points)
        pts = np.array([self._points[n] for n in markers], float).reshape(-1, 3)
        points, _ = to_internal(pts, None, *UNITY)
        frame = LiveFrame(self._index, arrival, self._sender_time, names, pos, rot, markers, points,
                          tuple(self._events))
        self._index += 1
        self.stats.frames += 1
        self._open()
        return frame


# --- writing ------------------------------------------------------------------------------------


def message(address: str, *args) -> OscMessage:
    """One OSC message: str as s, float as f (VMC's float32), int as i."""
    b = OscMessageBuilder(address)
    for a in args:
        b.add_arg(a, "s" if isinstance(a, str) else "i" if isinstance(a, int) else "f")
    return b.build()


def bundles(messages: list[OscMessage], limit: int = MAX_DATAGRAM) -> list[bytes]:
    """The messages in order, packed into as few bundles of at most `limit` bytes as they fit in (a
    message larger than that goes alone)."""
    out, group, size = [], [], 16
    for m in messages:
        if group and size + 4 + m.size > limit:
            out.append(_bundle(group))
            group, size = [], 16
        group.append(m)
        size += 4 + m.size
    if group:
        out.append(_bundle(group))
    return out


def _bundle(group: list[OscMessage]) -> bytes:
    b = OscBundleBuilder(IMMEDIATELY)
    for m in group:
        b.add_content(m)
    return b.build().dgram


def device_messages(names, kinds, positions, rotations, *, scaled: bool = True) -> list[OscMessage]:
    """`/VMC/Ext/<Hmd|Con|Tra>/Pos/Local` (and, with `scaled`, the plain message with the same
    values: a receiver that reads only those still gets the devices) of each device, from internal
    positions (n, 3) and rotations (n, 4) w, x, y, z."""
    pos, rot = from_internal(positions, rotations, *UNITY)
    out = []
    for name, kind, p, q in zip(names, kinds, pos.tolist(), rot.tolist(), strict=True):
        base = f"/VMC/Ext/{ADDRESS_TAG[kind]}/Pos"
        args = (name, p[0], p[1], p[2], q[1], q[2], q[3], q[0])
        if scaled:
            out.append(message(base, *args))
        out.append(message(base + "/Local", *args))
    return out


def now() -> float:
    """The clock frames are stamped with."""
    return time.perf_counter()

