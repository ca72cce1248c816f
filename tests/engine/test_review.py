"""The review of a bake, its engine side (bodycal_addon/output/review.py; DESIGN.md §7 "Review"):
the source's self-contacts against the synthetic performer's ground truth, every flagged figure
the benches' own (the same metrics functions on the same data), the flags against the benches'
limits, the order of reviews, and the figures unchanged when the room is turned and moved."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from bodycal_addon.core import transforms as tf
from bodycal_addon.output import metrics
from bodycal_addon.output import review as rv
from bodycal_addon.recording.filters import DEFAULT_FILTER, filter_recording
from bodycal_addon.retarget import pipeline as pl
from bodycal_addon.retarget.pose_source import RecordingSource
from bodycal_dev import retarget_fixtures as rt
from bodycal_dev import synthetic

FPS = 90.0


@pytest.fixture(scope="module")
def take():
    """The contact motions and a walk, 90 Hz, smoothed as a bake smooths them by default."""
    perf = synthetic.make_performer(height=1.75, build="average", seed=1)
    rec, truth = synthetic.record_session(perf, motions=("clap", "hand_on_belly", "hand_on_head", "walk_in_place"),
                                          calibration=False, seed=1)
    return filter_recording(rec, DEFAULT_FILTER), truth, truth.body_model()


@pytest.fixture(scope="module")
def avatar():
    return rt.procedural_avatar()


@pytest.fixture(scope="module")
def reviews(take, avatar):
    rec, _truth, user = take
    out = {}
    for method in ("egocentric", "rotations"):
        anim = pl.retarget(rec, user, avatar, method)
        source = rv.source_motion(RecordingSource(rec, user), avatar, method)
        out[method] = (anim, source, rv.plan(anim, avatar, source, 1.0, FPS, {"reach p95": 12.0}))
    return out


def test_the_sources_self_contacts_are_the_performers(take, reviews):
    """Every frame the synthetic performer's palm touches its body (its ground truth) is found on
    the source, on the element it touches; the frames found besides are nearly all next to those
    (the hand coming and going within CONTACT_MM) or the other hand of a clap (a brush of a palm
    on an arm, which the ground truth does not list, is the rest)."""
    _rec, truth, _user = take
    _anim, source, _plan = reviews["egocentric"]
    found = {(c["effector"], c["target"].split("/")[0]): c["frames"] for c in source.contacts}
    assert truth.contacts
    near = np.zeros(len(truth.contacts[0]["frames"]), bool)
    for c in truth.contacts:
        key = (c["effector"], c["target"].split("/")[0])
        assert key in found, (key, sorted(found))
        recall = (found[key] & c["frames"]).sum() / c["frames"].sum()
        assert recall >= 0.95, (key, recall)
        near |= np.convolve(c["frames"], np.ones(2 * int(0.3 * FPS) + 1), "same") > 0
    extra = total = 0
    for (effector, _target), frames in found.items():
        total += frames.sum()
        mirrored = (f"palm_{'l' if effector[-1] == 'r' else 'r'}", f"mesh:{effector}")  # a clap: the other palm
        if not any((c["effector"], c["target"].split("/")[0]) == mirrored for c in truth.contacts):
            extra += (frames & ~near).sum()
    assert extra <= 0.02 * total, (extra, total)


def test_the_contact_gap_flag_is_the_benches_figure(take, avatar, reviews):
    """The flagged contact gap is bench_retarget_quality's `model_contact_gap` p95 (metrics.
    model_contact_gaps, metrics.stats_mm) on these contacts, to the digit; egocentric keeps it under
    the bench's limit, a rotation copy does not."""
    for method in ("egocentric", "rotations"):
        anim, source, plan = reviews[method]
        gaps = metrics.model_contact_gaps(avatar, anim.rotations, anim.root_location, source.contacts,
                                          anim.joints_world)
        assert plan.figures["contact_p95"] == metrics.stats_mm(np.concatenate(gaps))["p95"]
    ego = reviews["egocentric"][2].conclude(None)
    rot = reviews["rotations"][2].conclude(None)
    flag = {r: next(f for f in review.flags if f.name == "contact gap") for r, review in (("ego", ego), ("rot", rot))}
    assert not flag["ego"].over and flag["ego"].value <= metrics.CONTACT_GAP_P95_MM
    assert flag["rot"].over and flag["rot"].value > 3 * flag["ego"].value
    assert flag["rot"].limit == metrics.CONTACT_GAP_P95_MM


