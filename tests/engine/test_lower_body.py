"""The device ladder's bottom rungs (DESIGN.md §3 "The device ladder", §6 "A lower body from head and
hands"): a kit of HMD and two controllers (or plus a pelvis tracker) calibrated with estimated
devices, and the lower-body model that moves them; on recordings made from real motion by
`evaluation/` and on head paths made here to isolate one behaviour."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from outside_takes import clip_performer, outside_recording

from bodycal_addon.body.skeleton import JOINT_INDEX as JI
from bodycal_addon.calibration import calibrate_user, check_usable
from bodycal_addon.core import paths
from bodycal_addon.core import transforms as tf
from bodycal_addon.core.errors import BodyCalError
from bodycal_addon.live.solver import LiveSolver
from bodycal_addon.retarget import lower_body
from bodycal_addon.retarget import pipeline as pl
from bodycal_addon.retarget.lower_body import body_path, heel, kneel, stepping
from bodycal_addon.retarget.user_animation import animate_user
from bodycal_dev.retarget_fixtures import procedural_avatar
from evaluation import measure
from evaluation.level import level_take

FPS = 90.0


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    """A CMU walk recorded with HMD and controllers only, its capture, and its user model."""
    perf = clip_performer(paths.data_dir(), "02_01_walk.bvh")
    rec, cap = outside_recording(perf, tmp_path_factory.mktemp("three"), profile="three", seed=0)
    return rec, cap, calibrate_user(rec)


@pytest.fixture(scope="module")
def user(walk):
    return walk[2]


def test_a_three_point_kit_calibrates_with_estimated_devices_and_says_so(walk):
    rec, cap, user = walk
    assert [d.role for d in rec.devices] == ["head", "hand_l", "hand_r"]
    cov = check_usable(user)  # no refusal
    assert cov.estimated_devices == ("pelvis", "chest", "foot_l", "foot_r")
    assert "the pelvis and the feet estimated from the head and hands (3 devices" in cov.line()
    assert set(user.extra["estimated_devices"]) == {"pelvis", "chest", "foot_l", "foot_r"}
    assert {"pelvis", "hip_l", "ankle_r", "toe_l"} <= set(user.calibration["estimated"])
    for role in ("pelvis", "chest", "foot_l", "foot_r"):
        assert role in user.extra["tpose"]
    # the joints they carry are known in them, exactly where the devices stand on the body
    assert np.allclose(user.joints["ankle_l"].frames["foot_l"], 0.0, atol=1e-6)
    # what three points do measure is measured: the shoulders from the arm circles, within 10 mm
    truth = cap.truth()
    ref = int(round(user.reference_time * FPS))
    shoulders = measure.joint_errors_mm({j: v.world for j, v in user.joints.items()}, truth["joints"],
                                        truth["positions"][ref])
    assert max(shoulders["shoulder_l"], shoulders["shoulder_r"], shoulders["skull_base"]) < 10.0


def test_the_hmd_and_both_hands_are_the_lowest_rung(walk):
    rec, _, _ = walk
    one_hand = replace(rec, devices=rec.devices[:2], positions=rec.positions[:, :2], rotations=rec.rotations[:, :2],
                       valid=rec.valid[:, :2])
    with pytest.raises(BodyCalError, match=r"no hand_r device.*at least the HMD and both hands"):
        check_usable(calibrate_user(one_hand))


@pytest.mark.parametrize("profile", ["three", "four"])
def test_every_method_retargets_a_kit_below_six_devices(profile, tmp_path):
    perf = clip_performer(paths.data_dir(), "131_01_start_walk_stop.bvh")
    rec, _ = outside_recording(perf, tmp_path, profile=profile, seed=1)
    user = calibrate_user(rec)
    avatar = procedural_avatar()
    for method in pl.METHODS:
        anim = pl.retarget(rec, user, avatar, method)
        assert np.isfinite(anim.rotations).all() and np.isfinite(anim.root_location).all()
    assert any("estimated from the head and hands" in n for n in lower_body.complete(rec, user).notes)


@pytest.fixture(scope="module")
def start_walk_stop(tmp_path_factory):
    """A start, a walk and a stop (16 landings of the source's feet: a count 20 % can judge)."""
    perf = clip_performer(paths.data_dir(), "131_01_start_walk_stop.bvh")
    rec, cap = outside_recording(perf, tmp_path_factory.mktemp("three"), profile="three", seed=1)
    return rec, cap, calibrate_user(rec)


def test_estimated_feet_stand_still_on_the_floor_and_step_as_often_as_the_walker(start_walk_stop):
    rec, cap, user = start_walk_stop
    full = lower_body.complete(rec, user)
    pose = animate_user(full, user)
    truth = cap.truth()
    a, b = truth["motion"]
    for s in "lr":
        ball = pose.joints[a:b, JI[f"toe_{s}"]]  # the heel rises at the end of a stance: the ball stays
        v = np.linalg.norm(np.diff(ball, axis=0), axis=1) * FPS
        planted = v < 1e-6
        assert planted.mean() > 0.3  # it stands, exactly still, between its steps
        assert np.abs(ball[1:][planted, 2] - user.joints[f"toe_{s}"].world[2]).max() < 1e-6  # on the floor
        ankle = pose.joints[a:b, JI[f"ankle_{s}"]]
        hip = pose.joints[a:b, JI[f"hip_{s}"]]
        leg = user.bones[f"thigh_{s}"].length + user.bones[f"shin_{s}"].length
        # the heel rises (tiptoes) so the leg is not stretched far past its length (a standing body
        # straightens by heel.SWAY first)
        assert np.linalg.norm(hip - ankle, axis=1).max() < leg + 0.02
    J = truth["joints"]
    ours = sum(measure.landings(pose.joints[a:b, [JI[f"ankle_{s}"], JI[f"toe_{s}"]]], FPS) for s in "lr")
    source = sum(measure.landings(truth["positions"][a:b, [J.index(f"ankle_{s}"), J.index(f"toe_{s}")]], FPS)
                 for s in "lr")
    assert abs(ours - source) <= max(1, 0.2 * source)


@pytest.mark.parametrize("take", ["walk", "start_walk_stop"])
def test_a_walk_at_its_quickest_cadence_never_leaves_the_foot_behind_out_of_reach(take, request):
    """A walk's steps follow as quickly as a swing and its double support allow: the hip walks on
    from the foot behind meanwhile. Its heel rises to keep the hip within reach (heel.py) and the
    foot lifts once that is past stepping.RISE_STEP; a swing of the other foot is hurried so that
    foot may lift in time, after the double support too. So the leg is never further from its hip
    than the heel's reach (before: the leg 27.6 mm past its length on 02_01, its heel risen to heel.MOST)."""
    rec, cap, user = request.getfixturevalue(take)
    pose = animate_user(lower_body.complete(rec, user), user)
    shape = lower_body.LowerBodyShape.of(user)
    a, b = cap.truth()["motion"]
    limit = np.maximum(heel.REACH * shape.leg, np.linalg.norm(shape.hip - shape.ankle, axis=1) + heel.SWAY)
    for i, s in enumerate("lr"):
        d = np.linalg.norm(pose.joints[a:b, JI[f"hip_{s}"]] - pose.joints[a:b, JI[f"ankle_{s}"]], axis=1)
        assert d.max() < limit[i] + 0.001, (s, d.max() - limit[i])


def test_on_the_walks_floor_levelled_the_feet_step_as_often_as_the_walker(walk):
    """The CMU walk 02_01's floor rises 44 mm along its stances (the source's own: its balls'
    lowest per stance, measure.floor_along), the walker's head rising with it; the estimate's floor
    is flat (the calibration's), so its pelvis rises above it by as much, the legs straighten, each
    landing is pulled back within the leg's reach and the foot behind leaves reach sooner (a swing
    hurried): 7 steps as recorded against the walker's 5. The same take with its floor levelled
    (turned rigidly about a horizontal axis through where the calibration stood, as
    bench_three_point judges it: evaluation/level.py) steps within 20 % of the walker, the legs
    within their heels' reach (DESIGN.md §6 "Feet that step")."""
    rec, cap, user = walk
    truth = cap.truth()
    a, b = truth["motion"]
    T, J = truth["positions"], truth["joints"]
    feet = [T[a:b][:, [J.index(f"ankle_{s}"), J.index(f"toe_{s}")]] for s in "lr"]
    axis, slope, extent = measure.floor_along(feet, FPS)
    assert 0.03 < slope * extent < 0.06
    level, _, tilt = level_take(rec, truth, FPS)  # bench_three_point's levelling
    assert abs(np.tan(tilt) - slope) < 1e-12
    level_user = calibrate_user(level)
    pose = animate_user(lower_body.complete(level, level_user), level_user)
    ours = sum(measure.landings(pose.joints[a:b][:, [JI[f"ankle_{s}"], JI[f"toe_{s}"]]], FPS) for s in "lr")
    walker = sum(measure.landings(f, FPS) for f in feet)
    assert abs(ours - walker) <= 0.2 * walker, (ours, walker)
    shape = lower_body.LowerBodyShape.of(level_user)
    limit = np.maximum(heel.REACH * shape.leg, np.linalg.norm(shape.hip - shape.ankle, axis=1) + heel.SWAY)
    for i, s in enumerate("lr"):
        d = np.linalg.norm(pose.joints[a:b, JI[f"hip_{s}"]] - pose.joints[a:b, JI[f"ankle_{s}"]], axis=1)
        assert d.max() < limit[i] + 0.001, (s, d.max() - limit[i])


def test_the_floor_along_a_walk_is_measured_whichever_way_it_rises():
    """measure.floor_along on feet made here: stances on a floor rising 2 % along a walk heading
    30 degrees off the x axis, read as a rise whichever way the walk goes; a level floor reads 0."""
    heading = np.radians(30.0)
    way = np.array([np.cos(heading), np.sin(heading)])
    frames = np.arange(900)
    for slope, direction in ((0.02, 1.0), (0.02, -1.0), (0.0, 1.0)):
        feet = []
        for side, phase in ((-0.1, 0), (0.1, 90)):  # the two feet a step apart in time, apart across
            step = np.floor((frames + phase) / 180.0)  # each foot moves once every 2 s, standing 1.5 s
            u = np.clip(((frames + phase) % 180.0 - 135.0) / 45.0, 0.0, 1.0)
            along = direction * 1.2 * (step + u)
            xy = along[:, None] * way + side * np.array([-way[1], way[0]])
            z = slope * direction * along + 0.03 + 0.05 * np.sin(np.pi * u)
            ball = np.c_[xy, z]
            feet.append(np.stack([ball + [0.0, 0.0, 0.07], ball], axis=1))
        axis, got, extent = measure.floor_along(feet, FPS)
        assert abs(got - slope) < 1e-6
        assert extent > 5.0
        if slope:
            assert axis @ way * direction > 0.999  # along the walk, pointing up the floor


def test_the_pelvis_follows_the_walker_under_the_head(walk):
    rec, cap, user = walk
    pose = animate_user(lower_body.complete(rec, user), user)
    truth = cap.truth()
    a, b = truth["motion"]
    d = pose.joints[a:b, JI["pelvis"]] - truth["positions"][a:b, truth["joints"].index("pelvis")]
    assert np.median(np.linalg.norm(d[:, :2], axis=1)) < 0.04  # over the floor: the model's own
    # (its height is the anthropometric table's against this skeleton's: DESIGN.md §3)
    assert np.percentile(np.linalg.norm(d, axis=1), 95) < 0.08


def test_the_pelvis_is_compared_with_the_same_landmark_on_both_sides(walk):
    """bench_three_point compares our pelvis joint with the clip's "pelvis": both must be the middle
    of the two hip joint centres. Ours: the user skeleton's pelvis joint, its hips beside it (never
    above or below). The clip's: the middle of its thigh bones' heads, not its root (CMU's root sits
    on the pelvis about 0.1 m above them, where the hip-joint bones start)."""
    rec, cap, user = walk
    pose = animate_user(lower_body.complete(rec, user), user)
    mid = 0.5 * (pose.joints[:, JI["hip_l"]] + pose.joints[:, JI["hip_r"]])
    assert np.abs(pose.joints[:, JI["pelvis"]] - mid).max() < 1e-6
    truth = cap.truth()
    J = truth["joints"]
    T = truth["positions"]
    assert np.abs(T[:, J.index("pelvis")] - 0.5 * (T[:, J.index("hip_l")] + T[:, J.index("hip_r")])).max() < 1e-9
    perf = clip_performer(paths.data_dir(), "02_01_walk.bvh")
    _, P = perf.clip.fk()  # the clip's own joints, Z up
    root_above = P[:, perf.j("pelvis"), 2] - perf.truth_positions(P)[:, J.index("pelvis"), 2]
    assert np.median(root_above) > 0.08  # the root is another point, well above the hips' middle


def test_turning_the_recording_turns_the_estimated_body(walk):
    """An invariant: the same take turned about the vertical and moved on the floor gives the same
    estimated devices, turned and moved (the model has no preferred facing)."""
    rec, _, user = walk
    ang, move = np.radians(70.0), np.array([0.8, -1.3, 0.0])
    c, s = np.cos(ang), np.sin(ang)
    rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])
    q = tf.matrix_to_quat(rz)
    turned = replace(rec, positions=rec.positions @ rz.T + move, rotations=tf.quat_mul(q, rec.rotations))
    user2 = calibrate_user(turned)
    a = lower_body.complete(rec, user)
    b = lower_body.complete(turned, user2)
    for role in ("pelvis", "chest", "foot_l", "foot_r"):
        pa, _, _ = a.pose(role)
        pb, _, _ = b.pose(role)
        assert np.abs(pa @ rz.T + move - pb).max() < 1e-3, role


