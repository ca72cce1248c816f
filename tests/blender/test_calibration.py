"""User body calibration (bodycal_addon.calibration): each step on small hand-built recordings whose
answer is known exactly, then whole synthetic sessions against the performer's ground truth."""

import re

import numpy as np
import pytest

from bodycal_addon.calibration import calibrate_user
from bodycal_addon.calibration import limbs as L
from bodycal_addon.calibration import touches as T
from bodycal_addon.calibration.common import Session, State
from bodycal_addon.core import transforms as tf
from bodycal_addon.core.errors import BodyCalError
from bodycal_addon.recording.model import Device, Recording, Segment

FPS = 90.0
rng = np.random.default_rng(11)


def _random_quat():
    return tf.quat_normalize(rng.normal(size=4))


class Builder:
    """Devices and markers over time, filled piecewise; poses are (F, 3) + (F, 4)."""

    def __init__(self, seconds):
        self.time = np.arange(int(seconds * FPS)) / FPS
        self.devices, self.pos, self.rot = [], [], []
        self.markers, self.mpos = [], []
        self.segments = []

    def device(self, role, kind="tracker", pos=(0, 0, 1), rot=(1, 0, 0, 0)):
        n = len(self.time)
        self.devices.append(Device(role, kind, role))
        self.pos.append(np.tile(np.asarray(pos, float), (n, 1)))
        self.rot.append(np.tile(np.asarray(rot, float), (n, 1)))
        return len(self.devices) - 1

    def marker(self, name, pos=(0, 0, 0)):
        self.markers.append(name)
        self.mpos.append(np.tile(np.asarray(pos, float), (len(self.time), 1)))
        return len(self.markers) - 1

    def span(self, t0, t1):
        return (self.time >= t0) & (self.time <= t1)

    def build(self):
        n = len(self.time)
        return Recording("hand-built", self.time, self.devices, np.stack(self.pos, 1), np.stack(self.rot, 1),
                         np.ones((n, len(self.devices)), bool), self.markers,
                         np.stack(self.mpos, 1) if self.markers else None,
                         np.ones((n, len(self.markers)), bool) if self.markers else None, self.segments)


def _elbow_session(noise=0.0, flex_deg=120.0, touches=True):
    """Upper arm hanging still, forearm flexing about the elbow axis -X (performer's right), so that
    flexion brings the hand forward (-Y); returns (recording, truth)."""
    b = Builder(8.0)
    elbow = np.array([0.2, 0.0, 1.05])
    axis = np.array([-1.0, 0.0, 0.0])
    q_up = _random_quat()
    ua = b.device("upperarm_l", pos=elbow + [0.04, 0.01, 0.14], rot=q_up)
    fa = b.device("forearm_l")
    b.device("head", "hmd", pos=(0, 0, 1.6))
    tracker_in_bone = np.array([0.035, 0.15, 0.02])  # forearm tracker in the forearm bone frame
    q_mount = _random_quat()
    flex = np.zeros(len(b.time))
    m = b.span(0.5, 5.5)
    flex[m] = np.radians(flex_deg) * 0.5 * (1 - np.cos(2 * np.pi * 2 * (b.time[m] - 0.5) / 5.0))
    q_bone0 = tf.matrix_to_quat(tf.frame_from_axes(np.array([0, 0, -1.0]), axis))
    q_bone = tf.quat_mul(tf.axis_angle_to_quat(axis, flex), q_bone0)
    b.pos[fa] = elbow + tf.rotate(q_bone, tracker_in_bone)
    b.rot[fa] = tf.quat_mul(q_bone, q_mount)
    b.pos[ua] = b.pos[ua] + rng.normal(0, noise, b.pos[ua].shape)
    b.pos[fa] = b.pos[fa] + rng.normal(0, noise, b.pos[fa].shape)
    b.segments.append(Segment("flex_elbow_l", 0.5, 5.5))
    if touches:
        tip = b.marker("index_tip_r", (0.5, 0.3, 1.0))
        for name, off, (t0, t1) in (("elbow_in_l", -0.03, (6.0, 6.8)), ("elbow_out_l", 0.03, (7.0, 7.8))):
            s = b.span(t0, t1)
            b.mpos[tip][s] = elbow + off * axis  # forearm still (flex = 0) here
            b.segments.append(Segment("touch", t0, t1, name, "index_tip_r"))
    rec = b.build()
    truth = {"elbow_local": tf.inverse_transform_points(b.pos[fa][0], b.rot[fa][0], elbow),
             "right_local": tf.rotate(tf.quat_conj(b.rot[fa][0]), axis), "elbow": elbow}
    return rec, truth


