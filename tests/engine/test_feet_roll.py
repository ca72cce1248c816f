"""The rolling plant (feet.py, DESIGN.md §6 "Feet") on motion the synthetic performer did not make:
CMU 131_01 (start, walk, stop) recorded through `evaluation/` (trackers at random angles, noise,
soft tissue), calibrated and retargeted with every method; the avatar's heel and ball contact
points (FK of its foot) judged against the clip's own heel (ankle joint) and ball (toe joint)."""

from __future__ import annotations

import numpy as np
import pytest
from outside_takes import clip_performer, outside_recording

from bodycal_addon.avatar import foot_contact
from bodycal_addon.body.rest_frames import complete_joints
from bodycal_addon.body.skeleton import BONE_INDEX as BI
from bodycal_addon.body.skeleton import JOINT_INDEX as JI
from bodycal_addon.calibration import calibrate_user
from bodycal_addon.output import metrics
from bodycal_addon.recording.filters import OneEuro, filter_recording
from bodycal_addon.retarget import feet, offsets
from bodycal_addon.retarget import pipeline as pl
from bodycal_addon.retarget.avatar_pose import AvatarRig
from bodycal_addon.retarget.solver_methods import surface_correction
from bodycal_dev import retarget_fixtures as rt

STOP = "131_01_start_walk_stop.bvh"
DANCE = "05_06_dance.bvh"
FPS = 90.0


def test_contact_points_of_a_foot_shaped_underside():
    """Hits under a foot whose heel is round and whose toes curl up: the heel is the rearmost of the
    lowest, the ball the lowest under the toe joint, and the support keeps the heel's back and the
    toes' tip (what touches the floor when the foot pitches)."""
    f, lat, up = np.eye(3)[1], np.eye(3)[0], np.eye(3)[2]
    ankle, toe = np.array([0.0, 0.0, 0.08]), np.array([0.0, 0.15, 0.02])
    x = np.linspace(-0.06, 0.25, 32)
    z = np.where(x < 0.0, 0.3 * x * x / 0.06, 0.0) + np.where(x > 0.17, 0.4 * (x - 0.17), 0.0)  # heel round, toes up
    hits = np.stack([np.zeros_like(x), x, z], axis=1)
    got = foot_contact.contact_points(hits, ankle, toe, 0.0, f, lat, up)
    low = hits[hits[:, 2] <= foot_contact.LOW_BAND]
    assert got["heel"][1] == pytest.approx(low[:, 1].min())
    assert got["ball"][1] == pytest.approx(x[np.argmin(np.abs(x - 0.15))])
    ys = got["support"][:, 1]
    assert ys.min() == pytest.approx(x[0]) and ys.max() == pytest.approx(x[-1])
    assert foot_contact.contact_points(hits[:3], ankle, toe, 0.0, f, lat, up) is None  # too few: not measured


def test_the_heel_s_back_supports_a_foot_pitched_far_toes_up():
    """Hits on the heel's back (the rays cast forward at it, `back_origins`) join the support where
    they are the lowest for a pitch up to 90 degrees toes up, and change neither the heel nor the
    ball; without them the support is the underside's alone."""
    f, lat, up = np.eye(3)[1], np.eye(3)[0], np.eye(3)[2]
    ankle, toe = np.array([0.0, 0.0, 0.08]), np.array([0.0, 0.15, 0.02])
    x = np.linspace(-0.05, 0.2, 26)
    under = np.stack([np.zeros_like(x), x, np.where(x < 0.0, 0.3 * x * x / 0.05, 0.0)], axis=1)
    origins, reach = foot_contact.back_origins(ankle, toe, 0.0, f, lat, up)
    assert len(origins) == foot_contact.BACK_RAYS and np.all(origins @ f < ankle @ f) and reach > 0
    back = np.array([[0.0, -0.065, 0.03], [0.0, -0.06, 0.045], [np.nan] * 3])  # its back bulges behind the sole
    plain = foot_contact.contact_points(under, ankle, toe, 0.0, f, lat, up)
    got = foot_contact.contact_points(under, ankle, toe, 0.0, f, lat, up, back=back)
    assert np.array_equal(got["heel"], plain["heel"]) and np.array_equal(got["ball"], plain["ball"])
    assert any(np.allclose(p, back[0]) for p in got["support"])
    assert not any(np.allclose(p, back[0]) for p in plain["support"])


