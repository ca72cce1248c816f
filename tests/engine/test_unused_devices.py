"""A device the calibration leaves without a role is said aloud (issue 40): one warning line for the
device, one for each body joint defaulted that its tracker may have measured; on stderr from
`calibrate-user`, in the model's calibration record (which the Calibration panel shows)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
from outside_takes import clip_performer, outside_recording
from recording_fixtures import tpose_recording
from repo_paths import REPO

from bodycal_addon.body.bodymodel import REQUIRED_USER_JOINTS
from bodycal_addon.calibration import calibrate_user
from bodycal_addon.calibration.unused_devices import measured_with
from bodycal_addon.recording.io import save_recording
from bodycal_addon.recording.model import Device, Recording

RUN = "import sys; sys.modules['bpy'] = None\nfrom bodycal_addon.app.cli import main\nsys.exit(main(sys.argv[1:]))"


def _hidden_in_the_tpose(role: str, **kw) -> tuple[Recording, str]:
    """The T-pose fixture with every role given but `role`'s, whose device the T-pose never saw (so
    it cannot be identified); returns the recording and that device's name."""
    rec = tpose_recording(roles=True, shuffle=True, **kw)
    k = rec.device_index(role)
    rec.devices[k].role = None
    seg = rec.segments_of("tpose")[0]
    rec.valid[rec.frames(seg.start - 0.1, seg.end + 0.1), k] = False
    return rec, rec.devices[k].name


def _unused_lines(model) -> list[str]:
    return [w for w in model.calibration["warnings"] if "without a role" in w or "has no role" in w]


def test_a_device_left_without_a_role_is_one_line_and_so_is_each_joint_it_may_have_measured():
    rec, name = _hidden_in_the_tpose("forearm_l", yaw=0.7, seed=3)
    lines = _unused_lines(calibrate_user(rec))
    assert lines[0].startswith(f"device {name} has no role and is not used (not tracked in the tpose segment)")
    assert lines[1:] == [f"{j} defaulted: no forearm_l tracker measured it, and device {name}, left without a role, "
                         "may be that tracker" for j in ("elbow_l", "wrist_l")]
    rec, name = _hidden_in_the_tpose("thigh_r", yaw=-2.0, seed=1)
    lines = _unused_lines(calibrate_user(rec))
    assert [ln.split(":")[0] for ln in lines[1:]] == ["hip_r defaulted", "knee_r defaulted"]


def test_every_role_given_or_found_is_no_line():
    rec = tpose_recording(roles=True, shuffle=True, yaw=0.7, seed=3)
    rec.devices[rec.device_index("shin_r")].role = None  # found from the T-pose
    model = calibrate_user(rec)
    assert not _unused_lines(model), model.calibration["warnings"]


def test_an_extra_tracker_where_every_role_is_held_defaults_nothing_more():
    """A third tracker on the left arm: not used, said so, but no joint is laid on it."""
    rec = tpose_recording(roles=True, shuffle=True, yaw=0.3, seed=2)
    k = rec.device_index("forearm_l")
    extra = Recording(rec.name, rec.time, rec.devices + [Device("LHR-EXTRA", "tracker", None)],
                      np.concatenate([rec.positions, rec.positions[:, k:k + 1] - [0, 0, 0.04]], axis=1),
                      np.concatenate([rec.rotations, rec.rotations[:, k:k + 1]], axis=1),
                      np.concatenate([rec.valid, rec.valid[:, k:k + 1]], axis=1), segments=rec.segments)
    assert _unused_lines(calibrate_user(extra)) == [
        "device LHR-EXTRA has no role and is not used (on the left arm): give it its role (the device's \"role\" in "
        "the recording, or Sidebar > BodyCal > Recording > Devices)"]


def test_calibrate_user_prints_the_lines_on_stderr(tmp_path):
    rec, name = _hidden_in_the_tpose("shin_l", yaw=1.1, seed=5)
    path = save_recording(rec, tmp_path / "hidden.bcrec.json")[0]
    out = subprocess.run([sys.executable, "-c", RUN, "calibrate-user", str(path), "-o", str(tmp_path / "u.body.json"),
                          "--allow-defaults"], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    err = out.stderr.splitlines()
    assert f"bodycal calibrate-user: warning: device {name} has no role and is not used (not tracked in the " \
           "tpose segment): give it its role" in out.stderr
    assert [ln.split("warning: ")[1].split(":")[0] for ln in err if "left without a role" in ln] == \
        ["knee_l defaulted", "ankle_l defaulted"]
    saved = json.loads((tmp_path / "u.body.json").read_text())
    assert sum("left without a role" in w for w in saved["calibration"]["warnings"]) == 2


def test_measured_with_names_roles_that_exist():
    from bodycal_addon.recording.model import ROLES
    for joint in REQUIRED_USER_JOINTS:
        assert measured_with(joint) and set(measured_with(joint)) <= set(ROLES), joint


@pytest.mark.parametrize("role", ["forearm_r", "shin_l"])
def test_on_real_motion_the_lines_name_the_joints_that_went_wrong(data_dir, tmp_path, role):
    """A CMU walk (evaluation/) with one limb tracker hidden through the T-pose and no role: its
    joints are defaulted 6-30 mm off: the warnings name that limb's two joints, every body joint over
    8 mm off among them."""
    perf = clip_performer(data_dir, "02_01_walk.bvh")

    def cut(cap):
        k = next(i for i, m in enumerate(cap.mounts) if m.role == role)
        cap.mounts[k].role = None
        seg = next(s for s in cap.session.segments if s["step"] == "tpose")
        fps = cap.session.fps
        cap.valid[max(0, int((seg["start"] - 0.3) * fps)):int((seg["end"] + 0.3) * fps), k] = False

    rec, cap = outside_recording(perf, tmp_path, "full", 0, "Y", cut=cut)
    user = calibrate_user(rec)
    truth = cap.truth()
    ref = int(round(user.reference_time * truth["fps"]))
    err = {n: 1000 * float(np.linalg.norm(user.joints[n].world - truth["positions"][ref, k]))
           for k, n in enumerate(truth["joints"]) if n in user.joints}
    off = {j for j in REQUIRED_USER_JOINTS if err.get(j, 0.0) > 8.0}
    named = {ln.split(" ")[0] for ln in _unused_lines(user) if "left without a role" in ln}
    limb = {f"{j}_{role[-1]}" for j in (("elbow", "wrist") if role.startswith("forearm") else ("knee", "ankle"))}
    assert off and off <= named == limb, (sorted(off), sorted(named), {j: round(err[j], 1) for j in off})
    assert named <= set(user.calibration["defaulted"])