# --- one behaviour at a time, on head paths made here -------------------------------------------


def _head_take(user, heights, turns_deg=None, forward_m=None, pitch_deg=None, seconds=None):
    """A recording of the head along a path (its height (F,), heading turn (F,) degrees, travel
    forward (F,) m, pitch down (F,) degrees) from the user's reference pose, turning about the
    skull base as a head does, the hands held at their reference place relative to the head."""
    n = len(heights)
    tpose = user.extra["tpose"]
    head0 = np.asarray(tpose["head"][:3], float)
    r0 = tf.quat_to_matrix(np.asarray(tpose["head"][3:7], float))
    shape = lower_body.LowerBodyShape.of(user)
    fwd0 = np.array([np.cos(shape.heading0), np.sin(shape.heading0), 0.0])
    right0 = np.array([np.sin(shape.heading0), -np.cos(shape.heading0), 0.0])
    turns = np.radians(np.zeros(n) if turns_deg is None else turns_deg)
    pitch = np.radians(np.zeros(n) if pitch_deg is None else pitch_deg)
    travel = np.zeros(n) if forward_m is None else forward_m
    pos = np.empty((n, 3, 3))
    rot = np.empty((n, 3, 4))
    neck0 = np.asarray(user.joints["skull_base"].world, float)
    for k in range(n):
        yaw = tf.quat_to_matrix(tf.axis_angle_to_quat(np.array([0, 0, 1.0]), turns[k]))
        nod = tf.quat_to_matrix(tf.axis_angle_to_quat(right0, -pitch[k]))
        rh = yaw @ nod @ r0
        head = neck0 + yaw @ nod @ (head0 - neck0) + fwd0 * travel[k]
        head[2] += heights[k] - head0[2]
        pos[k, 0], rot[k, 0] = head, tf.matrix_to_quat(rh)
        for i, role in ((1, "hand_l"), (2, "hand_r")):
            hp = np.asarray(tpose[role][:3], float)
            hr = tf.quat_to_matrix(np.asarray(tpose[role][3:7], float))
            pos[k, i] = head + yaw @ (hp - head0)
            rot[k, i] = tf.matrix_to_quat(yaw @ hr)
    from bodycal_addon.recording.model import Device, Recording

    devices = [Device("hmd", "hmd", "head"), Device("l", "controller", "hand_l"), Device("r", "controller", "hand_r")]
    return Recording("made", np.arange(n) / FPS, devices, pos, rot, np.ones((n, 3), bool))


