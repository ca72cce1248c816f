"""`bodycal record` and `bodycal stream` end to end, as processes (Blender blocked: neither needs it
with a body-model avatar): a streamed take recorded again, Ctrl-C ending a recording with its
file complete, one clear line for what cannot work, and the retargeted avatar's bones received by
python-osc's server."""

import json
import os
import signal
import socket
import subprocess
import sys
import threading

import numpy as np
import pytest
from osc_server import OscServer
from pythonosc.udp_client import SimpleUDPClient
from recording_fixtures import tpose_recording
from repo_paths import REPO

from bodycal_addon.output.vmc_bones import HUMANOID
from bodycal_addon.recording.io import load_recording, save_recording
from bodycal_dev import synthetic
from bodycal_dev.retarget_fixtures import procedural_avatar

RUN = "import sys; sys.modules['bpy'] = None\nfrom bodycal_addon.app.cli import main\nsys.exit(main(sys.argv[1:]))"


def command(*args):
    return [sys.executable, "-c", RUN, *map(str, args)]


def bodycal(*args, timeout=30):
    return subprocess.run(command(*args), cwd=REPO, capture_output=True, text=True, timeout=timeout)


def free_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


class Recording:
    """`bodycal record` running; `listening()` waits for its first line."""

    def __init__(self, *args):
        self.proc = subprocess.Popen(command("record", *args), cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True)
        self.first = []
        reader = threading.Thread(target=lambda: self.first.append(self.proc.stdout.readline()), daemon=True)
        reader.start()
        reader.join(10)

    def finish(self, sig=None, timeout=10):
        if sig is not None:
            self.proc.send_signal(sig)
        out, err = self.proc.communicate(timeout=timeout)
        return self.proc.returncode, self.first[0] + out, err


@pytest.fixture(scope="module")
def take(tmp_path_factory):
    path = tmp_path_factory.mktemp("take") / "take.bcrec.json"
    save_recording(tpose_recording(leds=True, seconds=1.0), path)
    return path


def test_a_streamed_take_recorded_for_a_duration_of_wall_clock_time(take, tmp_path):
    """`--duration` counts wall-clock time from the first frame's arrival, not the take's length: a
    take streamed at half speed for 0.5 s is cut there, holding a quarter second of the take."""
    port, out = free_port(), tmp_path / "again.bcrec.json"
    rec = Recording("--port", port, "--duration", "0.5", "-o", out)
    assert rec.first and rec.first[0].startswith(f"listening for VMC on 127.0.0.1:{port}")
    sent = bodycal("stream", take, "--port", port, "--speed", "0.5")
    assert sent.returncode == 0 and sent.stderr == ""
    assert sent.stdout.splitlines()[-1].startswith("sent 90 frames")
    code, stdout, stderr = rec.finish()
    assert code == 0 and stderr == "", stderr
    lines = stdout.splitlines()
    assert lines[-1] == f"saved {out}" and "--duration 0.5 s reached (wall clock from the first frame)" in stdout
    again, original = load_recording(out, raw=True), load_recording(take, raw=True)
    arrival = json.loads(out.read_text())["extra"]["live"]["arrival"]
    assert arrival[-1] <= 0.5 and again.frame_count < original.frame_count  # cut by the clock, not the stream
    assert again.time[-1] - again.time[0] < 0.4  # the take's own length: half the wall time (the sender's clock)
    np.testing.assert_allclose(again.time, original.time[:again.frame_count], rtol=2.0 ** -23, atol=1e-9)
    assert [d.name for d in again.devices] == [d.name for d in original.devices]


def test_a_stream_that_stops_ends_the_take_after_the_idle_time(take, tmp_path):
    """The sender closes: `record` ends the take `--idle` seconds after the last frame, whole, and
    says why, instead of waiting for Ctrl-C."""
    port, out = free_port(), tmp_path / "idle.bcrec.json"
    rec = Recording("--port", port, "--idle", "1", "-o", out)
    sent = bodycal("stream", take, "--port", port)
    assert sent.returncode == 0, sent.stderr
    code, stdout, stderr = rec.finish(timeout=30)  # no signal: it ends by itself
    assert code == 0 and stderr == "", stderr
    assert "no frame for 1 s (the sender stopped?): the take ends at its last frame" in stdout
    assert load_recording(out, raw=True).frame_count == 90


