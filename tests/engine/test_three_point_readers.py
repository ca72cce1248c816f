"""The three-point readers on real takes (FORMATS.md §2.6, §2.7): A-Frame motion capture (an HTC
Vive through WebVR) and Beat Saber replays (a VIVE Pro 2, a Quest 2), read as head and hands in the
internal frame, with their axes checked on the data itself: the headset looks where it walks, the
hands are below and in front of it and on their sides, the rotations are continuous and move the
devices as rigid bodies do, the heights are a person's; and what a damaged file gets (one line)."""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest

from bodycal_addon.core import transforms as tf
from bodycal_addon.core.errors import BodyCalError
from bodycal_addon.recording import io as rio
from bodycal_addon.recording.io import aframe, bsor
from bodycal_dev import bsor_writer

AFRAME_TAKES = ("tracked-recording", "dev-recording", "grabLeft", "grabRight")
BSOR_TAKES = ("simsaber_sample", "xror_sample2")
# A standing adult's eyes (the headset), metres above the floor: from a short person's to a tall one's
STANDING_EYES_M = (1.40, 2.0)
# Beat Saber sets the player height this far above the headset when it measures it
GAME_HEIGHT_ABOVE_HMD_M = 0.10


@pytest.fixture(scope="module")
def aframe_dir(data_dir):
    return data_dir / "real_vr" / "aframe_vive"


@pytest.fixture(scope="module")
def bsor_dir(data_dir):
    return data_dir / "real_vr" / "beat_saber"


@pytest.fixture(scope="module")
def aframe_takes(aframe_dir):
    return {n: rio.load_recording(aframe_dir / f"{n}.json") for n in AFRAME_TAKES}


@pytest.fixture(scope="module")
def bsor_takes(bsor_dir):
    return {n: rio.load_recording(bsor_dir / f"{n}.bsor") for n in BSOR_TAKES}


def _all_takes(aframe_takes, bsor_takes):
    return {**aframe_takes, **bsor_takes}


def _tracked(rec, role):
    p, q, ok = rec.pose(role)
    return p, q


def _rigid_pivot(time, pos, rot):
    """The point c fixed in the device's frame that moves least (least squares of the velocity
    of pos + R c), and the RMS speed of the origin and of that point: a device turned about a joint
    (the neck, the elbow) has that joint there, when its rotations are the ones that move it."""
    r = tf.quat_to_matrix(rot)
    v = np.gradient(pos, time, axis=0)
    dr = np.gradient(r, time, axis=0)
    a, b = dr.reshape(-1, 3), -v.reshape(-1)
    c = np.linalg.lstsq(a, b, rcond=None)[0]
    return c, float(np.sqrt(np.mean(b ** 2))), float(np.sqrt(np.mean((a @ c - b) ** 2)))


def _angular_speed(time, rot):
    r = tf.quat_to_matrix(rot)
    rel = np.einsum("fji,fjk->fik", r[:-1], r[1:])
    return np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1)) / np.diff(time)


def _horizontal_unit(v):
    h = np.array(v, float)
    h[..., 2] = 0
    return h / np.linalg.norm(h, axis=-1, keepdims=True)


# --------------------------------------------------------------------------------------------
# What every real take reads as


def test_every_real_take_is_a_head_and_two_hands_with_no_steps(aframe_takes, bsor_takes):
    expected = {"tracked-recording": (2568, 29.24), "dev-recording": (816, 9.33), "grabLeft": (1127, 12.69),
                "grabRight": (1436, 16.34),
                # the first frame of a replay is all zeros (untracked); frames whose song time repeats dropped
                "simsaber_sample": (15185 - 4, 168.68), "xror_sample2": (26556 - 2, 295.23)}
    for name, rec in _all_takes(aframe_takes, bsor_takes).items():
        frames, seconds = expected[name]
        assert rec.frame_count == frames and rec.time[-1] - rec.time[0] == pytest.approx(seconds, abs=0.01), name
        assert sorted((d.kind, d.role) for d in rec.devices) == [
            ("controller", "hand_l"), ("controller", "hand_r"), ("hmd", "head")], name
        assert rec.segments == [] and rec.marker_names == [] and np.all(np.diff(rec.time) > 0), name
        assert 85 < rec.fps < 92, name
        assert np.isfinite(rec.positions).all() and np.allclose(np.linalg.norm(rec.rotations, axis=-1), 1), name
        assert not any("no role" in n for n in rec.notes), name