def test_hinge_axis_sign_position_and_radius_exact():
    rec, truth = _elbow_session()
    session, state = Session(rec), State()
    L.limbs(session, state)
    np.testing.assert_allclose(state.local["elbow_l"]["forearm_l"], truth["elbow_local"], atol=1e-6)
    role, right = state.hinge_right["forearm_l"]
    assert role == "forearm_l"
    np.testing.assert_allclose(right, truth["right_local"], atol=1e-6)  # the sign, too
    assert abs(state.radii["elbow_l"] - 0.03) < 1e-6
    q = session.quality["flex_elbow_l"]
    assert q["rms_mm"] < 1e-3 and 115 < q["range_deg"] < 125 and q["kept"] <= q["of"]
    # the same joint carried into the upper arm's frame
    up_pos, up_rot, _ = rec.pose("upperarm_l")
    np.testing.assert_allclose(state.local["elbow_l"]["upperarm_l"],
                               tf.inverse_transform_points(up_pos[0], up_rot[0], truth["elbow"]), atol=1e-6)


def test_hinge_sign_holds_with_noise_and_small_range():
    rec, truth = _elbow_session(noise=0.001, flex_deg=70)
    session, state = Session(rec), State()
    L.limbs(session, state)
    _, right = state.hinge_right["forearm_l"]
    assert right @ truth["right_local"] > 0.99
    assert np.linalg.norm(state.local["elbow_l"]["forearm_l"] - truth["elbow_local"]) < 0.004


def test_hinge_too_little_motion_is_reported_and_left_out():
    """A step that cannot be used is reported and defaulted, never fatal."""
    rec, _ = _elbow_session(flex_deg=15, touches=False)
    session, state = Session(rec), State()
    L.limbs(session, state)
    assert "flex_elbow_l" in session.missing and "elbow_l" not in state.local
    (line,) = [w for w in session.warnings if w.startswith("flex_elbow_l")]
    assert re.search(r"flex_elbow_l not used: only \d+ degrees of motion recorded, at least 40 needed \(flex", line)


def test_hinge_without_its_upper_arm_tracker_uses_a_trunk_tracker():
    """No upper arm tracker (six devices, or a dead one): the upper arm is held still against the
    trunk while the elbow flexes, so a trunk tracker (here the HMD) circles the hinge in the
    forearm's frame just as the upper arm tracker would."""
    rec, truth = _elbow_session(touches=False)
    rec.devices[0].role = None  # the upper arm tracker is unknown
    rec.devices[0].name = "LHR-1"
    session, state = Session(rec), State()
    L.limbs(session, state)
    q = session.quality["flex_elbow_l"]
    assert q["frames"] == "head in forearm_l"
    _, right = state.hinge_right["forearm_l"]
    np.testing.assert_allclose(right, truth["right_local"], atol=1e-6)
    # on the axis, at the circle plane of the HMD (no shoulder, no touches): only the place along
    # the axis is defaulted
    local = state.local["elbow_l"]["forearm_l"]
    off = local - truth["elbow_local"]
    assert np.linalg.norm(off - (off @ right) * right) < 1e-6
    assert "elbow_l along the hinge axis" in session.defaulted


def test_hinge_without_any_usable_tracker_is_reported_and_left_out():
    rec, _ = _elbow_session(touches=False)
    for d in rec.devices:
        if d.role in ("upperarm_l", "head"):
            d.role = None  # no upper arm tracker and no trunk tracker either
    session, state = Session(rec), State()
    L.limbs(session, state)
    assert "flex_elbow_l" in session.missing and "elbow_l" not in state.local
    assert any(w.startswith("flex_elbow_l not used") for w in session.warnings), session.warnings


def _shoulder_session(noise=0.0, outliers=0.0, swing_deg=50.0):
    b = Builder(6.0)
    shoulder = np.array([0.18, 0.0, 1.42])
    chest_q = _random_quat()
    b.device("chest", pos=shoulder + [-0.18, 0.1, -0.05], rot=chest_q)
    b.device("head", "hmd", pos=(0, 0, 1.6))
    ua = b.device("upperarm_l")
    t = b.time
    a = np.radians(swing_deg) * np.sin(2 * np.pi * 0.7 * t)
    c = np.radians(swing_deg) * np.sin(2 * np.pi * 0.45 * t + 1.0)
    q = tf.quat_mul(tf.axis_angle_to_quat(np.array([1.0, 0, 0]), a), tf.axis_angle_to_quat(np.array([0, 1.0, 0]), c))
    mount = np.array([0.04, 0.02, -0.12])
    b.pos[ua] = shoulder + tf.rotate(q, mount)
    b.rot[ua] = q
    for i in (0, ua):
        b.pos[i] = b.pos[i] + rng.normal(0, noise, b.pos[i].shape)
    if outliers:
        bad = rng.random(len(t)) < outliers
        b.pos[ua][bad] += rng.normal(0, 0.05, (bad.sum(), 3))
    b.segments.append(Segment("swing_shoulder_l", 0.0, 6.0))
    return b.build(), {"local": mount * 0 + tf.inverse_transform_points(b.pos[ua][0] * 0 + shoulder + tf.rotate(
        q[0], mount), q[0], shoulder), "shoulder": shoulder}


def test_anchor_sphere_fit_exact_and_carried_to_the_chest():
    rec, truth = _shoulder_session()
    session, state = Session(rec), State()
    L.limbs(session, state)
    np.testing.assert_allclose(state.local["shoulder_l"]["upperarm_l"], truth["local"], atol=1e-6)
    cp, cq, _ = rec.pose("chest")
    np.testing.assert_allclose(state.local["shoulder_l"]["chest"],
                               tf.inverse_transform_points(cp[0], cq[0], truth["shoulder"]), atol=1e-6)


