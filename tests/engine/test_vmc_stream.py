"""A recording sent as a VMC stream (recording/live/sender.py): what python-osc's own server
receives (addresses, argument types, Unity's axes, the frame's end), and a replayed take recorded
again equals the original within OSC's float32 precision."""

import math
import socket
import threading

import numpy as np
import pytest
from osc_server import OscServer
from pythonosc.osc_packet import OscPacket
from recording_fixtures import tpose_recording

from bodycal_addon.core import transforms as tf
from bodycal_addon.core.errors import BodyCalError
from bodycal_addon.recording.io import load_recording, save_recording
from bodycal_addon.recording.live.receiver import VmcReceiver
from bodycal_addon.recording.live.recorder import LiveRecorder
from bodycal_addon.recording.live.sender import RecordingMessages, VmcSender, replay
from bodycal_addon.recording.model import Device, Recording, Segment

F32 = 2.0 ** -23


def known_take() -> Recording:
    """Three frames: an HMD at (0.3, -0.2, 1.6) looking forward (+Y), a rigid body turned to look
    along +X (upright), a marker; the rigid body untracked in frame 1, the marker in frame 2."""
    look_x = np.stack([[0, -1.0, 0], [0, 0, 1.0], [-1.0, 0, 0]], axis=-1)  # right -Y, up +Z, local -Z along +X
    look_y = np.stack([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]], axis=-1)
    rot = np.stack([tf.matrix_to_quat(look_y), tf.matrix_to_quat(look_x)])
    time = np.array([0.0, 0.1, 0.2])
    pos = np.array([[[0.3, -0.2, 1.6], [1.0, 2.0, 0.5]]] * 3)
    valid = np.array([[True, True], [True, False], [True, True]])
    return Recording("known", time, [Device("HMD-1", "hmd", "head"), Device("GLOVE_L", "rigid_body", "hand_l")],
                     pos, np.tile(rot, (3, 1, 1)), valid, ["index_tip_r"], np.full((3, 1, 3), 0.25),
                     np.array([[True], [True], [False]]), [Segment("tpose", 0.0, 0.1)])


def f32(x):
    return float(np.float32(x))


def test_python_osc_receives_the_devices_in_unity_axes_as_float32_and_time_last():
    with OscServer() as srv, VmcSender("127.0.0.1", srv.port) as sender:
        replay(RecordingMessages(known_take()), sender, speed=20.0)
        srv.wait_for("/VMC/Ext/T", 3)
    msgs = srv.messages
    times = [args for a, args in msgs if a == "/VMC/Ext/T"]
    assert times == [[0.0], [f32(0.1)], [f32(0.2)]]
    # Every frame ends with /VMC/Ext/T, after its devices (the frame's end for receivers).
    assert msgs[-1][0] == "/VMC/Ext/T"
    ends = [i for i, (a, _) in enumerate(msgs) if a == "/VMC/Ext/T"]
    frames = [msgs[(ends[k - 1] + 1 if k else 0):ends[k]] for k in range(3)]
    hmd = [args for a, args in frames[0] if a == "/VMC/Ext/Hmd/Pos/Local"]
    # Unity: x right, y up, z forward; a device looking forward is Unity's identity, one looking
    # along +X is turned +90 degrees about +Y: (x, y, z, w) = (0, sin 45, 0, cos 45).
    s45 = f32(math.sqrt(0.5))
    assert hmd == [["HMD-1", f32(0.3), f32(1.6), f32(-0.2), 0.0, 0.0, 0.0, 1.0]]
    glove = [args for a, args in frames[0] if a == "/VMC/Ext/Tra/Pos/Local"][0]
    assert glove[:4] == ["GLOVE_L", 1.0, 0.5, 2.0]
    np.testing.assert_allclose(glove[4:], [0.0, s45, 0.0, s45], atol=1e-7)
    assert [args for a, args in frames[0] if a == "/VMC/Ext/Tra/Pos"] == [glove]  # the plain one: the same
    assert not [a for a, _ in frames[1] if a.startswith("/VMC/Ext/Tra")]  # untracked in frame 1
    assert [args for a, args in frames[0] if a == "/BodyCal/Marker/Pos"] == [["index_tip_r", 0.25, 0.25, 0.25]]
    assert not [a for a, _ in frames[2] if a == "/BodyCal/Marker/Pos"]
    assert [args for a, args in frames[0] if a == "/BodyCal/Device"] == [["HMD-1", "hmd", "head"],
                                                                        ["GLOVE_L", "rigid_body", "hand_l"]]
    assert [args for a, args in msgs if a == "/BodyCal/Segment"] == [["tpose", "", "", 0.0, f32(0.1)]]
    assert [args for a, args in msgs if a == "/VMC/Ext/OK"] == [[1]] * 3
    for a, args in msgs:
        if a.startswith("/VMC/Ext/") and "/Pos" in a:
            assert isinstance(args[0], str) and all(type(v) is float and v == f32(v) for v in args[1:])