def test_a_replays_first_frame_is_untracked_and_the_rest_tracked(bsor_takes):
    # simsaber_sample's first frame is all zeros in the file: nothing tracked, its values held (raw: identity)
    rec = bsor_takes["simsaber_sample"]
    assert not rec.valid[0].any() and rec.valid[1:].all()
    assert bsor_takes["xror_sample2"].valid.all()


def test_the_heights_are_a_persons_and_match_the_source(aframe_takes, bsor_takes):
    """Standing headset heights (its 95th percentile) of a person, the crouch SOURCE.md gives for the
    walk-and-crouch take (0.89-1.80 m), and a replay's headset about 0.1 m under the player height
    the game set (Beat Saber puts the player height 0.1 m above the headset when it measures it)."""
    for name, rec in _all_takes(aframe_takes, bsor_takes).items():
        z = rec.pose("head")[0][:, 2]
        low, high = STANDING_EYES_M
        assert low < np.percentile(z, 95) < high, name
        for role in ("hand_l", "hand_r"):
            assert np.all(rec.pose(role)[0][:, 2] > 0.3), name  # above the floor, z = 0
    z = aframe_takes["tracked-recording"].pose("head")[0][:, 2]
    assert z.min() == pytest.approx(0.887, abs=0.005) and z.max() == pytest.approx(1.801, abs=0.005)
    replay = bsor_takes["simsaber_sample"]
    z = replay.pose("head")[0][1:, 2]
    assert "player height 1.98 m" in replay.notes[0]
    expected = 1.98 - GAME_HEIGHT_ABOVE_HMD_M  # standing; the player also ducks walls and leans
    assert expected - 0.15 < np.median(z) < expected + 0.02, np.median(z)


def test_the_hands_are_below_and_in_front_of_the_headset_and_on_their_sides(aframe_takes, bsor_takes):
    for name, rec in _all_takes(aframe_takes, bsor_takes).items():
        ok = rec.valid.all(axis=1)
        hp, hq = (a[ok] for a in _tracked(rec, "head"))
        r = tf.quat_to_matrix(hq)
        forward, right = _horizontal_unit(-r[:, :, 2]), r[:, :, 0]
        sides = {}
        for role in ("hand_l", "hand_r"):
            rel = rec.pose(role)[0][ok] - hp
            assert 0.1 < np.median(-rel[:, 2]) < 0.5, (name, role)  # below the eyes
            # in front (a replay's sabers are held beside the head, a wand's in front)
            assert np.median(np.einsum("fi,fi->f", rel, forward)) > (-0.15 if name in BSOR_TAKES else 0.15), (
                name, role)
            sides[role] = np.einsum("fi,fi->f", rel, right)
        assert np.mean(sides["hand_r"] > sides["hand_l"]) > 0.75, name