def test_anchor_outlier_frames_are_dropped():
    rec, truth = _shoulder_session(noise=0.001, outliers=0.1)
    robust, plain = State(), State()
    L.limbs(Session(rec), robust)
    L.limbs(Session(rec, robust=False, despike=False), plain)
    err_r = np.linalg.norm(robust.local["shoulder_l"]["upperarm_l"] - truth["local"])
    err_p = np.linalg.norm(plain.local["shoulder_l"]["upperarm_l"] - truth["local"])
    assert err_r < 0.004
    assert err_r < err_p


def _touch_session(moving=False):
    b = Builder(2.0)
    hand_q = _random_quat()
    b.device("hand_l", "controller", pos=(0.4, 0.0, 1.0), rot=hand_q)
    b.device("head", "hmd", pos=(0, 0, 1.6))
    tip = b.marker("index_tip_r", (0.0, -0.2, 1.0))
    point = np.array([0.42, 0.01, 1.03])
    s = b.span(0.5, 1.5)
    b.mpos[tip][s] = point
    if moving:
        b.mpos[tip][s] = point + np.outer(b.time[s] - 1.0, [0.15, 0.0, 0.0])  # slides at 15 cm/s
    b.mpos[tip] += rng.normal(0, 0.001, b.mpos[tip].shape)
    b.segments.append(Segment("touch", 0.4, 1.6, "wrist_top_l", None))
    return b.build(), tf.inverse_transform_points(np.array([0.4, 0.0, 1.0]), hand_q, point)


def test_touch_position_in_the_touched_frame():
    rec, local = _touch_session()
    session = Session(rec)
    t = T.extract(session, State(), rec.segments[0])
    assert t.by == "index_tip_r" and t.role == "hand_l"
    assert np.linalg.norm(t.local - local) < 0.001


def test_a_touch_that_never_stops_moving_is_actionable():
    rec, _ = _touch_session(moving=True)
    with pytest.raises(BodyCalError, match=r"touch wrist_top_l by index_tip_r .*never stopped moving.*hold"):
        T.extract(Session(rec), State(), rec.segments[0])
    # ... and collecting the touches drops it with that warning instead of aborting
    session = Session(rec)
    assert T.collect(session, State()) == {}
    assert re.search(r"touch wrist_top_l by index_tip_r .* not used: the touch never stopped moving .*hold",
                     session.warnings[0])


@pytest.mark.slow
def test_a_borderline_touch_never_aborts_and_json_and_csv_agree(tmp_path):
    """The project's own compact clap session (22 fps, half pace) was rejected on one touch, and its
    CSV failed where the JSON passed. Every format now gives the same model."""
    from bodycal_addon.recording.io import load_recording, save_recording
    from bodycal_dev import synthetic

    rec, _ = synthetic.record_session(synthetic.make_performer(seed=0), motions=("clap",), fps=22, pace=0.5)
    models = [calibrate_user(rec)] + [calibrate_user(load_recording(save_recording(rec, tmp_path / name)[0]))
                                      for name in ("clap.bcrec.json", "clap.csv")]
    for m in models:
        assert not m.calibration["warnings"], m.calibration["warnings"]
    json_model, csv_model = models[1].to_dict(), models[2].to_dict()
    for j in json_model["joints"]:  # the two files read back the same numbers: the same model
        np.testing.assert_allclose(csv_model["joints"][j]["world"], json_model["joints"][j]["world"], atol=1e-12)
    for j in ("wrist_l", "elbow_r", "mcp_index_l", "skull_base"):
        # the files round positions to 0.1 µm: a robust mean may keep a frame more or less
        assert np.linalg.norm(models[1].world(j) - models[0].world(j)) < 1e-3, j


def test_touch_point_without_its_tracker():
    rec, _ = _touch_session()
    rec.segments[0] = Segment("touch", 0.4, 1.6, "ankle_in_l", None)
    with pytest.raises(BodyCalError, match="foot_l"):
        T.extract(Session(rec), State(), rec.segments[0])


def test_hand_built_session_yields_a_complete_model_with_defaults_reported():
    rec, truth = _still_session()
    model = calibrate_user(rec)
    from bodycal_addon.body.bodymodel import REQUIRED_USER_JOINTS, BodyModel

    assert set(REQUIRED_USER_JOINTS) <= set(model.joints)
    assert np.linalg.norm(model.joints["elbow_l"].world - truth["elbow"]) < 1e-6
    assert "flex_elbow_l" in model.calibration["steps_used"]
    assert "wrist_l" in model.calibration["defaulted"]
    assert "swing_hip_r" in model.calibration["missing"]
    back = BodyModel.from_dict(model.to_dict())
    np.testing.assert_allclose(back.joints["elbow_l"].world, model.joints["elbow_l"].world, atol=1e-6)
    assert back.bones["forearm_l"].extra["right_frame"] == "forearm_l"


