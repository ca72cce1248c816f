"""A Recording from sampled world matrices (scene objects as a take, FORMATS.md §2.5): device
poses without the objects' scale, markers by name, kinds guessed from names, and one line for
what cannot be a device (mirrored, damaged, doubled)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bodycal_addon.core import transforms as tf
from bodycal_addon.core.errors import BodyCalError
from bodycal_addon.recording.from_matrices import (
    SampledObject,
    guess_kind,
    marker_name,
    recording_from_matrices,
)
from bodycal_addon.recording.model import Segment


def _random_rotations(rng, shape) -> np.ndarray:
    q = tf.quat_normalize(rng.normal(size=shape + (4,)))
    return tf.quat_to_matrix(q)


def _matrices(rot, pos, scale) -> np.ndarray:
    m = np.zeros(rot.shape[:-2] + (4, 4))
    m[..., :3, :3] = rot * scale[..., None, :]
    m[..., :3, 3] = pos
    m[..., 3, 3] = 1.0
    return m


@pytest.mark.parametrize("name, kind", [
    ("HMD", "hmd"), ("Head", "hmd"), ("Valve Index Headset", "hmd"), ("LeftHand", "controller"),
    ("controller_R", "controller"), ("right_hand", "controller"), ("Knuckles.L", "controller"),
    ("glove_l", "rigid_body"), ("LHR-1A2B3C4D", "tracker"), ("Tracker 3", "tracker"), ("waist", "tracker"),
    ("Handle", "tracker"),
])
def test_kinds_are_guessed_from_the_words_of_a_name(name, kind):
    assert guess_kind(name) == kind


@pytest.mark.parametrize("name, marker", [
    ("index_tip_r", "index_tip_r"), ("Mocap.Index_Tip_L", "index_tip_l"), ("take:hand_led2_r", "hand_led2_r"),
    ("glove hand_led3_l", "hand_led3_l"), ("pinky_tip_l.001", None), ("xindex_tip_r", None), ("index_tip", None),
    ("hand_led4_l", None), ("tracker_foot_l", None),
])
def test_markers_are_objects_named_after_a_marker(name, marker):
    assert marker_name(name) == marker


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), uniform=st.booleans())
def test_device_poses_are_the_matrices_without_their_scale(seed, uniform):
    rng = np.random.default_rng(seed)
    f, n = 7, 4
    rot = _random_rotations(rng, (f, n))
    pos = rng.uniform(-3, 3, (f, n, 3))
    scale = rng.uniform(0.2, 5.0, (1, n, 1 if uniform else 3)) * np.ones((f, n, 3))
    frames = np.arange(10, 10 + f)
    objs = [SampledObject(f"obj{i}") for i in range(n)]
    rec = recording_from_matrices("t", frames, 24.0, _matrices(rot, pos, scale), objs)
    np.testing.assert_allclose(rec.time, np.arange(f) / 24.0)
    np.testing.assert_allclose(rec.positions, pos, atol=1e-12)
    np.testing.assert_allclose(tf.quat_to_matrix(rec.rotations), rot, atol=1e-9)
    assert rec.valid.all() and [d.name for d in rec.devices] == [o.name for o in objs]
    # one hemisphere along the frame axis, as every reader leaves a track
    assert np.all(np.einsum("fdi,fdi->fd", rec.rotations[1:], rec.rotations[:-1]) >= 0)


def test_a_sheared_frame_gets_its_nearest_rotation():
    """A child of a non-uniformly scaled, turned parent is sheared: its device frame is the
    rotation nearest to it (the polar factor), not the matrix's normalised columns."""
    rng = np.random.default_rng(3)
    parent = _random_rotations(rng, ())[None] * np.array([1.0, 3.0, 0.5])
    child = _random_rotations(rng, (5,))
    m = np.zeros((5, 1, 4, 4))
    m[:, 0, :3, :3] = parent @ child
    m[:, 0, 3, 3] = 1.0
    rec = recording_from_matrices("t", np.arange(5), 30.0, m, [SampledObject("child")])
    u, _s, vt = np.linalg.svd(m[:, 0, :3, :3])
    np.testing.assert_allclose(tf.quat_to_matrix(rec.rotations[:, 0]), u @ vt, atol=1e-9)


def test_markers_devices_kinds_roles_and_steps():
    f = 4
    names = ["HMD", "Tracker.007", "Mocap.index_tip_r", "LeftHand"]
    m = np.tile(np.eye(4), (f, len(names), 1, 1))
    m[..., :3, 3] = np.arange(f * len(names) * 3).reshape(f, len(names), 3) * 0.01
    objs = [SampledObject(names[0], role="head"), SampledObject(names[1], kind="rigid_body"),
            SampledObject(names[2]), SampledObject(names[3])]
    seg = [Segment("tpose", 0.0, 0.1)]
    rec = recording_from_matrices("take", np.arange(f), 30.0, m, objs, segments=seg, notes=["read"])
    assert [(d.name, d.kind, d.role) for d in rec.devices] == [
        ("HMD", "hmd", "head"), ("Tracker.007", "rigid_body", None), ("LeftHand", "controller", None)]
    assert rec.marker_names == ["index_tip_r"]
    np.testing.assert_allclose(rec.markers[:, 0], m[:, 2, :3, 3])
    np.testing.assert_allclose(rec.positions[:, 2], m[:, 3, :3, 3])
    assert rec.segments == seg and rec.notes == ["read"] and rec.marker_valid.all()


def _one_line(exc) -> str:
    line = exc.value.line()
    assert "\n" not in line
    return line


@pytest.mark.parametrize("what, edit, expect", [
    ("mirrored", lambda m, o: m.__setitem__((slice(None), 1, 0, 0), -1.0), "Tracker B: is mirrored"),
    ("zero scale", lambda m, o: m.__setitem__((2, 1, slice(0, 3), slice(0, 3)), 0.0), "Tracker B: has a zero scale"),
    ("non-finite", lambda m, o: m.__setitem__((3, 0, 0, 3), np.nan), "HMD: frame 13: has a non-finite transform"),
    ("far away", lambda m, o: m.__setitem__((1, 0, 2, 3), 2e4), "HMD: frame 11: position"),
    ("doubled role", lambda m, o: (setattr(o[0], "role", "hand_l"), setattr(o[1], "role", "hand_l")),
     "'HMD' and 'Tracker B' both have the role 'hand_l'"),
    ("unknown role", lambda m, o: setattr(o[1], "role", "left_hand"), "'left_hand' is not a device role"),
    ("doubled marker", lambda m, o: setattr(o[1], "name", "a.index_tip_l"),
     "'a.index_tip_l' and 'index_tip_l' are both the marker 'index_tip_l'"),
])
def test_what_cannot_be_read_is_one_line(what, edit, expect):
    m = np.tile(np.eye(4), (5, 3, 1, 1))
    objs = [SampledObject("HMD"), SampledObject("Tracker B"), SampledObject("index_tip_l")]
    edit(m, objs)
    with pytest.raises(BodyCalError) as exc:
        recording_from_matrices("t", np.arange(10, 15), 30.0, m, objs, source="scene objects")
    assert expect in _one_line(exc), what
