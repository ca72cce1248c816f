"""`bodycal record` against a hostile sender, over loopback and bounded in time: random datagrams,
truncated packets, wrong types, NaN and 1e30 positions, nested bundles, stray `/VMC/Ext/T` values,
then a flood of 20,000 frames whose sender clock runs 90 frames a second while they arrive far
faster. The command stays up, counts and skips every bad item (the counts exact), keeps no NaN,
and writes a take whose clock follows arrival: its length is the session's wall time (before, a
10 s session gave a 693 s take, steps of up to 39 s between frames), its steps never far from the
arrival's. A sender that restarts its clock still follows arrival (test_vmc_record.py)."""

import json
import signal
import socket
import time

import numpy as np
from pythonosc.osc_bundle_builder import IMMEDIATELY, OscBundleBuilder
from test_live_cli import Recording, free_port

from bodycal_addon.recording.io import load_recording
from bodycal_addon.recording.live.recorder import LEAD_S
from bodycal_addon.recording.live.vmc import message

HMD = ("/VMC/Ext/Hmd/Pos/Local", "HMD-1")
TRACKER = ("/VMC/Ext/Tra/Pos/Local", "LHR-1")


def _bundle(*contents, nested: int = 0) -> bytes:
    """A bundle of `contents` (messages), inside `nested` more bundles."""
    b = OscBundleBuilder(IMMEDIATELY)
    for c in contents:
        b.add_content(c)
    built = b.build()
    for _ in range(nested):
        outer = OscBundleBuilder(IMMEDIATELY)
        outer.add_content(built)
        built = outer.build()
    return built.dgram


def _device(address_serial, x, y=1.0, z=0.0):
    address, serial = address_serial
    return message(address, serial, float(x), float(y), float(z), 0.0, 0.0, 0.0, 1.0)


def _frame(k: int, t: float, nested: int = 0) -> bytes:
    return _bundle(_device(HMD, 0.001 * k, 1.6), _device(TRACKER, 0.001 * k), message("/VMC/Ext/T", float(t)),
                   nested=nested)


class Sender:
    """A UDP socket to the command, paced so that the kernel drops nothing before the flood."""

    def __init__(self, port):
        self.sock, self.to = socket.socket(socket.AF_INET, socket.SOCK_DGRAM), ("127.0.0.1", port)
        self.k = 0  # frames sent with a sender time k / 90

    def send(self, dgram: bytes, pause: float = 0.0005):
        self.sock.sendto(dgram, self.to)
        time.sleep(pause)

    def frames(self, n: int, pause: float = 1 / 90, nested: int = 0):
        for _ in range(n):
            self.send(_frame(self.k, self.k / 90.0, nested), pause)
            self.k += 1


def test_garbage_then_a_flood_leave_record_up_counted_and_its_take_on_the_arrival_clock(tmp_path):
    rng = np.random.default_rng(11)
    port, out = free_port(), tmp_path / "hostile.bcrec.json"
    recording = Recording("--port", port, "-o", out)
    assert recording.first and "listening for VMC" in recording.first[0]
    s = Sender(port)
    s.frames(45)  # half a second of a normal stream
    bad_datagrams = bad_messages = 0
    for _ in range(60):  # random bytes, never whole OSC words
        size = int(rng.integers(1, 300))
        size += size % 4 == 0
        s.send(bytes(rng.integers(0, 256, size, dtype=np.uint8)))
        bad_datagrams += 1
    whole = _frame(0, 0.0)
    for _ in range(60):  # a frame's bundle cut short (never at a whole word: nothing of it can be read)
        cut = int(rng.integers(17, len(whole) - 1))
        cut -= cut % 4 == 0
        s.send(whole[:cut])
        bad_datagrams += 1
    wrong = [message(HMD[0], 7, 0.0, 1.6, 0.0, 0.0, 0.0, 0.0, 1.0),  # the serial a number
             message(HMD[0], "HMD-1", "0", "1.6", "0", "0", "0", "0", "1"),  # numbers as text
             message(HMD[0], "HMD-1", 0.0, 1.6),  # too few
             message("/VMC/Ext/T", "soon"),  # a time as text
             message("/VMC/Ext/Tra/Pos/Local", "LHR-1", float("nan"), 1.0, 0.0, 0.0, 0.0, 0.0, 1.0),  # NaN
             message("/VMC/Ext/Tra/Pos/Local", "LHR-1", 1e30, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0),  # 1e30 m
             message("/VMC/Ext/Hmd/Pos/Local", "HMD-1", 0.0, 1.6, 0.0, float("nan"), 0.0, 0.0, 1.0),  # NaN turn
             message("/VMC/Ext/T", float("nan"))]
    for k in range(40):
        bad = wrong[k % len(wrong)]
        s.send(_bundle(bad, nested=k % 3))  # in bundles nested up to three deep
        bad_messages += 1
        s.frames(1, pause=0.002, nested=k % 4)  # a good frame between: nested bundles are read
    for stray in (1e9, -1e9, 0.0, 3.4e38, 5.0, 1e6, -3.0, 123456.0):  # /VMC/Ext/T alone: closes a frame
        s.send(_bundle(_device(HMD, 0.0, 1.6), message("/VMC/Ext/T", stray)), pause=0.005)
        s.frames(3, pause=0.005)
    flood = 20_000
    for _ in range(flood):  # the sender's clock at 90 Hz, the frames as fast as they go
        s.send(_frame(s.k, s.k / 90.0), pause=0.0)
        s.k += 1
    s.frames(45)  # and half a second of the normal stream again
    time.sleep(0.3)
    code, stdout, stderr = recording.finish(signal.SIGINT, timeout=60)
    assert code == 0, stderr  # still up, ended by Ctrl-C, the take written
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(
        f"bodycal record: warning: {bad_datagrams} bad packets and {bad_messages} bad messages skipped"), stderr
    take = load_recording(out, raw=True)
    arrival = np.asarray(json.loads(out.read_text())["extra"]["live"]["arrival"])
    assert len(arrival) == take.frame_count and take.frame_count > 45 + 40 + 8 * 4  # the flood: what the kernel kept
    for values in (take.time, take.positions[take.valid], take.rotations[take.valid]):
        assert np.isfinite(values).all()
    assert np.abs(take.positions[take.valid]).max() <= 0.001 * s.k + 1.6  # only what good frames carried
    assert np.all(np.diff(take.time) > 0)
    session = arrival[-1] - arrival[0]  # the session's wall time, from the first frame to the last
    length = take.time[-1] - take.time[0]
    assert session < 60.0 and abs(length - session) <= LEAD_S + 0.05, (length, session)
    assert np.diff(take.time).max() <= np.diff(arrival).max() + LEAD_S, np.diff(take.time).max()
    assert "arrival clock" in stdout  # the sender's clock was not followed all the way, and it says so
