"""The synthetic performer is the ground truth of every calibration and retargeting test, so its
own geometry is checked here against first principles: rigid bones, hinges, touches on the true
surface, diametric pairs, contacts, planted feet, noise levels and reproducibility."""

from __future__ import annotations

import json

import numpy as np
import pytest

from bodycal_addon.body import skeleton as sk
from bodycal_addon.body import surface_layout as sl
from bodycal_addon.body.bodymodel import BodyModel
from bodycal_addon.core.transforms import quat_to_matrix
from bodycal_dev import synthetic as sy

FPS = 45.0
TOUCHES = ["elbow_in_l", "elbow_out_l", "wrist_top_r", "wrist_bottom_r", "mcp_index_r", "knee_in_r", "knee_out_r",
           "ankle_in_l", "ankle_out_l", "sole_1_l", "sole_2_l", "sole_3_l", "sole_4_l", "skull_top", "chin",
           "shoulder_front_r", "shoulder_back_r", "belly_c1", "back_ul", "palm_1_l"]


@pytest.fixture(scope="module")
def perf():
    return sy.make_performer(seed=3)


@pytest.fixture(scope="module")
def clean(perf):
    """Noise-free, wobble-free session with a subset of touches and every motion."""
    return sy.record_session(perf, fps=FPS, noise_mm=0.0, wobble_mm=0.0, touch_points=TOUCHES, seed=1)


def _dev(truth, role, frames):
    d = truth.roles.index(role)
    return truth.device_positions[frames, d], quat_to_matrix(truth.device_rotations[frames, d])


def _to_local(pos, rot, world):
    return np.einsum("...ji,...j->...i", rot, world - pos)


def _jt(truth, name):
    return truth.joint_tracks[name]


def test_bone_lengths_constant_and_match_the_performer(perf, clean):
    _, truth = clean
    for i, b in enumerate(sk.BONES):
        if b.name.startswith("shortcut_"):  # spans flexing vertebrae: not rigid
            continue
        L = np.linalg.norm(_jt(truth, b.tail) - _jt(truth, b.head), axis=-1)
        assert np.ptp(L) < 1e-9, b.name
        assert L[0] == pytest.approx(perf.length[i], abs=1e-9)
    # Proportions from the height (Winter's anthropometry): a 1.75 m performer.
    J = truth.joints_world
    assert np.linalg.norm(J["elbow_l"] - J["shoulder_l"]) == pytest.approx(0.186 * 1.75, abs=1e-9)
    assert np.linalg.norm(J["knee_r"] - J["hip_r"]) == pytest.approx(0.245 * 1.75, abs=1e-9)
    assert J["hip_l"][0] > 0 > J["hip_r"][0]  # left at +X
    assert J["ankle_l"][2] == pytest.approx(0.045 * 1.75, abs=1e-9)
    assert truth.body_model().extra["eye_height"] == pytest.approx(0.895 * 1.75 + 0.06, abs=1e-6)


def test_spine_has_twelve_equal_vertebrae_from_spine_root_to_skull_base(clean):
    _, truth = clean
    J = truth.joints_world
    pts = np.array([J[sk.spine_joint(k)] for k in range(13)])
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    assert np.ptp(seg) < 1e-9
    np.testing.assert_allclose(J["spine_12"], J["skull_base"], atol=1e-12)
    np.testing.assert_allclose(J["spine_root"] - J["pelvis"], [0.0, 0.05, 0.10], atol=1e-12)