def _feet(full):
    return np.stack([full.pose(f"foot_{s}")[0] for s in "lr"], axis=1)


def test_a_person_standing_still_never_steps(user):
    z0 = user.extra["tpose"]["head"][2]
    full = lower_body.complete(_head_take(user, np.full(450, z0) + 0.005 * np.sin(np.arange(450) / 40)), user)
    feet = _feet(full)
    assert np.abs(feet - feet[0]).max() < 1e-9
    assert "(0 steps)" in full.notes[-1]


def test_a_glance_aside_does_not_step_a_turn_does(user):
    """Looking 40 degrees aside for two seconds is a glance (the body stays); turning 90 degrees and
    staying so turns the feet with it, step by step."""
    z0 = user.extra["tpose"]["head"][2]
    n = 540
    glance = np.concatenate([np.zeros(90), np.full(180, 40.0), np.zeros(n - 270)])
    feet = _feet(lower_body.complete(_head_take(user, np.full(n, z0), glance), user))
    assert np.abs(feet - feet[0]).max() < 1e-9
    turn = np.clip((np.arange(n) - 60) / 90.0, 0, 1) * 90.0
    take = _head_take(user, np.full(n, z0), turn)
    full = lower_body.complete(take, user)
    shape = lower_body.LowerBodyShape.of(user)
    body = body_path.offline_path(shape, take.time, *lower_body.filled_pose(take, "head")).heading
    for s in "lr":
        forward = tf.quat_to_matrix(full.pose(f"foot_{s}")[1]) @ [0, 1.0, 0]
        feet = np.unwrap(np.arctan2(forward[:, 1], forward[:, 0]))
        assert np.degrees(feet[-1] - feet[0]) > 45.0  # it stepped round with the body ...
        # ... and stands within a step's threshold of the body's heading
        assert abs(np.degrees(feet[-1] - feet[0] - (body[-1] - body[0]))) <= np.degrees(stepping.TURN_STEP) + 1e-6