def _still_session(six=False):
    """The elbow session with a still stand first; `six`: `_with_the_six`."""
    rec, truth = _elbow_session()
    rec.segments.insert(0, Segment("stand", 0.0, 0.45))  # still, before the flexion (segments never overlap)
    return (_with_the_six(rec) if six else rec), truth


def _with_the_six(rec):
    """`rec` with the devices every method animates from (pelvis, hands and feet standing still
    beside the HMD), which calibrate-user requires (calibration/coverage.py)."""
    n = rec.frame_count
    places = {"pelvis": (0.0, 0.0, 1.0), "hand_l": (0.3, -0.2, 1.0), "hand_r": (-0.3, -0.2, 1.0),
              "foot_l": (0.1, -0.05, 0.08), "foot_r": (-0.1, -0.05, 0.08)}
    devices = [*rec.devices, *(Device(r, "tracker", r) for r in places)]
    pos = np.concatenate([rec.positions, np.tile(np.array(list(places.values())), (n, 1, 1))], axis=1)
    rot = np.concatenate([rec.rotations, np.tile([1.0, 0, 0, 0], (n, len(places), 1))], axis=1)
    if "forearm_l" in [d.role for d in rec.devices]:  # the left hand rides with the forearm (no wrist motion)
        k, h = rec.device_index("forearm_l"), len(rec.devices) + 1
        pos[:, h] = rec.positions[:, k] + tf.rotate(rec.rotations[:, k], np.array([0.0, 0.0, -0.2]))
        rot[:, h] = rec.rotations[:, k]
    return Recording(rec.name, rec.time, devices, pos, rot, np.ones((n, len(devices)), bool), rec.marker_names,
                     rec.markers, rec.marker_valid, rec.segments, rec.source)


def test_cli_calibrate_user_writes_the_body_model(tmp_path, capsys):
    from bodycal_addon.app import cli
    from bodycal_addon.body.bodymodel import BodyModel
    from bodycal_addon.recording.io import save_recording

    rec, truth = _still_session(six=True)
    path = save_recording(rec, tmp_path / "elbow.bcrec.json")[0]
    out = tmp_path / "user.body.json"
    # one joint measured: a body mostly guessed, written only when the defaults are accepted
    assert cli.main(["calibrate-user", str(path), "-o", str(out), "--allow-defaults"]) == 0
    model = BodyModel.load(out)
    assert model.kind == "user"
    assert np.linalg.norm(model.world("elbow_l") - truth["elbow"]) < 1e-4
    assert "flex_elbow_l" in capsys.readouterr().out


def test_cli_unusable_step_is_reported_and_the_model_written(tmp_path, capsys):
    from bodycal_addon.app import cli
    from bodycal_addon.body.bodymodel import BodyModel
    from bodycal_addon.recording.io import save_recording

    rec, _ = _elbow_session(flex_deg=15)
    rec = _with_the_six(rec)
    path = save_recording(rec, tmp_path / "small.bcrec.json")[0]
    assert cli.main(["calibrate-user", str(path), "-o", str(tmp_path / "u.body.json"), "--allow-defaults"]) == 0
    captured = capsys.readouterr()
    # warnings on stderr (FORMATS.md §4), each one line naming the command
    warnings = [ln for ln in captured.err.splitlines() if ln.startswith("bodycal calibrate-user: warning: ")]
    assert warnings and len(warnings) == len(captured.err.splitlines())
    assert any("flex_elbow_l not used: only" in ln for ln in warnings)
    assert "warning" not in captured.out and "Traceback" not in captured.err
    model = BodyModel.load(tmp_path / "u.body.json")
    cal = model.calibration
    assert "flex_elbow_l" in cal["missing"] and cal["warnings"]
    assert "elbow_l touches" in cal["steps_used"]  # the elbow still comes from its two touches