def test_hinges_flex_only_about_their_right_axis(clean):
    """The upper bone stays perpendicular to the hinge axis carried by the lower bone's tracker."""
    _, truth = clean
    bm = truth.body_model()
    for bone, upper in (("forearm_l", ("shoulder_l", "elbow_l")), ("shin_r", ("hip_r", "knee_r"))):
        role = bm.bones[bone].extra["right_frame"]
        pos, rot = _dev(truth, role, slice(None))
        # The exact axis (the body model rounds to 1e-7).
        right = rot[truth.ref_frame].T @ truth.ref_bone_rot[sy._BONE_INDEX[bone]][:, 0]
        np.testing.assert_allclose(bm.bones[bone].extra["right_local"], right, atol=1e-6)
        d = _to_local(pos, rot, _jt(truth, upper[0])) - _to_local(pos, rot, _jt(truth, upper[1]))
        cos = d @ right / np.linalg.norm(d, axis=1)
        assert np.max(np.abs(cos)) < 1e-9, bone
        # ... and the flexion range of the flex step is large (calibration needs it).
    seg = next(s for s in truth.segments if s.step == "flex_elbow_l")
    f = (truth.time >= seg.start) & (truth.time <= seg.end)
    u = _jt(truth, "elbow_l")[f] - _jt(truth, "shoulder_l")[f]
    v = _jt(truth, "wrist_l")[f] - _jt(truth, "elbow_l")[f]
    ang = np.degrees(np.arccos(np.sum(u * v, 1) / np.linalg.norm(u, axis=1) / np.linalg.norm(v, axis=1)))
    assert ang.max() - ang.min() > 90
    assert f.sum() >= 150 * FPS / 90


def test_tracker_local_joints_are_constant_without_noise(clean):
    _, truth = clean
    for joint, role in (("elbow_l", "forearm_l"), ("elbow_l", "upperarm_l"), ("knee_r", "thigh_r"),
                        ("hip_l", "pelvis"), ("wrist_r", "hand_r"), ("ankle_l", "foot_l"), ("skull_base", "head"),
                        ("shoulder_r", "upperarm_r"), ("spine_root", "pelvis")):
        pos, rot = _dev(truth, role, slice(None))
        loc = _to_local(pos, rot, _jt(truth, joint))
        assert np.max(np.ptp(loc, axis=0)) < 1e-9, (joint, role)
        np.testing.assert_allclose(loc[truth.ref_frame], truth.body_model().joints[joint].frames[role], atol=1e-6)


def test_wobble_moves_trackers_by_about_wobble_mm(perf):
    rec, truth = sy.record_session(perf, fps=FPS, noise_mm=0.0, wobble_mm=4.0, calibration=["flex_elbow_l"],
                                   motions=("squat",), seed=2)
    pos, q, _ = rec.pose("forearm_l")
    loc = _to_local(pos, quat_to_matrix(q), _jt(truth, "elbow_l"))
    dev = np.linalg.norm(loc - loc.mean(0), axis=1)
    rms_mm = 1000 * np.sqrt(np.mean(dev ** 2))
    assert 12.0 > rms_mm > 1.5  # the elbow sits ~15 cm from the tracker: rotation wobble adds to 4 mm
    # Position wobble alone (the device origin against its true pose) has the requested RMS.
    d = truth.roles.index("forearm_l")
    err = np.linalg.norm(rec.positions[:, d] - truth.device_positions[:, d], axis=1)
    assert 1000 * np.sqrt(np.mean(err ** 2)) == pytest.approx(4.0, rel=0.5)


def test_touch_effectors_lie_on_the_true_surface(clean):
    rec, truth = clean
    bm = truth.body_model()
    for seg in rec.segments_of("touch"):
        frames, world = truth.touch_tracks[seg.point]
        if seg.by in rec.marker_names:
            eff = rec.marker(seg.by)[0][frames]
        else:  # palm centre: the hand device origin projected onto the palm plane
            role = f"hand_{seg.by[-1]}"
            pos, rot = _dev(truth, role, frames)
            eff = pos + np.einsum("nij,j->ni", rot, bm.extra["palm_planes"][role]["point"])
        assert np.max(np.linalg.norm(eff - world, axis=1)) < 1e-9, seg.point
        # The touch holds still for ~0.5 s.
        assert seg.end - seg.start >= 0.5
        assert np.max(np.ptp(world, axis=0)) < 1e-9
    assert truth.ik_miss < 1e-9
    assert {s.point for s in rec.segments_of("touch")} == set(TOUCHES)
    by = {s.point: s.by for s in rec.segments_of("touch")}
    assert by["elbow_in_l"] == "index_tip_r" and by["belly_c1"] == "palm_r" and by["back_ul"].startswith("palm_")