def test_ctrl_c_ends_a_recording_with_its_file_complete(tmp_path):
    port, out = free_port(), tmp_path / "take.csv"
    rec = Recording("--port", port, "-o", out, "--role", "T1=pelvis")
    client = SimpleUDPClient("127.0.0.1", port)
    for k in range(10):
        client.send_message("/VMC/Ext/Tra/Pos/Local", ["T1", 0.1 * k, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0])
        client.send_message("/VMC/Ext/Hmd/Pos/Local", ["H1", 0.0, 1.6, 0.0, 0.0, 0.0, 0.0, 1.0])
        client.send_message("/VMC/Ext/T", 0.01 * k)
    client.send_message("/VMC/Ext/Tra/Pos", ["SCALED", 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 1.0])
    client.send_message("/VMC/Ext/T", 0.1)
    threading.Event().wait(0.5)
    code, stdout, stderr = rec.finish(signal.SIGINT)
    assert code == 0, stderr
    assert stderr.strip() == ("bodycal record: warning: SCALED came only as /VMC/Ext/*/Pos, scaled to the sender's "
                              "avatar (its raw values are the /Local messages: enable them in the sender)")
    assert f"saved {out}" in stdout and f"saved {out.with_suffix('.json')}" in stdout
    back = load_recording(out, raw=True)
    assert back.frame_count == 11 and [(d.name, d.role) for d in back.devices] == [("T1", "pelvis"), ("H1", None),
                                                                                    ("SCALED", None)]
    np.testing.assert_allclose(back.positions[:10, 0, 0], 0.1 * np.arange(10), atol=1e-6)
    assert not [p for p in os.listdir(tmp_path) if p.startswith(".")]  # no temporary file left


def test_a_recording_with_nothing_arriving_is_one_line_and_no_file(tmp_path):
    out = tmp_path / "none.bcrec.json"
    rec = Recording("--port", free_port(), "-o", out)
    code, _, stderr = rec.finish(signal.SIGTERM)
    assert code == 2 and stderr.startswith("bodycal record: error: nothing received on port")
    assert len(stderr.splitlines()) == 1 and not out.exists()


def test_what_cannot_work_is_refused_before_listening(tmp_path, take):
    existing = tmp_path / "x.bcrec.json"
    existing.write_text("{}")
    r = bodycal("record", "-o", existing, "--port", free_port())
    assert r.returncode == 2 and "already exists" in r.stderr and len(r.stderr.splitlines()) == 1
    assert bodycal("record", "-o", tmp_path / "x.txt").returncode == 2
    r = bodycal("record", "-o", tmp_path / "y.bcrec.json", "--role", "A=tail")
    assert r.returncode == 2 and "unknown role 'tail'" in r.stderr
    busy = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    busy.bind(("127.0.0.1", 0))
    r = bodycal("record", "-o", tmp_path / "z.bcrec.json", "--port", busy.getsockname()[1])
    busy.close()
    assert r.returncode == 2 and "is in use" in r.stderr and not (tmp_path / "z.bcrec.json").exists()
    r = bodycal("stream", take, "--user", "u.body.json")
    assert r.returncode == 2 and "--user and --avatar are for --retarget" in r.stderr
    r = bodycal("stream", take, "--speed", "0")
    assert r.returncode == 2 and "not a positive speed" in r.stderr