def test_the_slide_and_acceleration_flags_are_the_benches_figures(reviews):
    """Acceleration: bench_real_motion's p95 ratio (metrics.acceleration_p95, the source scaled by
    metrics.motion_scale); slide: its p95 in mm per 90 Hz frame while the source's foot is down."""
    anim, source, plan = reviews["egocentric"]
    for joint in ("wrist", "ankle"):
        ratio = max(metrics.acceleration_p95(anim.joints_world[f"{joint}_{s}"], FPS)
                    / (metrics.acceleration_p95(source.joints[f"{joint}_{s}"], FPS) * source.scale[joint])
                    for s in "lr")
        assert plan.figures[f"{joint}_accel_ratio"] == pytest.approx(ratio, rel=1e-12)
    review = plan.conclude(None)
    slide = next(f for f in review.flags if f.name == "foot slide")
    assert slide.value == plan.figures["slide_p95"] and slide.limit == metrics.SLIDE_P95_MM
    accel = next(f for f in review.flags if f.name == "wrist acceleration")
    assert accel.limit == metrics.ACCEL_RATIO and accel.over == (accel.value > metrics.ACCEL_RATIO)


def test_the_sheet_frames_are_where_their_figures_are(reviews):
    anim, _source, plan = reviews["rotations"]
    review = plan.conclude({"l": np.array([0.01, -0.02, 0.0, 0.03]), "r": np.array([0.0, 0.0, 0.0, 0.0])})
    frames = {f.title: f for f in review.frames}
    assert set(frames) == set(rv.SHEET_FRAMES)
    worst = frames["worst contact gap"].index
    gap_flag = next(f for f in review.flags if f.name == "contact gap")
    assert gap_flag.frame == frames["worst contact gap"].frame
    pooled = [np.abs(np.asarray(c["avatar"][1], float)) for c in review.series["contact"]]
    assert f"{plan.figures['contact_worst']:.1f} mm" in frames["worst contact gap"].label
    assert max(np.nanmax(np.where(np.equal(p, None), np.nan, p).astype(float)) for p in pooled) == pytest.approx(
        plan.figures["contact_worst"], abs=0.01)
    assert 0 <= worst < anim.frame_count
    # the lowest skin the mesh gave: the left foot's second candidate, -20 mm below the floor, past the limit
    skin = next(f for f in review.flags if f.name == "foot skin")
    assert skin.value == pytest.approx((-0.02 - plan.floor) * 1000) and skin.over == (skin.value < -10.0)
    assert frames["lowest foot skin"].index == plan.skin_frames["l"][1]
    wrist = frames["largest wrist acceleration"].index
    a = max(np.nanmax(metrics.acceleration(anim.joints_world[f"wrist_{s}"], FPS)) for s in "lr")
    assert max(metrics.acceleration(anim.joints_world[f"wrist_{s}"], FPS)[wrist] for s in "lr") == pytest.approx(a)
    assert frames["middle of the take"].index == anim.frame_count // 2


def test_reviews_are_ordered_worst_first_a_failed_verification_above_all():
    def review(*values):
        return rv.Review([rv.Flag("contact gap", v, 10.0, "mm", v > 10.0, 1.0, "", v / 10.0) for v in values])

    failed = rv.verification_failed("the baked keys do not move the bones that deform the mesh")
    order = sorted([review(5.0), review(30.0, 12.0), failed, review(40.0), review(9.0, 11.0)],
                   key=lambda r: r.severity())
    assert order[0] is failed
    assert [[f.value for f in r.flags] for r in order[1:]] == [[30.0, 12.0], [40.0], [9.0, 11.0], [5.0]]