def test_touch_points_are_on_the_analytic_surface(perf, clean):
    _, truth = clean
    bm = truth.body_model()
    skull = bm.element("sphere:skull")
    _, local, _ = perf.surface_points["skull_top"]
    assert np.linalg.norm(local - skull.center) == pytest.approx(skull.radius, abs=1e-12)
    # Capsule points: at the bone's radius from its axis.
    for point, bone, radius in (("elbow_in_l", "forearm_l", "radius_head"), ("knee_out_r", "shin_r", "radius_head"),
                                ("shoulder_back_r", "upperarm_r", "radius_head")):
        b, local, _ = perf.surface_points[point]
        assert b == bone
        assert np.hypot(local[0], local[2]) == pytest.approx(getattr(bm.bones[bone], radius), abs=1e-12)
        assert local[1] == pytest.approx(0.0, abs=1e-12)
    # Torso points ride their nearest vertebra (surface_layout) and the belly bulges out of the
    # plane of its corners by about the performer's belly depth.
    torso = bm.element("mesh:torso")
    spine = np.array([truth.joints_world[sk.spine_joint(k)] for k in range(13)])
    for name, p in torso.points.items():
        w = truth.touch_world(name)
        assert sl.nearest_vertebra(w, spine) == p.bone, name


def test_diametric_touches_recover_joint_centres_and_radii(perf, clean):
    rec, truth = clean
    bm = truth.body_model()
    for a, b, joint, role, radius in (("elbow_in_l", "elbow_out_l", "elbow_l", "forearm_l", perf.radius["elbow_l"]),
                                      ("knee_in_r", "knee_out_r", "knee_r", "shin_r", perf.radius["knee_r"]),
                                      ("ankle_in_l", "ankle_out_l", "ankle_l", "foot_l", perf.radius["ankle_l"]),
                                      ("wrist_top_r", "wrist_bottom_r", "wrist_r", "hand_r", perf.radius["wrist_r"])):
        loc = []
        for p in (a, b):
            frames, _ = truth.touch_tracks[p]
            seg = next(s for s in rec.segments_of("touch") if s.point == p)
            pos, rot = _dev(truth, role, frames)
            loc.append(_to_local(pos, rot, rec.marker(seg.by)[0][frames]).mean(0))
        np.testing.assert_allclose((loc[0] + loc[1]) / 2, bm.joints[joint].frames[role], atol=1e-9)
        assert np.linalg.norm(loc[0] - loc[1]) / 2 == pytest.approx(radius, abs=1e-9)
    assert bm.bones["forearm_l"].radius_head == perf.radius["elbow_l"]


def test_mcp_touch_projected_on_palm_plane_recovers_the_joint(perf, clean):
    rec, truth = clean
    bm = truth.body_model()
    plane = bm.extra["palm_planes"]["hand_r"]
    pt, n = np.array(plane["point"]), np.array(plane["normal"])
    frames, _ = truth.touch_tracks["mcp_index_r"]
    pos, rot = _dev(truth, "hand_r", frames)
    touch = _to_local(pos, rot, rec.marker("index_tip_l")[0][frames]).mean(0)
    proj = touch - ((touch - pt) @ n) * n
    joint = proj - perf.radius["finger_index_r"] * n  # one finger radius toward the back of the hand
    np.testing.assert_allclose(joint, bm.joints["mcp_index_r"].frames["hand_r"], atol=1e-9)