def test_stream_retarget_sends_the_avatars_bones(tmp_path):
    perf = synthetic.make_performer(seed=0)
    rec, truth = synthetic.record_session(perf, motions=("clap",), calibration=["tpose"], noise_mm=0.0,
                                          wobble_mm=0.0)
    rec = rec.window(0, 30)
    save_recording(rec, tmp_path / "take.bcrec.json")
    truth.body_model().save(tmp_path / "user.body.json")
    procedural_avatar().save(tmp_path / "avatar.body.json")
    with OscServer() as srv:
        r = bodycal("stream", tmp_path / "take.bcrec.json", "--retarget", "--user", tmp_path / "user.body.json",
                    "--avatar", tmp_path / "avatar.body.json", "--port", srv.port, "--speed", "10", timeout=60)
        assert r.returncode == 0, r.stderr
        srv.wait_for("/VMC/Ext/T", 30)
    bones = [args[0] for a, args in srv.messages if a == "/VMC/Ext/Bone/Pos"]
    assert len(bones) == 30 * len(HUMANOID) and "LeftUpperArm" in bones
    assert "the avatar's bones" in r.stdout.splitlines()[-2]


def test_live_retargets_a_stream_and_sends_the_avatar(tmp_path):
    """`bodycal live`, solving here and with `--worker` (side by side, each with its own stream): a
    take streamed by `bodycal stream` (its devices' roles announced) is solved frame by frame and
    the avatar's bones arrive at python-osc's server; the summary line counts the frames solved."""
    perf = synthetic.make_performer(seed=0)
    rec, truth = synthetic.record_session(perf, motions=("clap",), calibration=["tpose"], noise_mm=0.0,
                                          wobble_mm=0.0)
    save_recording(rec.window(0, 120), tmp_path / "take.bcrec.json")
    truth.body_model().save(tmp_path / "user.body.json")
    procedural_avatar().save(tmp_path / "avatar.body.json")
    ways = ((), ("--worker",))
    listen = [free_port() for _ in ways]
    with OscServer() as here, OscServer() as there:
        servers = (here, there)
        lives = [subprocess.Popen(command("live", "--user", tmp_path / "user.body.json", "--avatar",
                                          tmp_path / "avatar.body.json", "--port", port, "--send",
                                          f"127.0.0.1:{srv.port}", "--duration", 14, *extra),
                                  cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                 for port, srv, extra in zip(listen, servers, ways, strict=True)]
        for live in lives:
            first = live.stdout.readline()
            assert "listening on" in first, first + live.stderr.read()
        # At a quarter of real time (44 ms a frame) a solve keeps up even on a loaded machine: the
        # test is that frames are solved and sent, not how fast (bench_live_solver measures that).
        streams = [subprocess.Popen(command("stream", tmp_path / "take.bcrec.json", "--port", port, "--speed", 0.25),
                                    cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                   for port in listen]
        for stream in streams:
            _out, err = stream.communicate(timeout=60)
            assert stream.returncode == 0, err
        outs = [live.communicate(timeout=30) for live in lives]
    for live, (out, err), srv, extra in zip(lives, outs, servers, ways, strict=True):
        assert live.returncode == 0, err
        solved = [a for a, _ in srv.messages if a == "/VMC/Ext/T"]
        bones = {args[0] for a, args in srv.messages if a == "/VMC/Ext/Bone/Pos"}
        assert len(solved) >= 30, out  # a loaded machine may drop some: the receiver says how many
        assert {"Hips", "LeftUpperArm", "RightHand"} <= bones
        last = out.splitlines()[-1]
        assert f"solved and sent {len(solved)} frames" in last and ("in the worker process" in last) == bool(extra)


def test_live_refuses_what_cannot_work_in_one_line(tmp_path):
    procedural_avatar().save(tmp_path / "avatar.body.json")
    r = bodycal("live", "--user", tmp_path / "avatar.body.json", "--avatar", tmp_path / "avatar.body.json",
                "--send", "127.0.0.1:40000")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "user body model" in r.stderr
    r = bodycal("live", "--user", tmp_path / "avatar.body.json", "--avatar", tmp_path / "avatar.body.json",
                "--send", "nowhere")
    assert r.returncode == 2 and "HOST:PORT" in r.stderr