def test_a_review_is_plain_json_and_reads_back(reviews):
    _anim, _source, plan = reviews["egocentric"]
    review = plan.conclude(None)
    text = json.dumps(review.to_dict(), allow_nan=False)
    again = rv.Review.from_dict(json.loads(text))
    assert [f.text for f in again.flags] == [f.text for f in review.flags]
    assert [f.frame for f in again.frames] == [f.frame for f in review.frames]


def test_a_thinned_series_keeps_its_spikes():
    v = np.random.default_rng(0).normal(size=5000)
    v[1234], v[4321] = 40.0, -35.0
    v[100:400] = np.nan
    idx, values = rv._thin(v)
    assert len(idx) <= rv.PLOT_POINTS + 2 and np.all(np.diff(idx) >= 0)
    assert 1234 in idx and 4321 in idx and np.nanmax(values) == 40.0 and np.nanmin(values) == -35.0


def test_the_metrics_the_flags_use_measure_what_they_say():
    t = np.arange(200) / FPS
    fall = np.stack([0.3 * t, 0.0 * t, -4.9 * t ** 2], axis=1)  # 9.8 m/s^2 down, steady across
    a = metrics.acceleration(fall, FPS)
    assert np.isnan(a[[0, -1]]).all() and np.allclose(a[1:-1], 9.8)
    assert metrics.acceleration_p95(fall, FPS) == pytest.approx(9.8)
    on = np.ones(200, bool)
    assert metrics.slide_p95_mm(fall, on, FPS) == pytest.approx(0.3 * 1000 / 90, abs=0.005)  # 0.3 m/s a 90 Hz frame
    # the same steps at 30 Hz are a third of the speed: a third of the slide per 90 Hz frame
    assert metrics.slide_p95_mm(fall, on, 30.0) == pytest.approx(0.3 * 1000 / 90 / 3, abs=0.005)
    still = np.zeros((100, 3))
    still[50:] = [0.0, 0.0, 0.2]  # lifted after half the take
    assert (metrics.ground_contact(still, FPS) == (np.arange(100) < 50)).all()


def _moved(rec, yaw_deg, offset):
    """The same recording with the whole room turned about the vertical and moved on the floor."""
    a = np.radians(yaw_deg)
    R = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0.0, 0.0, 1.0]])
    out = copy.copy(rec)
    out.positions = rec.positions @ R.T + offset
    out.rotations = tf.quat_mul(tf.matrix_to_quat(R), rec.rotations)
    out.markers = rec.markers @ R.T + offset
    return out


def test_turning_and_moving_the_room_changes_no_figure(take, avatar, reviews):
    """Distances, slides and accelerations do not depend on where the performer stood or faced."""
    rec, _truth, user = take
    moved = _moved(rec, 137.0, (1.3, -0.8, 0.0))
    anim = pl.retarget(moved, user, avatar, "egocentric")
    source = rv.source_motion(RecordingSource(moved, user), avatar, "egocentric")
    again = rv.plan(anim, avatar, source, 1.0, FPS)
    before = reviews["egocentric"][2].figures
    for key in ("contact_p95", "contact_worst", "slide_p95", "slide_ratio", "wrist_accel_ratio", "ankle_accel_ratio"):
        assert again.figures[key] == pytest.approx(before[key], rel=0.02, abs=0.05), key
    assert {(c["effector"], c["target"]) for c in source.contacts} == \
        {(c["effector"], c["target"]) for c in reviews["egocentric"][1].contacts}


def test_a_source_at_other_samples_keeps_its_contacts_there(reviews):
    _anim, source, _plan = reviews["egocentric"]
    every_other = source.at(np.arange(0, len(source.joints["pelvis"]), 2))
    assert len(every_other.joints["pelvis"]) == (len(source.joints["pelvis"]) + 1) // 2
    for c in every_other.contacts:
        full = next(s for s in source.contacts if (s["effector"], s["target"]) == (c["effector"], c["target"]))
        assert (c["frames"] <= full["frames"][::2]).all()