def test_palms_together_leds_and_fingertips(perf, clean):
    rec, truth = clean
    bm = truth.body_model()
    seg = rec.segments_of("palms_together")[0]
    f = rec.frames(seg.start, seg.end)
    for s in sk.SIDES:
        role = f"hand_{s}"
        plane = bm.extra["palm_planes"][role]
        pt, n = np.array(plane["point"]), np.array(plane["normal"])
        pos, rot = _dev(truth, role, f)
        # Midpoints of opposite LEDs lie on each hand's palm plane (Delahaye 2023, appendix B, Hands).
        for k in (1, 2, 3):
            mid = 0.5 * (rec.marker(f"hand_led{k}_l")[0][f] + rec.marker(f"hand_led{k}_r")[0][f])
            assert np.max(np.abs((_to_local(pos, rot, mid) - pt) @ n)) < 1e-9
        # Extended fingertip LEDs: two finger radii from the palm plane, on the back side.
        for finger in sk.FINGERS:
            tip = _to_local(pos, rot, rec.marker(f"{finger}_tip_{s}")[0][f])
            np.testing.assert_allclose((tip - pt) @ n, -2 * perf.radius[f"finger_{finger}_{s}"], atol=1e-9)
        # The glove frame follows the LED rule: Z out of the back of the hand, so the palm normal is -Z.
        np.testing.assert_allclose(n, [0.0, 0.0, -1.0], atol=1e-9)


def test_contacts_hold_effectors_on_the_surface(clean):
    rec, truth = clean
    assert {c["motion"] for c in truth.contacts} == {"clap", "hand_on_belly", "hand_on_head", "hands_on_thighs"}
    for c in truth.contacts:
        eff, tgt = truth.contact_tracks[(c["effector"], c["target"])]
        f = c["frames"]
        assert f.sum() > 3
        assert np.max(np.linalg.norm(eff[f] - tgt[f], axis=1)) < 1e-3
        seg = next(s for s in rec.segments_of("motion") if s.point == c["motion"])
        assert seg.start <= c["start"] <= c["end"] <= seg.end
    belly = next(c for c in truth.contacts if c["motion"] == "hand_on_belly")
    assert belly["end"] - belly["start"] > 2.0


def test_feet_on_the_floor_when_planted(clean):
    _, truth = clean
    for s in sk.SIDES:
        planted = truth.planted[f"foot_{s}"]
        assert 0.3 < planted.mean() < 1.0
        pos, rot = _dev(truth, f"foot_{s}", slice(None))
        pos_r, rot_r = _dev(truth, f"foot_{s}", truth.ref_frame)
        soles = np.array([truth.touch_world(n) for n in sl.sole_points(4, s)])
        local = _to_local(pos_r, rot_r, soles)
        world = pos[:, None] + np.einsum("nij,kj->nki", rot, local)
        assert np.max(np.abs(world[planted, :, 2])) < 1e-9
        assert np.max(np.ptp(world[planted], axis=0)) < 1e-9  # not sliding
        assert np.max(world[~planted, :, 2].max(axis=1)) > 0.05  # lifted in walk_in_place / flex / swing


def test_reproducible_with_a_seed_and_different_across_seeds(perf):
    kw = dict(fps=30.0, calibration=["stand"], motions=("squat",), dropout_rate=0.02, outlier_rate=0.05)
    a, _ = sy.record_session(perf, seed=5, **kw)
    b, _ = sy.record_session(perf, seed=5, **kw)
    c, _ = sy.record_session(perf, seed=6, **kw)
    np.testing.assert_array_equal(a.positions, b.positions)
    np.testing.assert_array_equal(a.markers, b.markers)
    np.testing.assert_array_equal(a.valid, b.valid)
    assert not np.allclose(a.positions, c.positions)
    # The performer's seed fixes the tracker mounting.
    p2 = sy.make_performer(seed=4)
    assert not np.allclose(p2.mounts["thigh_l"][1], perf.mounts["thigh_l"][1])