def test_walking_forward_steps_the_feet_along_and_never_crosses_them(user):
    z0 = user.extra["tpose"]["head"][2]
    n = 450
    full = lower_body.complete(_head_take(user, np.full(n, z0), forward_m=np.clip(np.arange(n) - 45, 0, None)
                                          / FPS * 1.2), user)
    feet = _feet(full)
    shape = lower_body.LowerBodyShape.of(user)
    right = np.array([np.sin(shape.heading0), -np.cos(shape.heading0), 0.0])
    fwd = np.array([np.cos(shape.heading0), np.sin(shape.heading0), 0.0])
    assert ((feet[-1] - feet[0]) @ fwd > 3.0).all()  # 3.9 m walked: the feet came along
    across = (feet[:, 0] - feet[:, 1]) @ right  # the left foot on the left
    assert across.max() < -0.05


def test_a_deep_crouch_kneels_on_one_knee_and_the_pelvis_never_sinks_below_a_heel(user):
    z0 = user.extra["tpose"]["head"][2]
    n = 400
    heights = z0 - (z0 - 0.6) * np.clip(np.sin(np.pi * np.arange(n) / n) * 1.6, 0, 1)
    full = lower_body.complete(_head_take(user, heights), user)
    pose = animate_user(full, user)
    shape = lower_body.LowerBodyShape.of(user)
    low = np.argmin(heights)
    w = kneel.kneel_weight(shape, pose.joints[:, JI["pelvis"], 2])
    assert w[low] == pytest.approx(1.0) and w[0] == 0.0
    knees = pose.joints[low, [JI["knee_l"], JI["knee_r"]], 2]
    assert knees.min() < 0.12  # one knee down on the floor
    assert knees.max() > 0.25  # the other up: its foot still planted
    assert pose.joints[:, JI["pelvis"], 2].min() >= body_path.LOWEST_PELVIS * shape.pelvis_height - 1e-6