def test_cli_bad_calibration_data_is_one_actionable_line(tmp_path, capsys):
    from bodycal_addon.app import cli
    from bodycal_addon.recording.io import save_recording

    rec, _ = _elbow_session()
    rec.devices = [d for d in rec.devices]
    k = next(i for i, d in enumerate(rec.devices) if d.role == "head")
    rec.devices[k].role = "chest"  # no HMD: nothing can place the head
    path = save_recording(rec, tmp_path / "nohead.bcrec.json")[0]
    assert cli.main(["calibrate-user", str(path), "-o", str(tmp_path / "u.body.json")]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "no HMD" in err and "Traceback" not in err
    assert not (tmp_path / "u.body.json").exists()


def test_operators_store_show_save_and_reload(tmp_path):
    import bpy

    from bodycal_addon.blender import calibration_scene as cs
    from bodycal_addon.blender.recording_scene import import_recording_to_scene

    assert not bpy.ops.bodycal.calibrate_user.poll()
    rec, truth = _still_session(six=True)
    import_recording_to_scene(rec, bpy.context.scene)
    assert bpy.ops.bodycal.calibrate_user() == {"FINISHED"}
    model = cs.load_user_model(bpy.context.scene)
    assert np.linalg.norm(model.world("elbow_l") - truth["elbow"]) < 1e-4
    coll = bpy.data.collections[cs.COLLECTION]
    names = {o.name for o in coll.objects}
    assert {"joint:elbow_l", "sphere:skull", "mesh:torso", "hinge:forearm_l", "anchor:hip_r", "mesh:palm_l"} <= names
    np.testing.assert_allclose(bpy.data.objects["joint:elbow_l"].location, truth["elbow"], atol=1e-4)
    out = tmp_path / "u.body.json"
    assert bpy.ops.bodycal.save_user_model(filepath=str(out)) == {"FINISHED"}
    blend = tmp_path / "scene.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    bpy.ops.wm.read_homefile(use_empty=True)
    assert not cs.has_user_model(bpy.context.scene)
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    again = cs.load_user_model(bpy.context.scene)
    np.testing.assert_allclose(again.world("elbow_l"), model.world("elbow_l"), atol=1e-6)
    bpy.ops.wm.read_homefile(use_empty=True)
    assert bpy.ops.bodycal.load_user_model(filepath=str(out)) == {"FINISHED"}
    assert bpy.ops.bodycal.show_calibration_helpers() == {"FINISHED"}


# --- whole synthetic sessions against the performer's ground truth ------------------------------

GROUP_TOL_MM = {"shoulder": 8.0, "hip": 8.0, "elbow": 8.0, "knee": 8.0, "wrist": 5.0, "ankle": 6.0}


@pytest.fixture(scope="module")
def full_session():
    from bodycal_dev import synthetic
    perf = synthetic.make_performer(height=1.68, build="heavy", seed=4)
    rec, truth = synthetic.record_session(perf, profile="full", motions=(), noise_mm=1.0, wobble_mm=2.0,
                                          outlier_rate=0.1, seed=21)
    return rec, truth


@pytest.fixture(scope="module")
def full_model(full_session):
    return calibrate_user(full_session[0])


def _surface_world(model, element_id):
    from bodycal_addon.body import surface_layout as sl

    e = model.element(element_id)
    out = {}
    for k, p in e.points.items():
        b = model.bones[p.bone]
        head, tail = model.world(b.head), model.world(b.tail)
        out[k] = head + sl.bone_frame(head, tail, b.right) @ p.local
    return out


@pytest.mark.slow
def test_full_session_joint_centres_match_the_truth(full_session, full_model):
    _, truth = full_session
    for s in ("l", "r"):
        for j, tol in GROUP_TOL_MM.items():
            err = 1000 * np.linalg.norm(full_model.world(f"{j}_{s}") - truth.joints_world[f"{j}_{s}"])
            assert err < tol, f"{j}_{s}: {err:.1f} mm"
        for f in ("thumb", "index", "middle", "ring", "pinky"):
            err = 1000 * np.linalg.norm(full_model.world(f"mcp_{f}_{s}") - truth.joints_world[f"mcp_{f}_{s}"])
            assert err < 5.0, f"mcp_{f}_{s}: {err:.1f} mm"
    for j in ("skull_base", "spine_root", "pelvis"):
        assert 1000 * np.linalg.norm(full_model.world(j) - truth.joints_world[j]) < 8.0, j
    cal = full_model.calibration
    for step in ("tpose", "palms_together", "flex_elbow_l", "flex_knee_r", "swing_shoulder_r", "swing_hip_l"):
        assert step in cal["steps_used"], step
    assert cal["missing"] == []
    q = cal["quality"]["swing_hip_l"]
    assert q["kept"] < q["of"] and q["range_deg"] > 40  # the 2-sigma pass dropped the outlier frames


@pytest.mark.slow
def test_full_session_radii_axes_and_surface_match_the_truth(full_session, full_model):
    _, truth = full_session
    tm = truth.body_model()
    for s in ("l", "r"):
        for bone in ("upperarm", "forearm", "thigh", "shin"):
            mine, true = full_model.bones[f"{bone}_{s}"], tm.bones[f"{bone}_{s}"]
            assert abs(mine.radius_head - true.radius_head) < 0.004, bone
            assert abs(mine.radius_tail - true.radius_tail) < 0.004, bone
        for bone in ("forearm", "shin"):
            mine, true = full_model.bones[f"{bone}_{s}"].extra, tm.bones[f"{bone}_{s}"].extra
            assert mine["right_frame"] == true["right_frame"]
            cos = np.dot(mine["right_local"], true["right_local"])
            assert cos > np.cos(np.radians(3)), f"{bone}_{s} hinge axis off by {np.degrees(np.arccos(cos)):.1f} deg"
        assert abs(full_model.bones[f"index_2_{s}"].radius_head - tm.bones[f"index_2_{s}"].radius_head) < 0.002
    for element, tol in (("mesh:jaw", 0.006), ("mesh:torso", 0.012), ("mesh:palm_l", 0.006), ("mesh:sole_r", 0.008)):
        mine, true = _surface_world(full_model, element), _surface_world(tm, element)
        assert set(mine) == set(true), element
        worst = max(np.linalg.norm(mine[k] - true[k]) for k in true)
        assert worst < tol, f"{element}: {worst * 1000:.1f} mm"
    skull, tskull = full_model.element("sphere:skull"), tm.element("sphere:skull")
    assert abs(skull.radius - tskull.radius) < 0.004


@pytest.mark.slow
def test_anchor_rigid_point_beats_the_sphere_under_wobble(full_session):
    """DESIGN.md §3 decision (limbs.py): the anchor centre from the rigid-point fit, not the sphere."""
    from bodycal_addon.core.geometry import fit_rigid_point, fit_sphere

    rec, truth = full_session
    tm = truth.body_model()
    session = Session(rec)
    sphere_err, rigid_err = [], []
    for joint, limb, root in (("hip", "thigh", "pelvis"), ("shoulder", "upperarm", "chest")):
        for s in ("l", "r"):
            idx = session.frames(rec.segments_of(f"swing_{joint}_{s}"))
            pts, used = session.relative_track("x", f"{limb}_{s}", root, idx)
            true_local = tm.joints[f"{joint}_{s}"].frames[f"{limb}_{s}"]
            sphere_err.append(np.linalg.norm(fit_sphere(pts).center - true_local))
            lp, lq, _ = session.pose(f"{limb}_{s}")
            rp, rq, _ = session.pose(root)
            fit = fit_rigid_point(tf.quat_to_matrix(lq[used]), lp[used], tf.quat_to_matrix(rq[used]), rp[used])
            rigid_err.append(np.linalg.norm(fit.local_a - true_local))
    assert max(rigid_err) < 0.006
    assert np.mean(rigid_err) < np.mean(sphere_err)


@pytest.mark.slow
def test_body_model_contract_matches_the_ground_truth_structure(full_session, full_model):
    _, truth = full_session
    tm = truth.body_model()
    assert set(full_model.joints) == set(tm.joints)
    for name, j in tm.joints.items():
        assert full_model.joints[name].frame == j.frame, name
        assert set(full_model.joints[name].frames) == set(j.frames), name
    assert {e.id for e in full_model.surface} == {e.id for e in tm.surface}
    assert set(full_model.bones) == set(tm.bones)
    assert set(full_model.extra["tpose"]) == set(tm.extra["tpose"])
    assert abs(full_model.extra["eye_height"] - tm.extra["eye_height"]) < 0.003
    for role, plane in tm.extra["palm_planes"].items():
        mine = full_model.extra["palm_planes"][role]
        assert np.dot(mine["normal"], plane["normal"]) > np.cos(np.radians(5))
        # the true palm surface lies on the calibrated plane (the truth's stored plane point is
        # projected through the device origin, so compare with its palm mesh instead)
        pos, rot = truth.device_pose(role)
        for p in _surface_world(tm, f"mesh:palm_{role[-1]}").values():
            local = rot.T @ (p - pos)
            assert abs(np.dot(local - mine["point"], mine["normal"])) < 0.004
    assert abs(full_model.reference_time - truth.reference_time) < 0.02
    assert {"wrist_l", "ankle_r", "pelvis"} <= set(full_model.offsets)


@pytest.mark.slow
def test_minimal_profile_yields_a_complete_model_with_defaults_reported():
    from bodycal_addon.body.bodymodel import REQUIRED_USER_JOINTS
    from bodycal_dev import synthetic

    perf = synthetic.make_performer(height=1.80, build="average", seed=2)
    rec, truth = synthetic.record_session(perf, profile="minimal", motions=(), noise_mm=1.0, wobble_mm=2.0,
                                          outlier_rate=0.1, seed=5)
    model = calibrate_user(rec)
    assert set(REQUIRED_USER_JOINTS) <= set(model.joints)
    cal = model.calibration
    assert {"shoulder_l", "elbow_r", "mcp_index_l"} <= set(cal["defaulted"])
    assert "swing_hip_l" in cal["missing"] and "palms_together" in cal["missing"]
    for j, tol in (("wrist_l", 6), ("wrist_r", 6), ("ankle_l", 6), ("hip_l", 8), ("hip_r", 8), ("skull_base", 8),
                   ("shoulder_l", 25), ("elbow_r", 25), ("knee_l", 25)):
        err = 1000 * np.linalg.norm(model.world(j) - truth.joints_world[j])
        assert err < tol, f"{j}: {err:.1f} mm"
    assert len(model.surface) == len(truth.body_model().surface)


def _drop_device(rec, role):
    i = rec.device_index(role)
    keep = [k for k in range(len(rec.devices)) if k != i]
    return Recording(rec.name, rec.time, [rec.devices[k] for k in keep], rec.positions[:, keep],
                     rec.rotations[:, keep], rec.valid[:, keep], rec.marker_names, rec.markers, rec.marker_valid,
                     rec.segments, rec.source)


@pytest.mark.slow
def test_bad_synthetic_data_is_reported_not_fatal(full_session):
    """Without the upper arm tracker the elbow step is fitted from the devices left (the hand
    circling the elbow in a trunk frame); a touch that never settles is dropped with a warning
    naming it, and the rest of the model still comes out."""
    rec, truth = full_session
    model = calibrate_user(_drop_device(rec, "upperarm_l"))
    q = model.calibration["quality"]["flex_elbow_l"]
    assert q["frames"].endswith(" in forearm_l")  # a trunk tracker stands in for the upper arm's
    assert np.linalg.norm(model.world("elbow_l") - truth.joints_world["elbow_l"]) < 0.01
    seg = next(s for s in rec.segments if s.step == "touch" and s.point == "wrist_top_l")
    by = seg.by or "index_tip_r"
    moving = Recording(rec.name, rec.time, rec.devices, rec.positions, rec.rotations, rec.valid, rec.marker_names,
                       rec.markers.copy(), rec.marker_valid, rec.segments, rec.source)
    idx = rec.frames(seg.start, seg.end)
    k = rec.marker_names.index(by)
    moving.markers[idx, k] += np.outer(rec.time[idx] - rec.time[idx[0]], [0.2, 0.0, 0.0])  # slides at 20 cm/s
    model = calibrate_user(moving)
    cal = model.calibration
    assert any(re.search(r"touch wrist_top_l by index_tip_r .* not used: the touch never stopped moving", w)
               for w in cal["warnings"]), cal["warnings"]
    assert "wrist_l" not in cal["steps_used"]  # the wrist touches were not used ...
    assert "wrist_l from the motion" in cal["quality"] or "wrist_l" in cal["defaulted"]  # ... it came from elsewhere


def test_wizard_lists_the_steps_of_the_timeline_with_their_quality():
    import bpy

    from bodycal_addon.blender.recording_scene import import_recording_to_scene

    panels = __import__("bl_ext.user_default.bodycal.panels.calibration_panel", fromlist=["x"])
    rec, _ = _still_session(six=True)
    import_recording_to_scene(rec, bpy.context.scene)
    found = panels.steps_in_scene(bpy.context.scene)
    assert found == {"stand": 1, "flex_elbow_l": 1, "touch": 2}
    assert bpy.ops.bodycal.calibrate_user() == {"FINISHED"}
    quality = panels._calibration(bpy.context.scene)["quality"]
    text = panels.quality_text(quality["flex_elbow_l"])
    assert "mm" in text and "pts" in text and "°" in text
    assert hasattr(bpy.types, "BODYCAL_PT_calibration")


def test_the_panel_says_which_device_was_left_without_a_role():
    """A tracker the T-pose never saw and no role given: not used, and its limb's joints defaulted;
    the Calibration panel says both."""
    import bpy
    import ui_layout
    from recording_fixtures import tpose_recording

    from bodycal_addon.blender.recording_scene import import_recording_to_scene

    rec = tpose_recording(roles=True, shuffle=True, yaw=0.4, seed=6)
    k = rec.device_index("forearm_r")
    name = rec.devices[k].name
    rec.devices[k].role = None
    seg = rec.segments_of("tpose")[0]
    rec.valid[rec.frames(seg.start - 0.1, seg.end + 0.1), k] = False
    import_recording_to_scene(rec, bpy.context.scene)
    assert bpy.ops.bodycal.calibrate_user() == {"FINISHED"}
    text = " ".join(e[1] for e in ui_layout.draw(bpy.types.BODYCAL_PT_calibration, bpy.context) if e[0] == "label")
    assert f"device {name} has no role and is not used" in text
    for joint in ("elbow_r", "wrist_r"):
        assert f"{joint} defaulted: no forearm_r tracker measured it, and device {name}, left without a role" in text


@pytest.mark.slow
def test_hinge_axis_from_rotations_beats_the_circle_normal(full_session):
    """DESIGN.md §3 decision (limbs.py): the hinge axis from the relative rotations."""
    from bodycal_addon.core.geometry import fit_circle, fit_rotation_axis

    rec, truth = full_session
    tm = truth.body_model()
    session = Session(rec)
    rot_err, circle_err = [], []
    for joint, inter, anch in (("elbow", "forearm", "upperarm"), ("knee", "shin", "thigh")):
        for s in ("l", "r"):
            pts, used = session.relative_track("x", f"{inter}_{s}", f"{anch}_{s}",
                                               session.frames(rec.segments_of(f"flex_{joint}_{s}")))
            circle = fit_circle(pts)
            rel = tf.quat_to_matrix(tf.quat_mul(tf.quat_conj(session.pose(f"{inter}_{s}")[1][used]),
                                                session.pose(f"{anch}_{s}")[1][used]))
            axis, swept = fit_rotation_axis(rel[circle.inliers])
            true = np.array(tm.bones[f"{inter}_{s}"].extra["right_local"])
            rot_err.append(np.degrees(np.arccos(min(1.0, abs(axis @ true)))))
            circle_err.append(np.degrees(np.arccos(min(1.0, abs(circle.normal @ true)))))
            assert swept > 60
    assert max(rot_err) < 2.0
    assert np.mean(rot_err) < np.mean(circle_err)


# --- measured or guessed (calibration/coverage.py, DESIGN.md §3) -----------------------------------


def _demo_part(frames=900, roles=None, segments=False):
    """The first `frames` of the bundled demo recording (15 devices, LED gloves), its calibration
    segments dropped unless `segments`, only the devices of `roles` when given."""
    from bodycal_addon.core import paths
    from bodycal_addon.recording.io import load_recording

    rec = load_recording(paths.ROOT_DIR / "sample_rigs" / "recordings" / "demo_full.bcrec.json")
    keep = [i for i, d in enumerate(rec.devices) if roles is None or d.role in roles]
    has_markers = roles is None and rec.markers is not None
    return Recording(rec.name, rec.time[:frames], [rec.devices[i] for i in keep], rec.positions[:frames, keep],
                     rec.rotations[:frames, keep], rec.valid[:frames, keep],
                     rec.marker_names if has_markers else [], rec.markers[:frames] if has_markers else None,
                     rec.marker_valid[:frames] if has_markers else None,
                     [s for s in rec.segments if s.end <= rec.time[frames - 1]] if segments else [], rec.source)


def test_cli_writes_a_body_mostly_guessed_and_says_so(tmp_path, capsys):
    """A recording without calibration steps: the model is written (a guessed body still
    retargets), with a warning line saying how little was measured; --allow-defaults, kept for
    older scripts, changes nothing (DESIGN.md §3 "Measured or guessed")."""
    from bodycal_addon.app import cli
    from bodycal_addon.body.bodymodel import REQUIRED_USER_JOINTS, BodyModel
    from bodycal_addon.recording.io import save_recording

    path = save_recording(_demo_part(), tmp_path / "take.bcrec.json")[0]
    outputs = []
    for extra in ([], ["--allow-defaults"]):
        out = tmp_path / f"u{len(extra)}.body.json"
        assert cli.main(["calibrate-user", str(path), "-o", str(out), *extra]) == 0
        captured = capsys.readouterr()
        defaulted = BodyModel.load(out).calibration["defaulted"]
        measured = [j for j in REQUIRED_USER_JOINTS if j not in defaulted]
        assert 2 * len(measured) < len(REQUIRED_USER_JOINTS)  # the case: mostly guessed
        summary = captured.out.splitlines()[0]
        assert f"measured {len(measured)} of {len(REQUIRED_USER_JOINTS)} body joints" in summary
        warning = [ln for ln in captured.err.splitlines() if "body joints measured" in ln]
        assert warning == [f"bodycal calibrate-user: warning: only {len(measured)} of {len(REQUIRED_USER_JOINTS)} "
                           f"body joints measured, the other {len(REQUIRED_USER_JOINTS) - len(measured)} guessed from "
                           "the eye height: the user's proportions are a table's (the calibration steps of "
                           "docs/FORMATS.md §2.4 measure them)"]
        outputs.append(out.read_text())
    assert outputs[0] == outputs[1]


def test_cli_calibrates_a_three_point_recording_and_retargets_it(tmp_path, capsys, data_dir):
    """HMD and two controllers, with the calibration steps: it used to be refused ("a 3-point one
    cannot drive the hips and legs"); now the pelvis and feet are estimated, the summary says so,
    and the take retargets onto an avatar with a verified bake (DESIGN.md §3 "The device ladder")."""
    from bodycal_addon.app import cli
    from bodycal_addon.body.bodymodel import BodyModel
    from bodycal_addon.recording.io import save_recording

    rec = _demo_part(frames=2822, roles=("head", "hand_l", "hand_r"), segments=True)
    path = save_recording(rec, tmp_path / "3point.bcrec.json")[0]
    user = tmp_path / "u.body.json"
    assert cli.main(["calibrate-user", str(path), "-o", str(user)]) == 0
    summary = capsys.readouterr().out.splitlines()[0]
    assert "the pelvis and the feet estimated from the head and hands (3 devices (HMD and two controllers))" \
        in summary
    model = BodyModel.load(user)
    assert set(model.extra["estimated_devices"]) == {"pelvis", "chest", "foot_l", "foot_r"}
    avatar = data_dir / "avatars" / "mpfb2_variants" / "child_10y.glb"
    out = tmp_path / "baked.blend"
    assert cli.main(["retarget", str(path), "--user", str(user), "--avatar", str(avatar), "-o", str(out)]) == 0
    captured = capsys.readouterr()
    assert out.exists() and "estimated from the head and hands" in captured.out
    assert "Traceback" not in captured.err


def test_cli_refuses_a_recording_without_a_hand_in_one_line(tmp_path, capsys):
    from bodycal_addon.app import cli
    from bodycal_addon.recording.io import save_recording

    rec = _demo_part(frames=900, roles=("head", "hand_l"), segments=True)
    path = save_recording(rec, tmp_path / "2point.bcrec.json")[0]
    assert cli.main(["calibrate-user", str(path), "-o", str(tmp_path / "u.body.json")]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "no hand_r device" in line and "at least the HMD and both hands" in line and "Traceback" not in line
    assert not (tmp_path / "u.body.json").exists()


def test_the_sidebar_calibrates_a_guessed_body_and_says_so():
    import bpy

    from bodycal_addon.blender import calibration_scene as cs
    from bodycal_addon.blender.recording_scene import import_recording_to_scene

    ops = __import__("bl_ext.user_default.bodycal.operators.calibration", fromlist=["x"])
    import_recording_to_scene(_demo_part(frames=600), bpy.context.scene)
    assert bpy.ops.bodycal.calibrate_user() == {"FINISHED"}
    assert cs.has_user_model(bpy.context.scene) and bpy.context.scene.name not in ops.REFUSED