def test_rolling_pivots_about_the_point_that_is_down():
    """Heel down only: the ball's share is 0; ball only: 1; both: between; the weight eases around
    the contact; the foot stands with the pinned contact point on the floor; the share changes
    smoothly (no step larger than an easing's)."""
    F, n = 80, 6
    heel = feet.eased((np.arange(F) >= 10) & (np.arange(F) < 40), n)
    ball = feet.eased((np.arange(F) >= 25) & (np.arange(F) < 60), n)
    heel_at, ball_at = np.tile([0.1, 0.0], (F, 1)), np.tile([0.1, 0.15], (F, 1))
    weight, share, h_at, b_at = feet.rolling(heel, ball, n, heel_at, ball_at)
    assert weight[10:60].min() == 1.0 and weight[:10 - n].max() == 0.0 and weight[60 + n:].max() == 0.0
    assert share[15] < 0.1 and abs(share[32] - 0.5) < 0.01 and share[50] > 0.9
    assert np.abs(np.diff(share)).max() < 0.35
    frames = np.repeat(np.eye(3)[None], F, axis=0)
    contact = feet.Contact(np.array([0.0, -0.03, -0.08]), np.array([0.0, 0.12, -0.08]),
                           np.array([[0.0, -0.03, -0.08], [0.0, 0.12, -0.08], [0.0, 0.18, -0.07]]))
    out = feet.roll(np.tile([0.5, 0.5, 0.5], (F, 1)), h_at, b_at, weight, share, frames, contact)
    assert np.allclose(out[32, :2], [0.1, 0.03]) and abs(out[32, 2] - 0.08) < contact.floor_blend
    assert np.allclose(out[0], [0.5, 0.5, 0.5])


def test_a_foot_turning_in_place_stands_on_its_heel():
    """`with_pivots`: an ankle stance that neither the heel nor the ball shares (the foot turns in
    place) becomes the heel's; one that overlaps either changes nothing."""
    F, n = 120, 6
    frames = np.arange(F)
    heel = feet.eased((frames >= 10) & (frames < 30), n)
    ball = feet.eased((frames >= 25) & (frames < 40), n)
    alone = feet.eased((frames >= 70) & (frames < 95), n)
    overlapping = feet.eased((frames >= 35) & (frames < 50), n)
    got = feet.with_pivots(heel, ball, alone, n)
    assert np.array_equal(got.weight >= 1.0, (heel.weight >= 1.0) | (alone.weight >= 1.0)) and got.count == 2
    assert feet.with_pivots(heel, ball, overlapping, n) is heel


@pytest.fixture(scope="module")
def dance(data_dir, tmp_path_factory):
    rec, cap = outside_recording(clip_performer(data_dir, DANCE, "cmu_bvh_held_out"), tmp_path_factory.mktemp("pivot"),
                                 "full", seed=0)
    return rec, calibrate_user(rec), cap.truth()