def _bow_after_a_quick_turn(user, n=360):
    """The head turns 90 degrees in 0.3 s and at once bows (pitched 60 degrees down, the head
    0.25 m lower) for a second, then turns back up: picking something up beside you."""
    z0 = user.extra["tpose"]["head"][2]
    k = np.arange(n)
    turn = 90.0 * np.clip((k - 60) / 27.0, 0, 1) * np.clip((240 - k) / 27.0, 0, 1)
    bow = np.clip((k - 87) / 20.0, 0, 1) * np.clip((213 - k) / 20.0, 0, 1)
    return _head_take(user, z0 - 0.25 * bow, turn, pitch_deg=60.0 * bow), slice(120, 180)


def _lean_off_the_head_deg(path, head_heading) -> np.ndarray:
    """(F,) how far (degrees) the pelvis -> skull base line over the floor points from the head's
    heading."""
    trunk = path.neck - path.pelvis
    return np.degrees(np.abs(shape_wrap(np.arctan2(trunk[:, 1], trunk[:, 0]) - head_heading)))


def shape_wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


def test_a_bow_after_a_quick_turn_leans_toward_where_the_head_looks(user):
    """The body's heading is the head's smoothed (a glance does not turn the body), so it lags a
    quick turn; the trunk bows toward what the eyes look down at, not along the lagging body: the
    pelvis goes behind the head as it faces (offline and live). Before, the bow went along the
    body's heading: here 30 degrees off (4 after); on the CMU start-walk-stop's turn and crouch 40-60
    degrees, the pelvis 160 mm aside."""
    take, bowed = _bow_after_a_quick_turn(user)
    shape = lower_body.LowerBodyShape.of(user)
    pos, rot = lower_body.filled_pose(take, "head")
    _, head_heading, _ = body_path.neck_and_head(shape, pos, rot)
    offline = body_path.offline_path(shape, take.time, pos, rot)
    assert np.degrees(np.abs(shape_wrap(offline.heading[bowed] - head_heading[bowed]))).max() > 20.0  # it lags
    assert np.degrees(offline.lean[bowed]).min() > 20.0  # a bow
    assert _lean_off_the_head_deg(offline, head_heading)[bowed].max() < 8.0
    live = body_path.LivePath(shape)
    steps = [live.step(t, pos[i], rot[i]) for i, t in enumerate(take.time)]
    path = body_path.BodyPath(*(np.concatenate([getattr(s, f) for s in steps]) for f in
                                ("neck", "heading", "lean", "pelvis", "pelvis_rot", "lift", "velocity")))
    assert _lean_off_the_head_deg(path, head_heading)[bowed].max() < 8.0


def test_a_hop_lifts_both_feet_and_lands_them(user):
    z0 = user.extra["tpose"]["head"][2]
    n = 270
    hop = 0.18 * np.clip(np.sin(np.pi * (np.arange(n) - 90) / 45.0), 0, None) * ((np.arange(n) >= 90)
                                                                                    & (np.arange(n) < 135))
    feet = _feet(lower_body.complete(_head_take(user, z0 + hop), user))
    top = 90 + 22
    assert feet[top, :, 2].min() > feet[0, :, 2].max() + 0.08  # both off the floor
    assert np.abs(feet[-1] - feet[0]).max() < 1e-6  # and back where they stood


def test_seated_the_pelvis_stays_on_the_seat_and_the_feet_stay_planted(user):
    z0 = user.extra["tpose"]["head"][2]
    n = 360
    sway = 0.06 * np.sin(np.arange(n) / 30.0)
    full = lower_body.complete(_head_take(user, np.full(n, z0 - 0.45), forward_m=sway), user, seat_height=0.45)
    shape = lower_body.LowerBodyShape.of(user)
    pelvis = animate_user(full, user).joints[:, JI["pelvis"], 2]
    assert np.allclose(pelvis, 0.45 + body_path.HIP_ABOVE_SEAT * shape.stature, atol=0.02)
    feet = _feet(full)
    assert np.abs(feet - feet[0]).max() < 1e-9
    assert "seated at 0.45 m" in full.notes[-1]