def test_local_only_sends_no_scaled_message_and_bundles_stay_under_1500_bytes():
    rec = tpose_recording(leds=True, seconds=0.1)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(2.0)
    with VmcSender("127.0.0.1", sock.getsockname()[1]) as sender:
        replay(RecordingMessages(rec, scaled=False), sender, speed=50.0)
        sizes, addresses = [], set()
        for _ in range(sender.datagrams):
            d = sock.recv(65535)
            sizes.append(len(d))
            addresses |= {m.message.address for m in OscPacket(d).messages}
    sock.close()
    assert max(sizes) <= 1500 and len(sizes) > rec.frame_count  # a frame of 13 devices and 8 markers: 2 bundles
    assert "/VMC/Ext/Tra/Pos/Local" in addresses and "/VMC/Ext/Tra/Pos" not in addresses


def record_replay(rec, **kw):
    receiver = VmcReceiver(port=0)
    recorder = LiveRecorder(rec.name)
    receiver.add_sink(recorder)
    with receiver, VmcSender("127.0.0.1", receiver.port) as sender:
        stats = replay(RecordingMessages(rec), sender, **kw)
        done = threading.Event()
        while recorder.frames < stats.frames and not done.wait(0.01):
            pass
    return recorder, stats


def test_a_replayed_take_recorded_again_equals_the_original(tmp_path):
    rec = tpose_recording(leds=True, seconds=1.0, roles=True)
    rec.devices[3].kind = "rigid_body"
    rec.valid[10:20, 2] = False  # a dropout
    rec.marker_valid[30:35, 1] = False
    rec.segments.append(Segment("touch", 0.6, 0.7, "chin", "index_tip_r"))
    path = tmp_path / "take.bcrec.json"
    save_recording(rec, path)
    original = load_recording(path, raw=True)
    recorder, _ = record_replay(original)  # in real time: the take keeps the sender's clock while it keeps to arrival
    recorder.save(tmp_path / "again.bcrec.json")
    again = load_recording(tmp_path / "again.bcrec.json", raw=True)
    assert [(d.name, d.kind, d.role) for d in again.devices] == [(d.name, d.kind, d.role) for d in original.devices]
    assert again.marker_names == original.marker_names
    assert again.valid.tolist() == original.valid.tolist()
    assert again.marker_valid.tolist() == original.marker_valid.tolist()
    np.testing.assert_allclose(again.time, original.time, rtol=F32, atol=1e-9)
    v, mv = original.valid, original.marker_valid
    np.testing.assert_allclose(again.positions[v], original.positions[v], rtol=F32, atol=2e-7)
    np.testing.assert_allclose(again.rotations[v], original.rotations[v], atol=3e-7)
    np.testing.assert_allclose(again.markers[mv], original.markers[mv], rtol=F32, atol=2e-7)
    # Each step is announced once its end was sent: in the order they end.
    assert [(s.label, s.start, s.end) for s in again.segments] == \
        sorted([(s.label, f32(s.start), f32(s.end)) for s in original.segments], key=lambda s: s[2])


def test_a_loop_goes_on_in_time_until_stopped():
    rec = tpose_recording(seconds=0.1, profile="minimal")
    stop = threading.Event()
    recorder, stats = record_replay(rec, loop=True, stop=stop,
                                    progress=lambda s: s.loops >= 2 and stop.set(), progress_every_s=0.0)
    assert stats.loops >= 2 and stop.is_set()
    t = recorder.recording().time
    n = rec.frame_count
    period = rec.time[-1] - rec.time[0] + 1 / 90
    np.testing.assert_allclose(t[n:2 * n], rec.time + period, atol=1e-6)
    assert np.all(np.diff(t) > 0)


def test_bad_replay_requests_are_one_clear_error():
    with VmcSender("127.0.0.1", 9) as sender:
        with pytest.raises(BodyCalError, match="not a positive number"):
            replay(RecordingMessages(known_take()), sender, speed=0.0)
    with pytest.raises(BodyCalError, match="cannot send to"):
        VmcSender("no such host.invalid", 39539)