def test_the_headset_looks_where_the_person_walks(aframe_takes):
    """tracked-recording walks about: over each second the headset's horizontal travel (where it
    went 0.4 m or more) points along its forward axis (local -Z), not behind or beside it."""
    rec = aframe_takes["tracked-recording"]
    t, (p, q) = rec.time, _tracked(rec, "head")
    later = np.searchsorted(t, t + 1.0)
    i = np.flatnonzero(later < len(t))
    j = later[i]
    travel = p[j] - p[i]
    travel[:, 2] = 0
    dist = np.linalg.norm(travel, axis=1)
    walked = dist > 0.4
    forward = _horizontal_unit(-tf.quat_to_matrix(q[(i + j) // 2])[:, :, 2])
    cos = np.einsum("fi,fi->f", forward, travel)[walked] / dist[walked]
    assert walked.sum() > 100 and np.median(cos) > 0.9 and np.mean(cos > 0) > 0.85


def test_a_replays_head_looks_at_the_notes(bsor_takes):
    """Beat Saber's notes come from the player's +Z (Unity), +Y inside BodyCal: the head's forward
    axis (local -Z) points there, its up axis up."""
    for name, rec in bsor_takes.items():
        q = rec.pose("head")[1][rec.valid[:, 0]]
        r = tf.quat_to_matrix(q)
        assert np.mean(-r[:, 1, 2] > 0.7) > 0.95 and np.mean(r[:, 2, 1] > 0.7) > 0.95, name


def test_the_rotations_move_the_devices_as_rigid_bodies(aframe_takes, bsor_takes):
    """A controller turns about the elbow and wrist behind it: the point of its frame that moves
    least lies behind it along local +Z (its pointing axis is -Z), 0.15-0.55 m, and explains much of
    its motion; the headset of the still take turns about the neck, below and behind the eyes.
    Rotations that do not belong to the positions find no such point: the same rotations mirrored
    (a handedness mistake, R -> S R S) or inverted explain at least 0.15 of the motion less."""
    mirror = np.diag([1.0, 1.0, -1.0])
    for name, rec in _all_takes(aframe_takes, bsor_takes).items():
        ok = rec.valid.all(axis=1)
        for role in ("hand_l", "hand_r"):
            p, q = (a[ok] for a in _tracked(rec, role))
            c, moved, least = _rigid_pivot(rec.time[ok], p, q)
            assert 0.15 < c[2] < 0.55 and abs(c[0]) < 0.2 and least < 0.75 * moved, (name, role, c, moved, least)
            for wrong in (tf.matrix_to_quat(mirror @ tf.quat_to_matrix(q) @ mirror), tf.quat_conj(q)):
                assert _rigid_pivot(rec.time[ok], p, wrong)[2] > least + 0.15 * moved, (name, role)
    rec = aframe_takes["dev-recording"]
    c, moved, least = _rigid_pivot(rec.time, *_tracked(rec, "head"))
    assert -0.25 < c[1] < -0.08 and 0.02 < c[2] < 0.15 and abs(c[0]) < 0.05 and least < 0.5 * moved


def test_a_frames_euler_order_is_the_one_with_continuous_rotations(aframe_dir, aframe_takes):
    """three.js applies the A-Frame `rotation` as Euler 'YXZ': read so, a fast wand turns at most
    about 60 rad/s between samples; read in three.js's default order 'XYZ', the Euler angles'
    branch changes (near 90 degrees pitch) become turns of 100 rad/s and more."""
    doc = json.loads((aframe_dir / "tracked-recording.json").read_text())
    rec = aframe_takes["tracked-recording"]
    for name in ("left", "right"):
        deg = np.array([[p["rotation"][a] for a in "xyz"] for p in doc[name]["poses"]])
        xyz = rio.to_internal(np.zeros((len(deg), 3)),
                              tf.matrix_to_quat(tf.euler_matrices(np.radians(deg), "XYZ")), "Y", "right", "m")[1]
        ours = rec.pose(name)[1]
        assert _angular_speed(rec.time, ours).max() < 60 < 100 < _angular_speed(rec.time, xyz).max(), name
        assert np.percentile(_angular_speed(rec.time, ours), 99) < np.percentile(_angular_speed(rec.time, xyz), 99)


def test_a_frame_axes_on_a_known_pose(tmp_path):
    """One pose converted by hand: three.js (x, y, z) is (x, -z, y) inside BodyCal (floor y = 0 at
    z = 0); Euler (0, 90, 0) degrees turns the headset to look along three.js -X (a quarter turn to
    its left), and (30, 0, 0) tilts it 30 degrees up."""
    def pose(pos, rot, ts):
        return {"position": dict(zip("xyz", pos)), "rotation": dict(zip("xyz", rot)), "timestamp": ts}

    doc = {"camera": {"poses": [pose((0.5, 1.6, -2.0), (0, 90, 0), 10.0), pose((0.5, 0.0, -2.0), (30, 0, 0), 21.0)],
                      "events": []},
           "leftHand": {"poses": [pose((0.3, 1.2, -2.3), (0, 0, 0), 10.0), pose((0.3, 1.2, -2.3), (0, 0, 0), 21.0)]},
           "rightHand": {"poses": [pose((0.7, 1.2, -2.3), (0, 0, 0), 10.0), pose((0.7, 1.2, -2.3), (0, 0, 0), 21.0)]}}
    path = tmp_path / "one.json"
    path.write_text(json.dumps(doc))
    rec = rio.load_recording(path, raw=True)
    np.testing.assert_allclose(rec.time, [0.0, 0.011])
    np.testing.assert_allclose(rec.pose("head")[0], [[0.5, 2.0, 1.6], [0.5, 2.0, 0.0]], atol=1e-12)
    r = tf.quat_to_matrix(rec.pose("head")[1])
    np.testing.assert_allclose(-r[0, :, 2], [-1, 0, 0], atol=1e-12)  # looks along -X
    np.testing.assert_allclose(-r[1, :, 2], [0, np.cos(np.pi / 6), np.sin(np.pi / 6)], atol=1e-12)  # +Y, 30 up
    assert rec.devices[rec.device_index("hand_l")].name == "leftHand"  # too few frames: the ids decide


def test_an_entity_recorded_late_is_untracked_before(tmp_path):
    def pose(ts):
        return {"position": {"x": 0, "y": 1, "z": 0}, "rotation": {"x": 0, "y": 0, "z": 0}, "timestamp": ts}

    doc = {"camera": {"poses": [pose(t) for t in (0.0, 11.0, 22.0)]},
           "left": {"poses": [pose(t) for t in (11.0, 22.0)]}, "right": {"poses": [pose(22.0)]}}
    (tmp_path / "late.json").write_text(json.dumps(doc))
    rec = rio.load_recording(tmp_path / "late.json", raw=True)
    assert rec.valid.tolist() == [[True, False, False], [True, True, False], [True, True, True]]


# --------------------------------------------------------------------------------------------
# Which controller is which hand


def test_the_hands_are_told_by_where_they_are_whatever_the_labels_say(aframe_dir, aframe_takes, tmp_path):
    """grabLeft / grabRight label each wand's gamepad with the other side; by default the wand on the
    headset's right is the right hand whatever the labels (the entity ids agree; a note says the
    gamepads do not). Renamed entities (ids swapped) change nothing but the names. `labels` and
    `swapped` are explicit."""
    for name, rec in aframe_takes.items():
        assert rec.devices[rec.device_index("hand_r")].name == "right", name
        note = next(n for n in rec.notes if n.startswith("hands from where they are"))
        assert ("gamepads say" in note) == name.startswith("grab"), name
    doc = json.loads((aframe_dir / "tracked-recording.json").read_text())
    doc = {"camera": doc["camera"], "left": doc["right"], "right": doc["left"]}  # the labels swapped
    (tmp_path / "renamed.json").write_text(json.dumps(doc))
    renamed = rio.load_recording(tmp_path / "renamed.json")
    original = aframe_takes["tracked-recording"]
    for role in ("hand_l", "hand_r"):
        np.testing.assert_array_equal(renamed.pose(role)[0], original.pose(role)[0])
    assert renamed.devices[renamed.device_index("hand_r")].name == "left"
    assert any("against the file's labels" in n for n in renamed.notes)
    as_named = rio.load_recording(tmp_path / "renamed.json", hands="labels")
    assert as_named.devices[as_named.device_index("hand_r")].name == "right"
    swapped = rio.load_recording(aframe_dir / "tracked-recording.json", hands="swapped")
    assert swapped.devices[swapped.device_index("hand_r")].name == "left"
    with pytest.raises(BodyCalError, match="is not a way to tell the hands") as err:
        rio.load_recording(aframe_dir / "tracked-recording.json", hands="gamepad")
    assert "\n" not in err.value.line() and "tracked-recording.json" in err.value.line()


def test_a_turned_room_tells_the_same_hands(aframe_dir, tmp_path):
    """Invariance: the whole take turned 120 degrees about the vertical (three.js +Y) and moved: the
    same wands are the same hands, the heights are unchanged."""
    doc = json.loads((aframe_dir / "grabLeft.json").read_text())
    turn = np.radians(120.0)
    c, s = np.cos(turn), np.sin(turn)
    for ent in doc.values():
        for p in ent["poses"]:
            x, z = p["position"]["x"], p["position"]["z"]
            p["position"]["x"], p["position"]["z"] = c * x + s * z + 3.0, -s * x + c * z - 1.0
            p["rotation"]["y"] += 120.0  # R = Ry Rx Rz: a turn about Y first in the product
    (tmp_path / "turned.json").write_text(json.dumps(doc))
    turned = rio.load_recording(tmp_path / "turned.json")
    original = rio.load_recording(aframe_dir / "grabLeft.json")
    assert [d.role for d in turned.devices] == [d.role for d in original.devices]
    np.testing.assert_allclose(turned.positions[..., 2], original.positions[..., 2], atol=1e-9)
    share = [next(n for n in r.notes if n.startswith("hands")) for r in (turned, original)]
    assert share[0] == share[1]


def test_a_replays_hands_follow_its_labels_and_the_geometry(bsor_takes, bsor_dir):
    for name, rec in bsor_takes.items():
        assert rec.devices[rec.device_index("hand_r")].name == "right_hand", name
        assert any("as the file labels them" in n for n in rec.notes), name
    swapped = rio.load_recording(bsor_dir / "simsaber_sample.bsor", hands="swapped")
    assert swapped.devices[swapped.device_index("hand_r")].name == "left_hand"


# --------------------------------------------------------------------------------------------
# The replay format itself


def _decode_frames(data: bytes):
    """The frames of a .bsor, decoded field by field with struct from the published layout (an
    independent reading to compare the reader's numpy one with)."""
    at = 5

    def take(fmt):
        nonlocal at
        v = struct.unpack_from(fmt, data, at)
        at += struct.calcsize(fmt)
        return v

    assert data[at] == 0
    at += 1
    for k in range(16):
        n = take("<i")[0]
        at += n
        if k == 12:
            take("<i")  # score
    take("<f?ffff")
    assert data[at] == 1
    at += 1
    n = take("<i")[0]
    time, fps, pose = [], [], []
    for _ in range(n):
        t, f = take("<fi")
        time.append(t)
        fps.append(f)
        pose.append(take("<21f"))
    return np.array(time), np.array(fps), np.array(pose).reshape(n, 3, 7), at


def test_a_replays_values_are_the_files_in_unitys_axes(bsor_dir, bsor_takes):
    """The reader's head and hands, taken back to Unity's axes (`coords` Y up, left-handed), are the
    file's float32 values as an independent field-by-field decoding reads them; and the song time,
    at 1x, runs at the player's frame rate (each frame's `fps` field)."""
    for name in BSOR_TAKES:
        time, fps, pose, _ = _decode_frames((bsor_dir / f"{name}.bsor").read_bytes())
        rec = rio.load_recording(bsor_dir / f"{name}.bsor", raw=True)
        keep = np.r_[True, time[1:] > np.maximum.accumulate(time)[:-1]]
        np.testing.assert_allclose(rec.time, time[keep] - time[0], atol=1e-6)
        back = bsor_writer.unity_poses(rec)
        tracked = rec.valid
        for k in range(3):
            np.testing.assert_allclose(back[tracked[:, k], k, :3], pose[keep][tracked[:, k], k, :3], atol=1e-6)
            q_back, q_file = back[tracked[:, k], k, 3:], pose[keep][tracked[:, k], k, 3:]
            sign = np.sign(np.einsum("fi,fi->f", q_back, q_file))[:, None]
            np.testing.assert_allclose(sign * q_back, q_file, atol=1e-6)
        dt_fps = np.diff(rec.time) * fps[keep][1:]
        assert np.median(dt_fps) == pytest.approx(1.0, abs=0.02), name


def test_another_real_take_written_as_a_replay_reads_back_the_same(aframe_takes, tmp_path):
    """A real A-Frame take written as a .bsor (the test writer, Unity's axes) reads back as the same
    head and hands, within float32, in the same frame: the two readers' conversions agree."""
    rec = aframe_takes["tracked-recording"]
    path = bsor_writer.write_bsor(tmp_path / "aframe.bsor", rec.time, bsor_writer.unity_poses(rec))
    back = rio.load_recording(path)
    assert back.frame_count == rec.frame_count
    for role in ("head", "hand_l", "hand_r"):
        np.testing.assert_allclose(back.pose(role)[0], rec.pose(role)[0], atol=2e-6)
        angle = tf.quat_angle(tf.quat_mul(tf.quat_conj(back.pose(role)[1]), rec.pose(role)[1]))
        assert np.degrees(angle).max() < 1e-3
    np.testing.assert_allclose(back.time, rec.time, atol=1e-5)


def test_speed_modifiers_give_the_performers_seconds(tmp_path):
    time = np.arange(10) / 90.0
    poses = np.tile([0.0, 1.7, 0.0, 0.0, 0.0, 0.0, 1.0], (10, 3, 1))
    for info, factor in [({"modifiers": "FS"}, 1.2), ({"modifiers": "SS,NF"}, 0.85), ({"speed": 0.5}, 0.5),
                         ({"modifiers": "SF", "speed": 2.0}, 3.0), ({}, 1.0)]:
        rec = rio.load_recording(bsor_writer.write_bsor(tmp_path / "speed.bsor", time, poses, info))
        np.testing.assert_allclose(rec.time, time / factor, rtol=1e-6)
        assert (f"times divided by {factor:g}" in rec.notes[0]) == (factor != 1.0)


def test_a_header_string_counted_in_utf16_units_is_read(tmp_path):
    """Some recorders counted the player name, song name and mapper in UTF-16 units: a name with
    letters beyond ASCII then has more bytes than its count. The header is still read."""
    time = np.arange(5) / 90.0
    poses = np.tile([0.0, 1.7, 0.0, 0.0, 0.0, 0.0, 1.0], (5, 3, 1))
    info = {"player name": "Jürgen ツ", "song name": "Ünïcødé 曲", "height": 1.75}
    rec = rio.load_recording(bsor_writer.write_bsor(tmp_path / "u16.bsor", time, poses, info, utf16_counts=True))
    assert "player height 1.75 m" in rec.notes[0] and "'Ünïcødé 曲'" in rec.notes[0]


def test_untracked_and_repeated_frames(tmp_path):
    time = np.array([0.0, 0.011, 0.011, 0.022, 0.020, 0.033])
    poses = np.tile([0.0, 1.7, 0.0, 0.0, 0.0, 0.0, 1.0], (6, 3, 1))
    poses[0] = 0.0  # the game's first frame
    poses[3, 1, 3:] = 0.0  # the left hand lost in one frame
    rec = rio.load_recording(bsor_writer.write_bsor(tmp_path / "gaps.bsor", time, poses), raw=True)
    np.testing.assert_allclose(rec.time, [0.0, 0.011, 0.022, 0.033], atol=1e-7)
    assert rec.valid.tolist() == [[False] * 3, [True] * 3, [True, False, True], [True] * 3]
    assert "2 frames dropped: their song time did not advance" in rec.notes


@pytest.mark.parametrize("damage, words", [
    (lambda b: b[:3], "magic number: the file ends here"),
    (lambda b: b"\0\0\0\0" + b[4:], "not a Beat Saber replay"),
    (lambda b: b[:4] + b"\x02" + b[5:], "BSOR version 2 is not known"),
    (lambda b: b[:40], "the file ends here"),
    (lambda b: b[:-200], "frames: 10 frames declared, the file holds"),
])
def test_a_damaged_replay_is_one_line(tmp_path, damage, words):
    time = np.arange(10) / 90.0
    poses = np.tile([0.0, 1.7, 0.0, 0.0, 0.0, 0.0, 1.0], (10, 3, 1))
    data = bsor_writer.write_bsor(tmp_path / "ok.bsor", time, poses).read_bytes()[:-20]  # no trailing blocks
    (tmp_path / "bad.bsor").write_bytes(damage(data))
    with pytest.raises(BodyCalError) as err:
        rio.load_recording(tmp_path / "bad.bsor")
    line = err.value.line()
    assert words in line and line.startswith("bad.bsor") and "\n" not in line


def test_a_replay_cut_short_after_its_frames_still_loads(bsor_dir, tmp_path):
    data = (bsor_dir / "simsaber_sample.bsor").read_bytes()
    end = _decode_frames(data)[3]  # where the frames end and the notes begin
    (tmp_path / "cut.bsor").write_bytes(data[:end + 3])
    assert rio.load_recording(tmp_path / "cut.bsor").frame_count == 15181
    (tmp_path / "cut.bsor").write_bytes(data[:end - 3])
    with pytest.raises(BodyCalError, match="15185 frames declared, the file holds 15184"):
        rio.load_recording(tmp_path / "cut.bsor")


def test_non_finite_and_far_values_are_refused_with_the_frame(tmp_path):
    time = np.arange(6) / 90.0
    poses = np.tile([0.0, 1.7, 0.0, 0.0, 0.0, 0.0, 1.0], (6, 3, 1))
    for k, value, words in [(3, np.nan, "frame 3: not a finite number"), (4, 2e4, "frame 4: position"),
                            (2, 0.5, "frame 2: quaternion is not unit length")]:
        bad = poses.copy()
        bad[k, 2, 6 if words.endswith("length") else 1] = value
        with pytest.raises(BodyCalError) as err:
            rio.load_recording(bsor_writer.write_bsor(tmp_path / "v.bsor", time, bad))
        assert words in err.value.line(), err.value.line()


# --------------------------------------------------------------------------------------------
# Dispatch, the drop check


def test_the_new_files_pass_the_drop_check_and_others_do_not(aframe_dir, bsor_dir, tmp_path):
    for path in [*(aframe_dir / f"{n}.json" for n in AFRAME_TAKES), *(bsor_dir / f"{n}.bsor" for n in BSOR_TAKES)]:
        rio.check_recording_file(path)
    (tmp_path / "notes.json").write_text('{"camera": "a photo", "notes": []}')
    (tmp_path / "song.bsor").write_bytes(b"RIFF....WAVEfmt ")
    for name, words in [("notes.json", "not an A-Frame motion capture"), ("song.bsor", "not a Beat Saber replay")]:
        with pytest.raises(BodyCalError) as err:
            rio.check_recording_file(tmp_path / name)
        assert words in err.value.line() and err.value.line().startswith(name)


def test_a_json_is_read_by_what_it_is(aframe_dir, tmp_path):
    """A .json starting as an A-Frame capture goes to its reader; BodyCal's own format wins when the
    file says it; anything else is BodyCal's reader's one line."""
    assert aframe.looks_like_aframe((aframe_dir / "dev-recording.json").read_bytes()[:100])
    (tmp_path / "other.json").write_text('{"camera": {"poses": []}, "format": "bodycal-recording"}')
    with pytest.raises(BodyCalError, match="unknown field"):  # BodyCal's reader, not A-Frame's
        rio.load_recording(tmp_path / "other.json")
    (tmp_path / "empty.json").write_text('{"camera": {"poses": []}}')
    with pytest.raises(BodyCalError, match="empty.json: camera.poses: no pose recorded"):
        rio.load_recording(tmp_path / "empty.json")
    (tmp_path / "bad.json").write_text('{"camera": {"poses": [{"position": {"x": 0, "y": true, "z": 0}, '
                                       '"rotation": {"x": 0, "y": 0, "z": 0}, "timestamp": 1}]}}')
    with pytest.raises(BodyCalError, match="bad.json: camera.poses.position.y: pose 0: not a finite number: True"):
        rio.load_recording(tmp_path / "bad.json")


def test_the_file_browser_lists_the_new_files():
    from fnmatch import fnmatch

    for name in ("tracked-recording.json", "replay.bsor", "take.bcrec.json", "take.csv", "take.c3d"):
        assert any(fnmatch(name.lower(), g) for g in rio.RECORDING_GLOBS), name
    assert bsor.is_bsor(bsor.MAGIC_BYTES) and not bsor.is_bsor(b"\x69\x3d\x2d")


def test_a_frame_ids_and_times_that_cannot_be_a_recording_are_one_line(tmp_path):
    def pose(ts):
        return {"position": {"x": 0, "y": 1, "z": 0}, "rotation": {"x": 0, "y": 0, "z": 0}, "timestamp": ts}

    for doc, words in [
        ({"camera": {"poses": [pose(0.0), pose(5e-324)]}}, "timestamp: sample 1: time must increase strictly"),
        ({"camera": {"poses": [pose(0.0)]}, " ": {"poses": [pose(0.0)]}}, "an entity with an empty id"),
        ({"camera": {"poses": [pose(0.0), pose(0.0)]}}, "camera.poses.timestamp: pose 1: timestamp must increase"),
        ({"camera": {"poses": [pose(0.0)]}, "left": [1, 2]}, "left: not an entity"),
    ]:
        (tmp_path / "odd.json").write_text(json.dumps(doc))
        with pytest.raises(BodyCalError) as err:
            rio.load_recording(tmp_path / "odd.json")
        assert err.value.line().startswith("odd.json: ") and words in err.value.line(), err.value.line()