def test_live_frames_get_the_estimated_devices_as_they_come(walk):
    """The stream's estimated body is forward only; it stands where the bake's does when the
    performer stands, and every frame is solved."""
    rec, _, user = walk
    solver = LiveSolver(user, procedural_avatar(), "egocentric", devices=rec.devices, rate=FPS)
    frames = range(0, 400)
    solved = [solver.push(rec.time[k], rec.positions[k], rec.rotations[k], rec.valid[k]) for k in frames]
    assert all(s is not None and np.isfinite(s.basis).all() for s in solved)
    live = solver.recording
    whole = lower_body.complete(rec, user)
    for role in ("pelvis", "foot_l"):
        a = live.pose(role)[0][:400]
        b = whole.pose(role)[0][:400]
        assert np.median(np.linalg.norm(a - b, axis=1)) < 0.02, role  # the performer stands here


def test_live_an_estimated_foot_stands_where_the_bake_plants_it_after_a_slow_short_step():
    """The real take simsaber (a Beat Saber replay, three points): the stepper moves the right foot
    7.4 cm in 0.5 s, inside one stance's hold; the bake cuts that stance where the foot has moved
    `feet.DRIFT` (FeetPlan, an estimated foot). The stance found frame by frame (a stream's) held
    the foot where it came down, 128 mm from the bake's place; it cuts the same step now, and
    wherever both plant the foot they plant it within 2 mm of each other."""
    from bodycal_addon.recording import io as recording_io
    from bodycal_addon.retarget import feet
    from bodycal_addon.retarget.pose_source import RecordingSource
    from bodycal_addon.retarget.solver import PreparedSolver

    rec = recording_io.load_recording(paths.data_dir() / "real_vr" / "beat_saber" / "simsaber_sample.bsor")
    user = calibrate_user(rec)
    full = lower_body.complete(rec, user)
    avatar = procedural_avatar()
    bake = PreparedSolver(RecordingSource(full, user), avatar, "offsets").feet.rows(0, full.frame_count)
    live = PreparedSolver(RecordingSource(full, user), avatar, "offsets", stance="causal")
    rows = live.feet.rows(0, full.frame_count)
    for s in "lr":
        both = (bake[s][0] >= 1.0) & (rows[s][0] >= 1.0)
        assert both.mean() > 0.95
        for place in (2, 3):  # the heel's and the ball's
            assert np.linalg.norm(bake[s][place][both] - rows[s][place][both], axis=1).max() < 0.002, (s, place)
    assert {st.drift for st in live.feet.stance.values()} == {feet.DRIFT}  # both feet estimated


def test_avatargos_six_devices_and_protocol_calibrate_without_a_flag(tmp_path):
    """AvatarGo's own protocol (six devices: T-pose, swings, flexes) measures 5 of the 14 body
    joints; it used to be refused as "mostly guessed" unless --allow-defaults, although Exact
    Offsets needs nothing but the T-pose (issue: the device ladder). Now it is usable, said."""
    perf = clip_performer(paths.data_dir(), "02_01_walk.bvh")
    rec, _ = outside_recording(perf, tmp_path, profile="six", seed=0)
    user = calibrate_user(rec)
    cov = check_usable(user)
    assert cov.mostly_guessed and not cov.estimated_devices
    assert cov.warnings() and "guessed from the eye height" in cov.warnings()[0]
    anim = pl.retarget(rec, user, procedural_avatar(), "offsets")
    assert np.isfinite(anim.rotations).all()


def test_without_calibration_steps_the_arms_are_a_body_of_that_height(walk):
    """No T-pose and no stand step: the reference is a moment the walker stood still, hands
    anywhere. The arms are the anthropometric table's for the height (within 12 % of the CMU
    skeleton's own), both alike, not the hand's distance from the shoulder at that moment."""
    rec, cap, _ = walk
    user = calibrate_user(replace(rec, segments=[]))
    assert user.calibration["reference"] == "standing moment"
    truth = cap.truth()
    J, names = truth["positions"][0], truth["joints"]
    true_arm = np.mean([np.linalg.norm(J[names.index(f"elbow_{s}")] - J[names.index(f"shoulder_{s}")])
                        + np.linalg.norm(J[names.index(f"wrist_{s}")] - J[names.index(f"elbow_{s}")]) for s in "lr"])
    arms = [user.bones[f"upperarm_{s}"].length + user.bones[f"forearm_{s}"].length for s in "lr"]
    assert abs(arms[0] - arms[1]) < 1e-3
    assert abs(arms[0] / true_arm - 1.0) < 0.12, (arms, true_arm)
    # the hands pulled in half way to the head all along (held at the chest at that moment)
    held = rec.positions.copy()
    held[:, 1:] = held[:, :1] + 0.5 * (held[:, 1:] - held[:, :1])
    pulled = calibrate_user(replace(rec, segments=[], positions=held))
    for s in "lr":
        arm = pulled.bones[f"upperarm_{s}"].length + pulled.bones[f"forearm_{s}"].length
        assert abs(arm / true_arm - 1.0) < 0.12, (s, arm, true_arm)


