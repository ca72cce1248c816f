"""VMC against an OSC implementation no one here wrote (osc4py3, test-only: docs/LIVE.md "Checked
against other tools"), beside python-osc, which the extension ships: osc4py3 sends six devices'
`/VMC/Ext/*/Pos` and `/Pos/Local` in time-tagged bundles (a nested one per frame) to `bodycal
record`, whose file, read back through the project's reader, holds every frame's poses as sent;
osc4py3's server parses what `bodycal stream --retarget` sends: every bone a Unity HumanBodyBone;
and a sender that sends nothing (osc4py3's `as_comthreads` backend, as vmcp's of the same name)
is said as "nothing received", never a silent wait.

The poses are real motion (a CMU walk's six-device session, `evaluation/`), and the conversion to
Unity's axes is written here from the VMC convention (Y up, left-handed, the device's local z
mirrored: FORMATS.md §6.1), not taken from the project's writer."""

import signal
import socket
import subprocess
import time

import numpy as np
import pytest
from outside_takes import clip_performer, outside_recording
from repo_paths import REPO
from test_live_cli import Recording, command, free_port

from bodycal_addon.recording.io import load_recording, save_recording
from bodycal_addon.recording.live.source import SourceStats
from bodycal_dev import synthetic
from bodycal_dev.retarget_fixtures import procedural_avatar

osc4py3 = pytest.importorskip("osc4py3")  # requirements-dev.txt: a fresh clone's `make test` installs it
from osc4py3 import oscbuildparse as obp  # noqa: E402
from osc4py3.oscmethod import OSCARG_ADDRESS, OSCARG_DATA  # noqa: E402

# Unity's HumanBodyBones (UnityEngine.HumanBodyBones, every member but LastBone), written out here.
UNITY_HUMAN_BODY_BONES = {
    "Hips", "LeftUpperLeg", "RightUpperLeg", "LeftLowerLeg", "RightLowerLeg", "LeftFoot", "RightFoot", "Spine",
    "Chest", "UpperChest", "Neck", "Head", "LeftShoulder", "RightShoulder", "LeftUpperArm", "RightUpperArm",
    "LeftLowerArm", "RightLowerArm", "LeftHand", "RightHand", "LeftToes", "RightToes", "LeftEye", "RightEye", "Jaw",
    *(f"{side}{finger}{part}" for side in ("Left", "Right") for finger in ("Thumb", "Index", "Middle", "Ring", "Little")
      for part in ("Proximal", "Intermediate", "Distal")),
}
SWAP_YZ = np.array([[1.0, 0, 0], [0, 0, 1], [0, 1, 0]])  # Blender's Z up, right-handed <-> Unity's Y up, left
MIRROR_Z = np.diag([1.0, 1.0, -1.0])  # a left-handed device frame: its local z mirrored
TAG = {"hmd": "Hmd", "controller": "Con", "tracker": "Tra"}


def _quat_matrix(q):
    w, x, y, z = q
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def _matrix_quat(m):
    """(w, x, y, z) of a rotation matrix (the largest of the four terms first: no cancellation)."""
    t = np.trace(m)
    k = int(np.argmax([t, m[0, 0], m[1, 1], m[2, 2]]))
    if k == 0:
        s = 2.0 * np.sqrt(1.0 + t)
        return np.array([s / 4, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s])
    i, j, n = [(0, 1, 2), (1, 2, 0), (2, 0, 1)][k - 1]
    s = 2.0 * np.sqrt(1.0 + m[i, i] - m[j, j] - m[n, n])
    q = np.empty(4)
    q[0] = (m[n, j] - m[j, n]) / s
    q[1 + i], q[1 + j], q[1 + n] = s / 4, (m[j, i] + m[i, j]) / s, (m[n, i] + m[i, n]) / s
    return q


def unity_pose(position, rotation):
    """A device's internal pose (Z up, right-handed; w x y z) as VMC sends it: position and
    quaternion (x, y, z, w) in Unity's axes, float32 on the wire."""
    r = SWAP_YZ @ _quat_matrix(rotation) @ MIRROR_Z
    q = _matrix_quat(r)
    p = SWAP_YZ @ position
    return [float(np.float32(v)) for v in (*p, q[1], q[2], q[3], q[0])]


