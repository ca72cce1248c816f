"""A VMC stream of a three-point kit (a headset and two controllers, nothing else) recorded by
`bodycal record` (FORMATS.md §6.2), as processes: a real A-Frame take sent by `bodycal stream`
(its roles announced), and a plain VMC sender's headset and controllers with `--role`. Neither is
refused; the file holds the three devices with their kinds and roles."""

from __future__ import annotations

import socket
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
from pythonosc.osc_bundle_builder import IMMEDIATELY, OscBundleBuilder
from pythonosc.osc_message_builder import OscMessageBuilder
from repo_paths import REPO

from bodycal_addon.recording.io import load_recording

RUN = "import sys; sys.modules['bpy'] = None\nfrom bodycal_addon.app.cli import main\nsys.exit(main(sys.argv[1:]))"


def command(*args):
    return [sys.executable, "-c", RUN, *map(str, args)]


def free_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


def start_recording(*args) -> tuple[subprocess.Popen, list]:
    proc = subprocess.Popen(command("record", *args), cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    first = []
    reader = threading.Thread(target=lambda: first.append(proc.stdout.readline()), daemon=True)
    reader.start()
    reader.join(10)
    assert first and first[0].startswith("listening for VMC"), first
    return proc, first


@pytest.mark.parametrize("hands", [None, "swapped"])
def test_a_real_three_point_take_streamed_is_recorded_with_its_roles(data_dir, tmp_path, hands):
    """`stream --hands swapped` announces the other controller as the right hand."""
    take = data_dir / "real_vr" / "aframe_vive" / "dev-recording.json"
    port, out = free_port(), tmp_path / "again.bcrec.json"
    proc, first = start_recording("--port", port, "--duration", "1.0", "-o", out)
    choice = ["--hands", hands] if hands else []
    # streamed in real time: --duration counts the recorder's wall clock
    sent = subprocess.run(command("stream", take, "--port", port, *choice), cwd=REPO,
                          capture_output=True, text=True, timeout=60)
    assert sent.returncode == 0 and sent.stderr == "", sent.stderr
    stdout, stderr = proc.communicate(timeout=20)
    assert proc.returncode == 0 and stderr == "", stderr
    assert (first[0] + stdout).splitlines()[-1] == f"saved {out}"
    again, original = load_recording(out), load_recording(take, raw=True)
    left, right = ("hand_r", "hand_l") if hands == "swapped" else ("hand_l", "hand_r")
    assert [(d.name, d.kind, d.role) for d in again.devices] == [
        ("camera", "hmd", "head"), ("left", "controller", left), ("right", "controller", right)]
    # 1.0 s of wall clock of a 9.3 s take: it stopped long before the end (about 87 frames; a sender
    # behind on a loaded machine catches up in a burst, so the count is not asserted to the frame)
    n = again.frame_count
    assert again.segments == [] and 20 <= n <= original.frame_count // 3, n
    np.testing.assert_allclose(again.time, original.time[:n], atol=1e-5)
    np.testing.assert_allclose(again.positions, original.positions[:n], atol=1e-6)


def _vmc_frame(k: int) -> bytes:
    """One frame as a plain VMC sender sends it: the headset's and two controllers' raw poses (Unity
    axes, x, y, z, qx, qy, qz, qw), then the sender's time."""
    bundle = OscBundleBuilder(IMMEDIATELY)
    for address, serial, x in (("/VMC/Ext/Hmd/Pos/Local", "HMD-1", 0.0), ("/VMC/Ext/Con/Pos/Local", "LHR-L", -0.3),
                               ("/VMC/Ext/Con/Pos/Local", "LHR-R", 0.3)):
        msg = OscMessageBuilder(address)
        msg.add_arg(serial)
        for v in (x, 1.6 if serial == "HMD-1" else 1.1, 0.2 + 0.001 * k, 0.0, 0.0, 0.0, 1.0):
            msg.add_arg(float(v), "f")
        bundle.add_content(msg.build())
    t = OscMessageBuilder("/VMC/Ext/T")
    t.add_arg(k / 90.0, "f")
    bundle.add_content(t.build())
    return bundle.build().dgram


def test_a_plain_vmc_headset_and_controllers_are_recorded_with_the_roles_given(tmp_path):
    port, out = free_port(), tmp_path / "kit.bcrec.json"
    proc, _ = start_recording("--port", port, "--duration", "0.5", "--role", "HMD-1=head", "--role", "LHR-L=hand_l",
                              "--role", "LHR-R=hand_r", "-o", out)
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        for k in range(90):
            sock.sendto(_vmc_frame(k), ("127.0.0.1", port))
            time.sleep(1 / 180)
    finally:
        sock.close()
    stdout, stderr = proc.communicate(timeout=20)
    assert proc.returncode == 0 and stderr == "", stderr
    rec = load_recording(out)
    assert [(d.name, d.kind, d.role) for d in rec.devices] == [
        ("HMD-1", "hmd", "head"), ("LHR-L", "controller", "hand_l"), ("LHR-R", "controller", "hand_r")]
    assert rec.valid.all() and rec.time[-1] - rec.time[0] >= 0.49
    # Unity's x is BodyCal's x: the left controller on the left
    assert np.all(rec.pose("hand_l")[0][:, 0] < rec.pose("hand_r")[0][:, 0])
    assert not any("no role" in n for n in rec.notes)