def _over_reach_mm(user, pose, reach=1.0):
    over = []
    for s in "lr":
        arm = reach * (user.bones[f"upperarm_{s}"].length + user.bones[f"forearm_{s}"].length)
        d = np.linalg.norm(pose.joints[:, JI[f"wrist_{s}"]] - pose.joints[:, JI[f"shoulder_{s}"]], axis=1)
        over.append(np.maximum(d - arm, 0.0))
    return np.concatenate(over) * 1000


def test_a_controller_beyond_the_arm_turns_its_shoulder_toward_it(monkeypatch):
    """A real Beat Saber replay (three points, no calibration steps): the player's controllers are
    beyond the arms of a rigid trunk on a third of the frames; the shoulder girdle turns each
    shoulder toward its hand (up to 25°) so the arms reach them, the
    shoulders as far from their middle as ever, and where the hands are within reach (and not
    nearer than the arm folds) the shoulders are the rigid trunk's to the bit."""
    from bodycal_addon.recording import io as recording_io
    from bodycal_addon.retarget import user_animation as ua

    rec = recording_io.load_recording(paths.data_dir() / "real_vr" / "beat_saber" / "simsaber_sample.bsor")
    user = calibrate_user(rec)
    full = lower_body.complete(rec, user)
    pose = animate_user(full, user)
    monkeypatch.setattr(ua, "SHOULDER_REACH", 0.0)
    rigid = animate_user(full, user)
    before, after = _over_reach_mm(user, rigid), _over_reach_mm(user, pose)
    assert np.percentile(before, 95) > 30.0 and (before > 5.0).mean() > 0.2
    assert np.percentile(after, 95) <= 5.0 and (after > 5.0).mean() < 0.03
    J, R = pose.joints, rigid.joints
    rmid = 0.5 * (R[:, JI["shoulder_l"]] + R[:, JI["shoulder_r"]])
    inside = (_over_reach_mm(user, rigid, ua.ARM_REACH).reshape(2, -1) == 0).all(axis=0)
    animator = ua.UserAnimator(full, user)
    for s in "lr":  # nor nearer than the arm folds (test_folded_arm.py)
        d = np.linalg.norm(rigid.joints[:, JI[f"wrist_{s}"]] - rigid.joints[:, JI[f"shoulder_{s}"]], axis=1)
        inside &= d >= animator._fold_distance(s)
    for s in "lr":
        row = JI[f"shoulder_{s}"]
        half = np.linalg.norm(R[:, row] - rmid, axis=1)
        moved = ~np.all(J[:, row] == R[:, row], axis=1)
        # turned about the rigid shoulders' middle: as far from it as before
        assert np.allclose(np.linalg.norm(J[moved, row] - rmid[moved], axis=1), half[moved], atol=1e-9)
        assert np.array_equal(J[inside, row], R[inside, row])


@pytest.mark.parametrize("take", ["aframe_vive/grabRight.json", "beat_saber/xror_sample2.bsor"])
def test_without_a_t_pose_the_controller_lies_along_the_hand_that_holds_it(take):
    """Real takes, no calibration step: the wrist is put in from the controller's grip (the fist's
    centre, along the hand), so the hand points from the wrist to the controller all along, as
    the avatar's hand holds its controller (retarget/offsets.controller_in_hand: along the hand,
    under the palm). A hand hanging down across the controller turned every avatar's hand 60-90°
    on it and, with Exact Offsets, swung the avatar's wrist about the controller on the wrong side
    (its acceleration 1.7x the player's on the Beat Saber replay)."""
    from bodycal_addon.body.skeleton import BONE_INDEX as BI
    from bodycal_addon.recording import io as recording_io

    rec = recording_io.load_recording(paths.data_dir() / "real_vr" / take)
    user = calibrate_user(rec)
    assert user.calibration["reference"] == "standing moment"
    pose = animate_user(lower_body.complete(rec, user), user)
    roles = [d.role for d in rec.devices]
    for s in "lr":
        grip = rec.positions[:, roles.index(f"hand_{s}")]
        to_grip = tf.normalize(grip - pose.joints[:, JI[f"wrist_{s}"]])
        along = pose.frames[:, BI[f"hand_{s}"]][:, :, 1]  # a bone's Y runs along it
        angle = np.degrees(np.arccos(np.clip((to_grip * along).sum(axis=1), -1.0, 1.0)))
        assert np.percentile(angle, 95) < 10.0, (s, np.percentile(angle, [50, 95]))


# --- a kneel steps its feet into place: no planted foot slides --------------------------------------

ON_FLOOR_M = 0.002  # an ankle this close to its lowest height stands on the floor (a lifted swing clears it)


def _floor_slide_mps(ankles: np.ndarray, balls: np.ndarray, fps: float) -> float:
    """The fastest a foot moves over the floor between two frames its ankle (F, 3) stands on the
    floor (within `ON_FLOOR_M` of its lowest): the slower of its ankle and its ball (F, 3), so a
    heel rising about the ball (heel.py) is not a slide, a foot moving along the floor is."""
    on = ankles[:, 2] < ankles[:, 2].min() + ON_FLOOR_M
    both = on[1:] & on[:-1]
    v = np.minimum(*(np.linalg.norm(np.diff(p[:, :2], axis=0), axis=1) for p in (ankles, balls))) * fps
    return float(v[both].max()) if both.any() else 0.0