@pytest.fixture(scope="module")
def six_devices(data_dir, tmp_path_factory):
    """180 frames of a real walk's six-device session (the calibration's T-pose onwards)."""
    rec, _cap = outside_recording(clip_performer(data_dir, "02_01_walk.bvh"), tmp_path_factory.mktemp("six"), "six", 3)
    assert len(rec.devices) == 6 and rec.valid[:180].all()
    return rec.window(0, 180)


class Osc4py3:
    """osc4py3's event-loop backend (one per process: start, use, terminate)."""

    def __init__(self, backend: str = "as_eventloop"):
        self.api = __import__(f"osc4py3.{backend}", fromlist=["osc_startup"])

    def __enter__(self):
        self.api.osc_startup()
        return self.api

    def __exit__(self, *exc):
        self.api.osc_terminate()


def test_osc4py3_sends_six_devices_in_time_tagged_bundles_and_record_keeps_every_frame(six_devices, tmp_path):
    rec = six_devices
    port, out = free_port(), tmp_path / "six.bcrec.json"
    recording = Recording("--port", port, "-o", out)
    assert recording.first and "listening for VMC" in recording.first[0]
    with Osc4py3() as osc:
        osc.osc_udp_client("127.0.0.1", port, "bodycal")
        start = time.perf_counter()
        for k in range(rec.frame_count):
            devices = []
            for d, device in enumerate(rec.devices):
                args = [device.name, *unity_pose(rec.positions[k, d], rec.rotations[k, d])]
                base = f"/VMC/Ext/{TAG[device.kind]}/Pos"
                devices += [obp.OSCMessage(base, ",sfffffff", args), obp.OSCMessage(base + "/Local", ",sfffffff", args)]
            tag = obp.unixtime2timetag(time.time())
            frame = obp.OSCBundle(tag, [obp.OSCBundle(tag, devices),  # nested, as a sender splitting a frame
                                        obp.OSCMessage("/VMC/Ext/T", ",f", [float(rec.time[k] - rec.time[0])])])
            osc.osc_send(frame, "bodycal")
            osc.osc_process()
            time.sleep(max(0.0, start + (k + 1) / rec.fps - time.perf_counter()))  # real time
        for _ in range(20):
            osc.osc_process()
            time.sleep(0.01)
    code, stdout, stderr = recording.finish(signal.SIGINT)
    assert code == 0 and stderr == "", stderr
    assert f"recorded {rec.frame_count} frames" in stdout.splitlines()[-2]  # every frame, counted and said
    back = load_recording(out, raw=True)
    assert back.frame_count == rec.frame_count and [d.name for d in back.devices] == [d.name for d in rec.devices]
    assert [d.kind for d in back.devices] == [d.kind for d in rec.devices] and back.valid.all()
    sent = np.array([[unity_pose(rec.positions[k, d], rec.rotations[k, d])[:3] for d in range(6)]
                     for k in range(rec.frame_count)])
    np.testing.assert_allclose(back.positions, sent @ SWAP_YZ.T, rtol=0, atol=1e-7)  # the float32 sent, as sent
    np.testing.assert_allclose(back.positions, rec.positions, rtol=0, atol=2e-7)  # float32 of the truth
    dots = np.abs(np.einsum("fdi,fdi->fd", back.rotations, rec.rotations))
    assert dots.min() > 1.0 - 1e-6
    np.testing.assert_allclose(back.time, rec.time - rec.time[0], atol=1e-6)  # the sender's clock, in real time