@pytest.mark.parametrize("method", ["egocentric", "rotations"])
def test_a_dancer_s_foot_turning_on_its_ankle_stays_planted(dance, method):
    """CMU 05_06 (the held-out dance), the right foot: for a quarter of a second (the clip's frames
    154-176 at 90 Hz) it turns about its ankle, which stays low and slower than 0.2 m/s, while its
    heel and ball points, 9-10 cm from the ankle, move at 0.25-0.6 m/s: neither had a stance, so the
    foot followed the method (the heel slid 1.65-1.90x the clip's ankle). Planted on the ankle's
    own stance (`feet.with_pivots`), the heel's slide (p95 over the clip's heel-down frames) is
    within 1.5x the clip's ankle's, scaled like the legs; now 0.71-0.74x."""
    rec, user, truth = dance
    avatar = _avatar_with_contacts()
    rig = AvatarRig.from_model(avatar)
    anim = pl.retarget(filter_recording(rec, OneEuro()), user, avatar, method, placement="performer")
    pose = rig.fk(anim.rotations, anim.root_location)
    corr = surface_correction(avatar, rig.frames0, complete_joints(avatar))
    a, b = truth["motion"]
    J = {n: i for i, n in enumerate(truth["joints"])}
    T = truth["positions"]
    at_ref = dict(zip(truth["joints"], T[int(round(user.reference_time * FPS))]))
    heel_local = np.asarray(avatar.element("mesh:sole_r").extra["contact"]["heel"])
    frame = pose.frames[a:b, BI["foot_r"]] @ corr[BI["foot_r"]]
    heel = pose.joints[a:b, JI["ankle_r"]] + np.einsum("fij,j->fi", frame, heel_local)
    down = metrics.ground_contact(T[a:b, J["ankle_r"]], FPS)
    clip = metrics.slide_p95_mm(T[a:b, J["ankle_r"]], down, FPS) * metrics.limb_ratios(rig, at_ref)["ankle"]
    assert metrics.slide_p95_mm(heel, down, FPS) <= 1.5 * clip, (method, metrics.slide_p95_mm(heel, down, FPS) / clip)


@pytest.fixture(scope="module")
def walk(data_dir, tmp_path_factory):
    rec, cap = outside_recording(clip_performer(data_dir, STOP), tmp_path_factory.mktemp("roll"), "full", seed=1,
                                 up="Z")
    return rec, calibrate_user(rec), cap.truth()


def _avatar_with_contacts():
    """The procedural avatar, its sole's contact points given as the calibration measures them:
    the outline's rearmost point (heel), its point nearest the toe joint (ball), the outline as
    support."""
    avatar = rt.procedural_avatar()
    for s in "lr":
        el = avatar.element(f"mesh:sole_{s}")
        local = np.array([v.local for v in el.points.values()], float)
        ankle, toe = (np.asarray(avatar.joints[f"{j}_{s}"].world, float) for j in ("ankle", "toe"))
        world = ankle + local @ _rest_frame(avatar, s).T
        heel = local[np.argmin(world @ (toe - ankle))]
        ball = local[np.argmin(np.linalg.norm((world - toe)[:, :2], axis=1))]
        el.extra["contact"] = {"heel": heel.tolist(), "ball": ball.tolist(), "support": local.tolist()}
    return avatar


def _rest_frame(avatar, s):
    """The avatar's foot frame its surface points are local to (the canonical one, corrected)."""
    rig = AvatarRig.from_model(avatar)
    corr = surface_correction(avatar, rig.frames0, complete_joints(avatar))
    return rig.frames0[BI[f"foot_{s}"]] @ corr[BI[f"foot_{s}"]]


@pytest.mark.parametrize("method", pl.METHODS)
def test_heel_and_ball_planted_on_the_floor_on_a_real_walk(walk, method):
    rec, user, truth = walk
    avatar = _avatar_with_contacts()
    anim = pl.retarget(rec, user, avatar, method, placement="performer")
    assert not any("contact points were not measured" in n for n in anim.notes)
    rig = AvatarRig.from_model(avatar)
    pose = rig.fk(anim.rotations, anim.root_location)
    corr = surface_correction(avatar, rig.frames0, complete_joints(avatar))
    a, b = truth["motion"]
    J = {n: i for i, n in enumerate(truth["joints"])}
    T = truth["positions"][a:b]
    for s in "lr":
        c = avatar.element(f"mesh:sole_{s}").extra["contact"]
        frame = pose.frames[a:b, BI[f"foot_{s}"]] @ corr[BI[f"foot_{s}"]]
        ankle = pose.joints[a:b, JI[f"ankle_{s}"]]
        support = ankle[:, None] + np.einsum("fij,kj->fki", frame, np.asarray(c["support"]))
        # no contact point under the floor (the plant's guard; the IK reaches its targets)
        assert support[..., 2].min() > -0.002, (method, s)
        down = {part: metrics.ground_contact(T[:, J[f"{joint}_{s}"]], FPS) for part, joint in (("heel", "ankle"),
                                                                                        ("ball", "toe"))}
        # the sole on the floor while the clip's foot is down (median of its lowest point)
        assert abs(np.median(support[down["heel"] | down["ball"], :, 2].min(axis=1))) < 0.005, (method, s)
        # (the heel's and the ball's slide and steps: bench_real_motion; on this take the left heel
        # still slides ~2.5x the source's and steps up to 13 mm between frames, DESIGN.md §6 "Feet")


