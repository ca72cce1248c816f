"""The VMC receiver (recording/live/): what python-osc's own client sends, read into frames in the
internal frame; bundles, the /Local messages, frames without /VMC/Ext/T; bad packets counted and
skipped; the latest-wins hand-off; Unity's axes both ways. Sockets on 127.0.0.1, ephemeral ports."""

import math
import socket
import subprocess
import sys
import time

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pythonosc.osc_bundle_builder import IMMEDIATELY, OscBundleBuilder
from pythonosc.osc_message_builder import OscMessageBuilder
from pythonosc.udp_client import SimpleUDPClient
from repo_paths import REPO

from bodycal_addon.core import transforms as tf
from bodycal_addon.core.errors import BodyCalError
from bodycal_addon.recording import coords
from bodycal_addon.recording.live import vmc
from bodycal_addon.recording.live.receiver import VmcReceiver

S45 = math.sqrt(0.5)


class Collect:
    """A sink keeping every frame."""

    def __init__(self):
        self.frames = []

    def __call__(self, frame):
        self.frames.append(frame)


@pytest.fixture()
def receiver():
    r = VmcReceiver(port=0)
    got = Collect()
    r.add_sink(got)
    r.start()
    r.got = got
    yield r
    r.stop()


def wait_for(cond, seconds=3.0):
    deadline = time.monotonic() + seconds
    while not cond():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.005)


def osc(address, *args):
    b = OscMessageBuilder(address)
    for a in args:
        b.add_arg(a)
    return b.build()


def bundle(*contents):
    b = OscBundleBuilder(IMMEDIATELY)
    for c in contents:
        b.add_content(c)
    return b.build()


def test_device_messages_from_python_osc_arrive_as_frames_in_the_internal_frame(receiver):
    client = SimpleUDPClient("127.0.0.1", receiver.port)
    # Unity: y up, left-handed, the avatar facing +Z. The tracker is turned 90 degrees about +Y (its
    # forward, Unity's +Z, now along +X); the HMD at Unity's identity looks along +Z.
    client.send_message("/VMC/Ext/Hmd/Pos/Local", ["HMD-1", 0.3, 1.6, -0.2, 0.0, 0.0, 0.0, 1.0])
    client.send_message("/VMC/Ext/Tra/Pos/Local", ["LHR-1", -0.1, 1.0, 0.5, 0.0, S45, 0.0, S45])
    client.send_message("/VMC/Ext/Con/Pos/Local", ["CTRL-L", 0.0, 1.2, 0.0, 0.0, 0.0, 0.0, 1.0])
    client.send_message("/VMC/Ext/T", 12.5)
    wait_for(lambda: receiver.got.frames)
    f = receiver.got.frames[0]
    assert f.devices == ("HMD-1", "LHR-1", "CTRL-L") and f.sender_time == 12.5
    assert receiver.devices == {"HMD-1": "hmd", "LHR-1": "tracker", "CTRL-L": "controller"}
    # Internal: Z up, right-handed, the performer's forward +Y: Unity (x, y, z) is (x, z, y).
    np.testing.assert_allclose(f.positions[0], [0.3, -0.2, 1.6], atol=1e-6)
    np.testing.assert_allclose(f.positions[1], [-0.1, 0.5, 1.0], atol=1e-6)
    # A device looks along its local -Z with local +Y up (OpenXR, FORMATS.md §1): the HMD forward
    # (+Y), the tracker along +X, both upright.
    np.testing.assert_allclose(tf.rotate(f.rotations[0], [0, 0, -1.0]), [0, 1, 0], atol=1e-6)
    np.testing.assert_allclose(tf.rotate(f.rotations[1], [0, 0, -1.0]), [1, 0, 0], atol=1e-6)
    np.testing.assert_allclose(tf.rotate(f.rotations[1], [0, 1.0, 0]), [0, 0, 1], atol=1e-6)
    assert ("device", "LHR-1", "tracker", None) in f.events