def test_osc4py3_parses_what_stream_retarget_sends_every_bone_a_unity_human_body_bone(tmp_path):
    perf = synthetic.make_performer(seed=2)
    rec, truth = synthetic.record_session(perf, motions=("clap",), calibration=["tpose"], noise_mm=0.0,
                                          wobble_mm=0.0)
    rec = rec.window(0, 40)
    save_recording(rec, tmp_path / "take.bcrec.json")
    truth.body_model().save(tmp_path / "user.body.json")
    procedural_avatar().save(tmp_path / "avatar.body.json")
    port, got = free_port(), []
    with Osc4py3() as osc:
        osc.osc_udp_server("127.0.0.1", port, "receiver")
        osc.osc_method("*", lambda address, args: got.append((address, args)), argscheme=OSCARG_ADDRESS + OSCARG_DATA)
        sender = subprocess.Popen(command("stream", tmp_path / "take.bcrec.json", "--retarget", "--user",
                                          tmp_path / "user.body.json", "--avatar", tmp_path / "avatar.body.json",
                                          "--port", port),  # real time: osc4py3 reads a datagram per turn
                                  cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 120.0  # the offline retarget first, then 0.4 s of stream
        while sender.poll() is None:
            assert time.monotonic() < deadline
            osc.osc_process()
            time.sleep(0.0005)
        for _ in range(200):  # what is still in the socket
            osc.osc_process()
            time.sleep(0.001)
        out, err = sender.communicate(timeout=10)
    assert sender.returncode == 0, err
    assert {a for a, _ in got} == {"/VMC/Ext/Root/Pos", "/VMC/Ext/Bone/Pos", "/VMC/Ext/OK", "/VMC/Ext/T"}
    frames, bones = [], None
    for address, args in got:
        if address == "/VMC/Ext/Bone/Pos":
            name, values = args[0], np.array(args[1:], float)
            assert name in UNITY_HUMAN_BODY_BONES, name
            assert values.shape == (7,) and np.isfinite(values).all() and abs(np.linalg.norm(values[3:]) - 1) < 1e-5
            bones = (bones or []) + [name]
        elif address == "/VMC/Ext/T":
            frames.append(bones)
            bones = None
    assert len(frames) == rec.frame_count  # every frame, each with its bones
    assert all(set(f) == set(frames[0]) and len(f) == len(set(f)) for f in frames)
    assert {"Hips", "Spine", "Head", "LeftUpperArm", "RightLowerLeg", "LeftFoot"} <= set(frames[0])
    assert f"sent {rec.frame_count} frames" in out.splitlines()[-1]


def test_a_sender_that_sends_nothing_is_said_as_nothing_received(tmp_path):
    """osc4py3's `as_comthreads` backend queues what it is given and sends none of it (vmcp's
    backend of that name behaves the same): `bodycal record` says "nothing received" while it
    listens and when it ends, rather than waiting in silence or writing an empty take."""
    port, out = free_port(), tmp_path / "none.bcrec.json"
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # what the sender really sends, seen here too
    probe.bind(("127.0.0.1", 0))
    probe.settimeout(0.2)
    recording = Recording("--port", port, "-o", out)
    with Osc4py3("as_comthreads") as osc:
        for name, where in (("bodycal", port), ("probe", probe.getsockname()[1])):
            osc.osc_udp_client("127.0.0.1", where, name)
        for k in range(60):  # 2.6 s: the progress line (every 2 s) is printed
            message = obp.OSCMessage("/VMC/Ext/Hmd/Pos/Local", ",sfffffff", ["HMD", 0.0, 1.6, 0.0, 0.0, 0.0, 0.0, 1.0])
            for name in ("bodycal", "probe"):
                osc.osc_send(obp.OSCBundle(obp.OSC_IMMEDIATELY, [message, obp.OSCMessage("/VMC/Ext/T", ",f",
                                                                                          [k / 90.0])]), name)
            osc.osc_process()
            time.sleep(0.045)
    with pytest.raises(TimeoutError):
        probe.recv(2048)  # the backend sent nothing indeed
    probe.close()
    code, stdout, stderr = recording.finish(signal.SIGINT)
    assert code == 2 and not out.exists()
    assert f"nothing received on port {port} yet" in stdout
    assert stderr.strip() == (f"bodycal record: error: nothing received on port {port}: 0 packets (is the sender "
                              "sending to this host and port?)"), stderr


def test_the_sources_line_says_nothing_received_until_a_packet_comes():
    """What the Live panel and the commands print of a source: "nothing received" until a packet
    comes, then packets without a device, then frames."""
    stats = SourceStats()
    assert stats.line() == "nothing received yet (0 packets)"
    stats.datagrams = 3
    assert stats.line() == "3 packets received, no device in them yet"
    stats.frames = 2
    assert stats.line() == "2 frames"