@pytest.mark.parametrize("method", pl.METHODS)
def test_the_planted_ankle_moves_as_smoothly_as_the_clip_s_on_a_real_walk(walk, method):
    """With the default settings (the devices smoothed, the feet planted), the avatar's ankle is
    no rougher than the clip's (acceleration p95 within 1.3x the clip's ankle's, scaled as the
    method scales motion: the legs' ratio, AvatarGo's eye-height ratio for offsets), and where the
    plant eases in or out it adds little to the method's own ankle (p95 over those frames within
    1.3x the unplanted ankle's). Now 1.04-1.27x and 1.02-1.22x; before the planted points followed
    the method off the contact (DESIGN.md §6 "Planted feet"): 1.27-1.40x and 1.29-1.55x."""
    rec, user, truth = walk
    smoothed = filter_recording(rec, OneEuro())
    avatar = _avatar_with_contacts()
    take = pl.prepare_recording(smoothed, user, avatar, method, placement="performer")
    anim = take.solve(0, take.frame_count)
    easing = {s: (w > 0.0) & (w < 1.0) for s, w in take.solver.feet.weight.items()}
    own = pl.retarget(smoothed, user, avatar, method, placement="performer", plant_feet=False)
    a, b = truth["motion"]
    J = {n: i for i, n in enumerate(truth["joints"])}
    T = truth["positions"]
    at_ref = dict(zip(truth["joints"], T[int(round(user.reference_time * FPS))]))
    k = metrics.motion_scale(method, metrics.limb_ratios(AvatarRig.from_model(avatar), at_ref),
                             offsets.eye_height(avatar) / offsets.eye_height(user))["ankle"]

    for s in "lr":
        mine = anim.joints_world[f"ankle_{s}"].astype(float)
        ratio = metrics.acceleration_p95(mine[a:b], FPS) / (metrics.acceleration_p95(T[a:b, J[f"ankle_{s}"]], FPS) * k)
        assert ratio <= 1.3, (method, s, ratio)
        e = easing[s] & (np.arange(len(mine)) >= max(a, 1)) & (np.arange(len(mine)) < min(b, len(mine) - 1))
        assert e.sum() > 50
        unplanted = own.joints_world[f"ankle_{s}"].astype(float)
        added = (np.percentile(metrics.acceleration(mine, FPS)[e], 95)
                 / np.percentile(metrics.acceleration(unplanted, FPS)[e], 95))
        assert added <= 1.3, (method, s, added)


def test_an_avatar_file_without_contact_points_still_plants_and_says_so(walk):
    """An avatar model from before the contact points were measured: its sole's outline stands in
    (the feet still planted, the sole above the floor) and the run says so in one note."""
    rec, user, truth = walk
    avatar = rt.procedural_avatar()
    assert all("contact" not in avatar.element(f"mesh:sole_{s}").extra for s in "lr")
    anim = pl.retarget(rec.window(0, 400), user, avatar, "rotations", placement="performer")
    notes = [n for n in anim.notes if "contact points were not measured" in n]
    assert len(notes) == 1 and "calibrate the avatar again" in notes[0]
    rig = AvatarRig.from_model(avatar)
    pose = rig.fk(anim.rotations, anim.root_location)
    corr = surface_correction(avatar, rig.frames0, complete_joints(avatar))
    for s in "lr":
        outline = np.array([p.local for p in avatar.element(f"mesh:sole_{s}").points.values()])
        frame = pose.frames[:, BI[f"foot_{s}"]] @ corr[BI[f"foot_{s}"]]
        low = (pose.joints[:, JI[f"ankle_{s}"], None] + np.einsum("fij,kj->fki", frame, outline))[..., 2].min(axis=1)
        assert low.min() > -0.002, s