def test_noise_dropouts_and_outliers(perf):
    rec, truth = sy.record_session(perf, fps=60.0, noise_mm=2.0, wobble_mm=0.0, dropout_rate=0.05,
                                   outlier_rate=0.1, calibration=["stand"], motions=("arm_raise",), seed=9)
    for arr in (rec.positions, rec.rotations, rec.markers):
        assert np.all(np.isfinite(arr))
    np.testing.assert_allclose(np.linalg.norm(rec.rotations, axis=-1), 1.0, atol=1e-9)
    assert 0.02 < 1 - rec.valid.mean() < 0.10
    assert 0.02 < 1 - rec.marker_valid.mean() < 0.10
    d = truth.roles.index("shin_l")
    ok = rec.valid[:, d]
    err = np.linalg.norm(rec.positions[ok, d] - truth.device_positions[ok, d], axis=1)
    jumps = err > 0.025
    assert 0.06 < jumps.mean() < 0.14  # the outlier frames (several cm)
    assert 1000 * np.sqrt(np.mean(err[~jumps] ** 2)) == pytest.approx(2.0 * np.sqrt(3), rel=0.15)
    # Dropped frames hold the last tracked value.
    f = np.flatnonzero(~ok)
    f = f[f > 0]
    np.testing.assert_array_equal(rec.positions[f, d], rec.positions[f - 1, d])


def test_minimal_profile_devices_and_controller_touches():
    perf = sy.make_performer(build="thin", seed=2)
    rec, truth = sy.record_session(perf, profile="minimal", fps=30.0, noise_mm=0.0, wobble_mm=0.0,
                                   touch_points=["elbow_in_r", "sole_2_r", "sternum"], motions=("clap",))
    kinds = sorted(d.kind for d in rec.devices)
    assert kinds == ["controller", "controller", "hmd", "tracker", "tracker", "tracker"]
    assert sorted(d.role for d in rec.devices if d.kind == "tracker") == ["foot_l", "foot_r", "pelvis"]
    assert rec.marker_names == ["controller_tip_l", "controller_tip_r"]
    assert not rec.segments_of("palms_together") and not rec.segments_of("flex_elbow_l")
    for seg in rec.segments_of("touch"):
        assert seg.by.startswith("controller_tip_")
        frames, world = truth.touch_tracks[seg.point]
        assert np.max(np.linalg.norm(rec.marker(seg.by)[0][frames] - world, axis=1)) < 1e-9
        pos, q, _ = rec.pose(f"hand_{seg.by[-1]}")
        tip = pos[frames] + np.einsum("nij,j->ni", quat_to_matrix(q[frames]), sy.CONTROLLER_TIP_LOCAL)
        np.testing.assert_allclose(tip, world, atol=1e-9)
    bm = truth.body_model()
    assert bm.joints["hip_l"].frames.keys() == {"pelvis"}
    assert bm.joints["wrist_r"].frame == "hand_r"
    assert bm.bones["forearm_l"].extra["right_frame"] == "hand_l"


def test_builds_differ_as_specified():
    avg = sy.make_performer()
    child = sy.make_performer(build="child")
    heavy = sy.make_performer(build="heavy")
    long_arms = sy.make_performer(build="long_arms")
    tall = sy.make_performer(build="tall")
    thin = sy.make_performer(build="thin")

    def arm(p):
        return sum(p.length[sy._BONE_INDEX[b]] for b in ("upperarm_l", "forearm_l"))

    def belly_depth(p):
        return -p.rest_rot[sy._BONE_INDEX[p.surface_points["belly_c2"][0]]].dot(p.surface_points["belly_c2"][1])[1]

    assert child.rest["head"][2] < avg.rest["head"][2] < tall.rest["head"][2]
    assert heavy.belly > avg.belly > thin.belly
    assert heavy.radius["knee_l"] > avg.radius["knee_l"] > thin.radius["knee_l"]
    assert arm(long_arms) > 1.1 * arm(avg)
    assert long_arms.rest["head"][2] == pytest.approx(avg.rest["head"][2])
    # The belly surface of the heavy build sticks out further in front of the spine.
    assert belly_depth(heavy) > belly_depth(avg) + 0.05
    # Overrides fine-tune one parameter.
    p = sy.make_performer(belly=0.08, upperarm_radius=0.05)
    assert p.belly == 0.08 and p.bone_radii("upperarm_r") == (0.05, 0.05)
    with pytest.raises(sy.BodyCalError):
        sy.make_performer(wings=2.0)