def test_bundles_nested_local_wins_over_scaled_and_scaled_only_devices_are_reported(receiver):
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    for k in range(2):
        inner = bundle(osc("/VMC/Ext/Tra/Pos", "A", 9.0, 9.0, 9.0, 0.0, 0.0, 0.0, 1.0),
                       osc("/VMC/Ext/Tra/Pos/Local", "A", 1.0, 2.0, float(k), 0.0, 0.0, 0.0, 1.0))
        outer = bundle(inner, osc("/VMC/Ext/Tra/Pos", "B", 0.5, 0.5, 0.5, 0.0, 0.0, 0.0, 1.0),
                       osc("/VMC/Ext/Bone/Pos", "Hips", 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0),
                       osc("/VMC/Ext/T", 1.0 + k))
        sock.sendto(outer.dgram, ("127.0.0.1", receiver.port))
    sock.close()
    wait_for(lambda: len(receiver.got.frames) == 2)
    for k, f in enumerate(receiver.got.frames):
        np.testing.assert_allclose(f.positions[f.devices.index("A")], [1.0, k, 2.0])  # the /Local values
        np.testing.assert_allclose(f.positions[f.devices.index("B")], [0.5, 0.5, 0.5])
    assert receiver.stats.scaled_devices == {"B"}
    assert receiver.stats.ignored_messages == 2  # the bones


def test_a_sender_without_time_messages_gets_a_frame_per_round_of_devices():
    r = VmcReceiver(port=0)
    got = Collect()
    r.add_sink(got)
    with r:
        client = SimpleUDPClient("127.0.0.1", r.port)
        for k in range(3):
            client.send_message("/VMC/Ext/Tra/Pos", ["A", float(k), 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
            client.send_message("/VMC/Ext/Tra/Pos", ["B", float(k), 1.0, 0.0, 0.0, 0.0, 0.0, 1.0])
        wait_for(lambda: len(got.frames) == 2)  # each closed when its first device came again
    assert len(got.frames) == 3  # the last one at the stop
    for k, f in enumerate(got.frames):
        assert f.devices == ("A", "B") and f.sender_time is None
        assert f.positions[0, 0] == k


BAD = [
    b"",
    b"\x00\x01garbage",
    b"/VMC/Ext/Tra/Pos\x00\x00\x00\x00,sfff",  # cut inside the type tags' arguments
    osc("/VMC/Ext/Tra/Pos", "A", 1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0).dgram[:40],  # truncated
    bundle(osc("/VMC/Ext/T", 1.0)).dgram[:-3],  # a bundle cut short
    b"#bundle\x00" + b"\x00" * 8 + b"\x00\x00\x01\x00" + b"/x\x00\x00",  # an element longer than the bundle
]
BAD_MESSAGES = [
    ("/VMC/Ext/Tra/Pos", ["A", 1, 2, 3, 0, 0, 0, 1]),  # ints
    ("/VMC/Ext/Tra/Pos", ["A", "1.0", 2.0, 3.0, 0.0, 0.0, 0.0, 1.0]),  # a string
    ("/VMC/Ext/Tra/Pos", ["A", 1.0, 2.0, 3.0]),  # too few
    ("/VMC/Ext/Tra/Pos", ["A", float("nan"), 2.0, 3.0, 0.0, 0.0, 0.0, 1.0]),
    ("/VMC/Ext/Con/Pos/Local", ["A", 1.0, float("inf"), 3.0, 0.0, 0.0, 0.0, 1.0]),
    ("/VMC/Ext/Hmd/Pos", ["A", 1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 2.0]),  # not a unit quaternion
    ("/VMC/Ext/Hmd/Pos", ["A", 1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 0.0]),  # zero
    ("/VMC/Ext/Tra/Pos", ["", 1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0]),  # no serial
    ("/VMC/Ext/Tra/Pos", [7, 1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0]),  # a number for a serial
    ("/VMC/Ext/Tra/Pos", ["A", 2e4, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0]),  # 20 km away
    ("/VMC/Ext/T", ["soon"]),
    ("/VMC/Ext/T", [float("nan")]),
    ("/BodyCal/Marker/Pos", ["index_tip_r", 1.0]),
    ("/BodyCal/Device", ["A", "spaceship", ""]),
    ("/BodyCal/Segment", ["tpose", "", "", 2.0, 1.0]),  # ends before it starts
]


def test_bad_packets_and_messages_are_counted_and_skipped_and_a_flood_ends_nothing(receiver):
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    addr = ("127.0.0.1", receiver.port)
    for d in BAD:
        sock.sendto(d, addr)
    client = SimpleUDPClient(*addr)
    for address, args in BAD_MESSAGES:
        client.send_message(address, args)
    client.send_message("/VMC/Ext/Blend/Val", ["Joy", 1.0])  # read by others, ignored here
    client.send_message("/VMC/Ext/Tra/Pos/Local", ["A", 1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0])
    client.send_message("/VMC/Ext/T", 1.0)
    wait_for(lambda: receiver.got.frames)
    s = receiver.stats
    assert (s.bad_datagrams, s.bad_messages, s.ignored_messages) == (len(BAD), len(BAD_MESSAGES), 1)
    assert receiver.got.frames[0].devices == ("A",)
    assert s.last_error
    for _ in range(3000):  # a flood of junk: the socket may drop some; nothing breaks
        sock.sendto(b"\xff" * 64, addr)
    client.send_message("/VMC/Ext/Tra/Pos/Local", ["A", 4.0, 5.0, 6.0, 0.0, 0.0, 0.0, 1.0])
    client.send_message("/VMC/Ext/T", 2.0)
    wait_for(lambda: len(receiver.got.frames) == 2)
    assert receiver.running and s.bad_datagrams > len(BAD)
    np.testing.assert_allclose(receiver.got.frames[1].positions[0], [4.0, 6.0, 5.0])
    sock.close()


def test_names_beyond_the_limit_are_refused():
    a = vmc.FrameAssembler()
    msgs = [osc("/VMC/Ext/Tra/Pos", f"S{k}", 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0) for k in range(vmc.MAX_DEVICES + 9)]
    frames = []
    for m in msgs + [osc("/VMC/Ext/T", 1.0)]:
        frames += a.feed(m.dgram, 0.0)
    assert len(frames[0].devices) == vmc.MAX_DEVICES and a.stats.refused_names == 9


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300))
def test_any_bytes_are_a_frame_or_a_counted_bad_packet(data):
    a = vmc.FrameAssembler()
    for prefix in (b"", b"#bundle\x00", b"/VMC/Ext/Tra/Pos\x00\x00\x00\x00"):
        a.feed(prefix + data, 0.0)
    assert a.stats.datagrams == 3