def _accel(x: np.ndarray, fps: float) -> np.ndarray:
    return np.linalg.norm(np.diff(x, 2, axis=0), axis=1) * fps * fps


def _kneel_heights(user, n=540):
    """Head heights: standing, down into a kneel (the pelvis at its lowest) held, and up again."""
    z0 = user.extra["tpose"]["head"][2]
    u = np.clip(np.sin(np.pi * np.arange(n) / n) * 1.6, 0, 1)
    return z0 - (z0 - 0.6) * u * u * (3 - 2 * u)


def test_a_kneel_steps_the_feet_into_place_and_never_slides_a_planted_foot(user):
    """Going down onto one knee and up again the feet lift, move and plant (as steps do): no foot
    moves over the floor while on it, and no ankle jerks (issue 39: the knee's foot used to slide
    back with the pelvis's height and turn back within 40 ms)."""
    take = _head_take(user, _kneel_heights(user))
    full = lower_body.complete(take, user)
    pose = animate_user(full, user)
    shape = lower_body.LowerBodyShape.of(user)
    low = int(np.argmin(pose.joints[:, JI["pelvis"], 2]))
    knees = pose.joints[low, [JI["knee_l"], JI["knee_r"]], 2]
    assert knees.min() < 0.12 and knees.max() > 0.25  # one knee down, the other up
    for s in "lr":
        ankle = pose.joints[:, JI[f"ankle_{s}"]]
        assert _floor_slide_mps(ankle, pose.joints[:, JI[f"toe_{s}"]], FPS) < 0.05, s
        # a swing's own (min-jerk over a stride within a leg, in a swing of at least SHORTEST_SWING_S)
        assert _accel(ankle, FPS).max() < 5.8 * shape.leg / stepping.SHORTEST_SWING_S ** 2, s
    # the stream (forward only) kneels the same way
    live = lower_body.LiveLowerBody(user, ("pelvis", "foot_l", "foot_r"), FPS)
    streamed = [live.frame(t, p[0], tf.quat_to_matrix(q[0])) for t, p, q in zip(take.time, take.positions,
                                                                                take.rotations)]
    poses = {r: (np.array([f[r][0] for f in streamed]), np.array([f[r][1] for f in streamed])) for r in streamed[0]}
    pose = animate_user(lower_body.with_devices(take, tuple(poses), poses, "streamed"), user)
    for s in "lr":
        assert _floor_slide_mps(pose.joints[:, JI[f"ankle_{s}"]], pose.joints[:, JI[f"toe_{s}"]], FPS) < 0.05, s


def test_standing_up_from_a_kneel_steps_both_feet_back_under_the_body(user):
    """Up from a kneel and standing still, the feet stand under the body again, where they stood
    before it (before: a foot stood where the kneel put it until some other step came, here 13 cm
    from its place at the end; on the synthetic performer's contact take, once the support reached
    back to the ankles, the front foot 22 cm ahead for 48 s)."""
    z0 = user.extra["tpose"]["head"][2]
    heights = np.concatenate([_kneel_heights(user), np.full(270, z0)])
    full = lower_body.complete(_head_take(user, heights), user)
    feet = _feet(full)
    for s in (0, 1):
        assert np.linalg.norm(feet[-1, s, :2] - feet[0, s, :2]) < 0.02, "lr"[s]


def test_the_real_kneel_plants_its_feet(tmp_path):
    """The real A-Frame take `tracked` kneels on its left knee (frames 2280-2330): the feet the
    user sees (the user animation's ankles, the default smoothing) never slide over the floor and
    their acceleration stays a step's (the old blend: 545 m/s^2 at frame 2299, back and forth)."""
    from bodycal_addon.recording import io as recording_io
    from bodycal_addon.recording.filters import DEFAULT_FILTER, filter_recording

    rec = recording_io.load_recording(paths.data_dir() / "real_vr" / "aframe_vive" / "tracked-recording.json")
    user = calibrate_user(rec)
    full = lower_body.complete(filter_recording(rec, DEFAULT_FILTER), user)
    pose = animate_user(full, user)
    shape = lower_body.LowerBodyShape.of(user)
    fps = rec.fps
    assert kneel.kneel_weight(shape, pose.joints[2280:2400, JI["pelvis"], 2]).max() == pytest.approx(1.0)
    for s in "lr":
        ankle = pose.joints[:, JI[f"ankle_{s}"]]
        assert _floor_slide_mps(ankle, pose.joints[:, JI[f"toe_{s}"]], fps) < 0.05, s
        assert _accel(ankle[2200:2500], fps).max() < 5.8 * shape.leg / stepping.SHORTEST_SWING_S ** 2, s