def test_body_model_is_consistent_and_round_trips(tmp_path, clean):
    rec, truth = clean
    bm = truth.body_model()
    tpose = bm.extra["tpose"]
    for name, joint in bm.joints.items():
        np.testing.assert_allclose(joint.world, truth.joints_world[name], atol=1e-12)
        for role, local in joint.frames.items():
            p = np.array(tpose[role][:3])
            R = quat_to_matrix(np.array(tpose[role][3:]))
            np.testing.assert_allclose(p + R @ local, joint.world, atol=1e-6)
    ids = {e.id for e in bm.surface}
    assert ids == set(sl.element_ids())
    for e in bm.surface:
        if e.type == "mesh":
            assert len(e.points) >= 3
    seg = rec.segments_of("tpose")[0]
    assert bm.reference_time == pytest.approx(0.5 * (seg.start + seg.end), abs=1 / FPS)
    loaded = BodyModel.load(bm.save(tmp_path / "truth.body.json"))
    np.testing.assert_allclose(loaded.joints["knee_l"].frames["shin_l"], bm.joints["knee_l"].frames["shin_l"],
                               atol=1e-6)
    path = truth.save(tmp_path / "x.truth.json")
    data = json.loads(path.read_text())
    assert data["reference_time"] == truth.reference_time
    assert data["contacts"][0]["frames"][0][0] >= 0


@pytest.mark.slow
def test_session_has_the_whole_protocol(perf):
    """Every calibration step of FORMATS.md §2.4 and every touch point the full profile allows."""
    rec, truth = sy.record_session(perf, fps=20.0, noise_mm=0.5, wobble_mm=1.0, motions=("walk_in_place",))
    steps = {s.step for s in rec.segments}
    assert steps == set(sy._calibration_steps("full", True)) | {"motion"}
    assert {s.point for s in rec.segments_of("touch")} == set(sy.calibration_touch_points("full"))
    assert truth.ik_miss < 1e-9
    for arr in (rec.positions, rec.rotations, rec.markers, truth.joints):
        assert np.all(np.isfinite(arr))


def test_write_session_round_trips_through_the_reader(tmp_path, perf):
    from bodycal_addon.recording import io as recording_io

    rec, truth = sy.record_session(perf, fps=30.0, calibration=["stand"], touch_points=None, motions=("clap",),
                                   dropout_rate=0.02, seed=4)
    rec_path, truth_path = sy.write_session(tmp_path, "s", rec, truth)
    assert rec_path.name == "s.bcrec.json" and truth_path.name == "s.truth.json"
    back = recording_io.load_recording(rec_path, fill_gaps_s=0.0)
    np.testing.assert_allclose(back.time, rec.time, atol=1e-8)
    np.testing.assert_array_equal(back.valid, rec.valid)
    ok = rec.valid
    np.testing.assert_allclose(back.positions[ok], rec.positions[ok], atol=1e-6)
    np.testing.assert_allclose(back.markers[rec.marker_valid], rec.markers[rec.marker_valid], atol=1e-6)
    assert [(s.step, s.point) for s in back.segments] == [(s.step, s.point) for s in rec.segments]
    assert {d.role for d in back.devices} == set(sy.FULL_ROLES)
    data = json.loads(truth_path.read_text())
    assert data["body_model"]["kind"] == "user" and data["generator"]["seed"] == 4


def test_noise_free_recording_equals_the_true_device_poses(clean):
    """Gloves are rebuilt from their LEDs with the synthetic API rule: without noise they are the
    true hand frames, like every other device."""
    rec, truth = clean
    np.testing.assert_allclose(rec.positions, truth.device_positions, atol=1e-9)
    dots = np.abs(np.sum(rec.rotations * truth.device_rotations, axis=-1))
    assert np.min(dots) > 1 - 1e-12
    for s in sk.SIDES:  # Z of the LED frame out of the back of the hand: away from the palm centre
        pos, rot = _dev(truth, f"hand_{s}", truth.ref_frame)
        plane = truth.body_model().extra["palm_planes"][f"hand_{s}"]
        assert np.dot(plane["normal"], [0, 0, 1]) < -0.99
        led = [rec.marker(f"hand_led{k}_{s}")[0][truth.ref_frame] for k in (1, 2, 3)]
        assert np.dot(np.cross(led[1] - led[0], led[2] - led[0]), rot[:, 2]) > 0


