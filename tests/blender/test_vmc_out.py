"""`bodycal stream --retarget` with an avatar file (Blender opens it and measures its body, as for
`retarget`): python-osc's server receives the avatar's bones every frame, the same as from the
avatar's body model written by `calibrate-avatar`."""

import subprocess
import sys

import bpy
import numpy as np
from osc_server import OscServer
from repo_paths import REPO

from bodycal_addon.core import paths
from bodycal_addon.output.vmc_bones import HUMANOID
from bodycal_addon.recording.io import save_recording
from bodycal_dev import synthetic

rigs = paths.sample_rigs()


def _stream(tmp_path, avatar):
    with OscServer() as srv:
        out = subprocess.run([sys.executable, "-m", "bodycal_addon", "stream", str(tmp_path / "take.bcrec.json"),
                              "--retarget", "--user", str(tmp_path / "user.body.json"), "--avatar", str(avatar),
                              "--port", str(srv.port), "--speed", "10"], cwd=REPO, capture_output=True, text=True,
                             timeout=300)
        assert out.returncode == 0, out.stderr
        srv.wait_for("/VMC/Ext/T", 20)
    return [(args[0], args[1:]) for a, args in srv.messages if a == "/VMC/Ext/Bone/Pos"], out


def test_stream_retarget_from_an_avatar_file_and_from_its_body_model(tmp_path):
    perf = synthetic.make_performer(seed=2)
    rec, truth = synthetic.record_session(perf, motions=("clap",), calibration=["tpose"], noise_mm=0.0,
                                          wobble_mm=0.0)
    save_recording(rec.window(0, 20), tmp_path / "take.bcrec.json")
    truth.body_model().save(tmp_path / "user.body.json")
    rigs.build_procedural_avatar()
    bpy.ops.wm.save_as_mainfile(filepath=str(tmp_path / "procedural.blend"))
    from_blend, out = _stream(tmp_path, tmp_path / "procedural.blend")
    assert len(from_blend) == 20 * len(HUMANOID) and out.stderr == ""
    calibrated = subprocess.run([sys.executable, "-m", "bodycal_addon", "calibrate-avatar",
                                 str(tmp_path / "procedural.blend"), "-o", str(tmp_path / "avatar.body.json")],
                                cwd=REPO, capture_output=True, text=True, timeout=300)
    assert calibrated.returncode == 0, calibrated.stderr
    from_model, _ = _stream(tmp_path, tmp_path / "avatar.body.json")
    assert [n for n, _ in from_model] == [n for n, _ in from_blend]
    np.testing.assert_allclose([v for _, v in from_model], [v for _, v in from_blend], atol=1e-5)