_VALUES = st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=32), st.integers(-2**31, 2**31 - 1),
                    # NUL ends an OSC string; a lone surrogate has no UTF-8 (the client cannot send it)
                    st.text(st.characters(exclude_characters="\x00", exclude_categories=("Cs",)), max_size=8),
                    st.booleans())


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.sampled_from([*vmc.DEVICE_ADDRESSES, vmc.TIME, vmc.MARKER, vmc.DEVICE_INFO,
                                           vmc.SEGMENT, vmc.MARKER_INFO, "/other"]),
                          st.lists(_VALUES, max_size=9)), max_size=12))
def test_any_osc_messages_give_finite_unit_frames(messages):
    a = vmc.FrameAssembler()
    frames = []
    for address, args in messages:
        b = OscMessageBuilder(address)
        for v in args:
            b.add_arg(v)
        frames += a.feed(b.build().dgram, 0.0)
    last = a.flush(0.0)
    for f in frames + ([last] if last else []):
        assert np.isfinite(f.positions).all() and np.isfinite(f.points).all()
        np.testing.assert_allclose(np.linalg.norm(f.rotations, axis=-1), 1.0, atol=1e-9)


def test_latest_wins_hands_the_newest_frame_and_counts_the_ones_it_replaced(receiver):
    assert receiver.latest() is None  # a consumer now takes frames: drops count from here
    client = SimpleUDPClient("127.0.0.1", receiver.port)
    for k in range(5):
        client.send_message("/VMC/Ext/Tra/Pos/Local", ["A", float(k), 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
        client.send_message("/VMC/Ext/T", float(k))
    wait_for(lambda: len(receiver.got.frames) == 5)  # the sink saw every frame
    newest = receiver.latest()
    assert newest.index == 4 and newest.sender_time == 4.0
    assert receiver.stats.dropped == 4
    assert receiver.latest() is None  # never a queue: nothing older is waiting


def test_a_sink_that_fails_is_reported_and_the_others_go_on(receiver):
    def broken(frame):
        raise RuntimeError("disk full")

    receiver._sinks.insert(0, broken)
    client = SimpleUDPClient("127.0.0.1", receiver.port)
    for k in range(2):
        client.send_message("/VMC/Ext/Tra/Pos/Local", ["A", float(k), 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
        client.send_message("/VMC/Ext/T", float(k))
    wait_for(lambda: len(receiver.got.frames) == 2)
    assert receiver.stats.sink_error == "RuntimeError: disk full" and receiver.running


def test_a_port_in_use_is_one_clear_error():
    other = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    other.bind(("127.0.0.1", 0))
    try:
        with pytest.raises(BodyCalError, match="is in use"):
            VmcReceiver(port=other.getsockname()[1]).start()
    finally:
        other.close()


def test_stop_reads_what_already_arrived_and_the_open_frame():
    r = VmcReceiver(port=0)
    got = Collect()
    r.add_sink(got)
    r.start()
    client = SimpleUDPClient("127.0.0.1", r.port)
    client.send_message("/VMC/Ext/Tra/Pos/Local", ["A", 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0])
    time.sleep(0.05)
    r.stop()
    r.stop()  # twice is fine
    assert [f.devices for f in got.frames] == [("A",)]


# --- Unity's axes, both ways --------------------------------------------------------------------------


def test_unity_turns_convert_both_ways():
    # A turn of +90 degrees about Unity's +Y takes +Z (forward) to +X; in the internal frame
    # (Unity +Z is +Y, +X is +X) it takes +Y to +X: -90 degrees about +Z.
    unity = np.array([S45, 0.0, S45, 0.0])  # w, x, y, z
    internal = coords.turns_to_internal(unity, *vmc.UNITY[:2])
    np.testing.assert_allclose(internal, [S45, 0.0, 0.0, -S45], atol=1e-12)
    np.testing.assert_allclose(coords.turns_from_internal(internal, *vmc.UNITY[:2]), unity, atol=1e-12)
    rng = np.random.default_rng(3)
    q = tf.quat_normalize(rng.normal(size=(50, 4)))
    back = coords.turns_from_internal(coords.turns_to_internal(q, "Y", "left"), "Y", "left")
    np.testing.assert_allclose(np.abs((back * q).sum(-1)), 1.0, atol=1e-12)
    # Turns compose as the frames they relate: A B in Unity is A' B' inside.
    a, b = q[:25], q[25:]
    np.testing.assert_allclose(
        np.abs((coords.turns_to_internal(tf.quat_mul(a, b), "Y", "left")
                * tf.quat_mul(coords.turns_to_internal(a, "Y", "left"),
                              coords.turns_to_internal(b, "Y", "left"))).sum(-1)), 1.0, atol=1e-12)


def test_unity_device_poses_convert_both_ways():
    rng = np.random.default_rng(4)
    pos = rng.normal(size=(20, 3))
    rot = tf.quat_normalize(rng.normal(size=(20, 4)))
    p, q = coords.to_internal(*coords.from_internal(pos, rot, *vmc.UNITY), *vmc.UNITY)
    np.testing.assert_allclose(p, pos, atol=1e-12)
    np.testing.assert_allclose(q, rot, atol=1e-12)  # the sign kept: a track stays continuous


def test_the_engine_imports_without_python_osc():
    """Only the live modules and the commands that run them import python-osc: the extension's
    registration and every other command work where it is missing."""
    live = ("recording.live.vmc", "recording.live.receiver", "recording.live.sender",
            "output.vmc_bones", "app.commands.record", "app.commands.stream")
    modules = sorted(".".join(p.relative_to(REPO).with_suffix("").parts)
                     for p in (REPO / "bodycal_addon").rglob("*.py") if "blender" not in p.parts)
    modules = [m.removesuffix(".__init__") for m in modules if not m.endswith(("__main__",) + live)]
    code = ("import sys; sys.modules['pythonosc'] = None; sys.modules['bpy'] = None\n"
            f"import importlib\nfor m in {modules!r}: importlib.import_module(m)\n"
            "assert 'pythonosc' not in [k for k, v in sys.modules.items() if v is not None]")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr[-2000:]