@pytest.mark.slow
@pytest.mark.parametrize("build,profile", [("child", "full"), ("tall", "full"), ("long_arms", "full"),
                                           ("heavy", "minimal"), ("thin", "minimal"), ("child", "minimal")])
def test_every_build_reaches_every_touch_above_the_floor(build, profile):
    perf = sy.make_performer(build=build, seed=1)
    rec, truth = sy.record_session(perf, profile=profile, fps=10.0, noise_mm=0.0, wobble_mm=0.0,
                                   motions=sy.MOTIONS)
    assert truth.ik_miss < 1e-9
    # Nothing below the floor during any step or motion (between steps, a hand sweeping from one
    # deep-crouch touch to the next is lifted by IK; at this low frame rate a few mm may remain).
    for seg in rec.segments:
        f = rec.frames(seg.start, seg.end)
        assert truth.joints[f, :, 2].min() > -1e-9, seg.label
    assert truth.joints[..., 2].min() > -0.03
    assert {s.point for s in rec.segments_of("touch")} == set(sy.calibration_touch_points(profile))
    for seg in rec.segments_of("touch"):
        frames, world = truth.touch_tracks[seg.point]
        if seg.by in rec.marker_names:
            assert np.max(np.linalg.norm(rec.marker(seg.by)[0][frames] - world, axis=1)) < 1e-9, seg.point


def test_mesh_triangles_are_wound_outward(clean):
    _, truth = clean
    bm = truth.body_model()
    J = truth.joints_world

    def normals(element):
        out = []
        for a, b, c in element.triangles:
            pa, pb, pc = (truth.touch_world(k) for k in (a, b, c))
            out.append((np.cross(pb - pa, pc - pa), (pa + pb + pc) / 3))
        return out

    for s in sk.SIDES:
        palm_n = truth.ref_bone_rot[sy._BONE_INDEX[f"hand_{s}"]][:, 2]  # out of the palm
        assert all(n @ palm_n > 0 for n, _ in normals(bm.element(f"mesh:palm_{s}")))
        assert all(n[2] < 0 for n, _ in normals(bm.element(f"mesh:sole_{s}")))
    axis = J["skull_base"] - J["spine_root"]
    for n, c in normals(bm.element("mesh:torso")):
        r = c - J["spine_root"]
        r -= (r @ axis) / (axis @ axis) * axis
        assert n @ r > 0  # away from the spine
    head = truth.touch_world("skull_top") - np.array([0, 0, truth.performer.skull_radius])
    assert all(n @ (c - head) > 0 for n, c in normals(bm.element("mesh:jaw")))


def test_touch_markers_are_on_the_surface_within_noise(perf):
    rec, truth = sy.record_session(perf, fps=FPS, noise_mm=1.0, wobble_mm=3.0, calibration=["touch"],
                                   touch_points=["knee_out_l", "jaw_r", "wrist_top_l"], motions=(), seed=8)
    for seg in rec.segments_of("touch"):
        frames, world = truth.touch_tracks[seg.point]
        d = rec.marker(seg.by)[0][frames] - world
        rms_mm = 1000 * np.sqrt(np.mean(np.sum(d * d, axis=1)))
        assert rms_mm == pytest.approx(np.sqrt(3.0), rel=0.5), seg.point  # white noise only: LEDs on the nail
        assert 1000 * np.linalg.norm(d.mean(0)) < 1.0


@pytest.mark.parametrize("kw", [dict(profile="vr"), dict(noise_mm=-1.0), dict(dropout_rate=0.9), dict(fps=0.0),
                                dict(motions=("dance",)), dict(touch_points=["nose"]), dict(calibration=["yoga"])])
def test_bad_arguments_raise_one_clear_error(perf, kw):
    with pytest.raises(sy.BodyCalError):
        sy.record_session(perf, **kw)
