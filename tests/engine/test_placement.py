"""Where a performance plays (DESIGN.md §1, "Placement"; retarget/placement.py): relative to the
armature object's placement by default, or where the performer was in the room; and the avatar model
moved with its object. The avatars are the procedural one as the calibration measures it on its
exact surface, placed by an armature matrix_world (bodycal_dev.retarget_fixtures)."""

from __future__ import annotations

import copy

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bodycal_addon.body import skeleton as sk
from bodycal_addon.core.errors import BodyCalError
from bodycal_addon.retarget import avatar_pose as ap
from bodycal_addon.retarget import pipeline as pl
from bodycal_addon.retarget import placement as pm
from bodycal_addon.retarget import user_animation as ua
from bodycal_dev import retarget_fixtures as rt
from bodycal_dev import synthetic


def yaw_scale_move(yaw: float, scale: float, offset) -> np.ndarray:
    """An armature matrix_world: turned about the vertical, uniformly scaled, moved."""
    c, s = np.cos(yaw), np.sin(yaw)
    m = np.eye(4)
    m[:3, :3] = scale * np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    m[:3, 3] = offset
    return m


def apply(m, p):
    return np.asarray(p, float) @ m[:3, :3].T + m[:3, 3]


@pytest.fixture(scope="module")
def session():
    perf = synthetic.make_performer(seed=4)
    rec, truth = synthetic.record_session(perf, motions=("hand_on_belly", "clap"), calibration=False,
                                          motion_seconds=1.0, seed=4)
    return rec, truth.body_model()


@pytest.fixture(scope="module")
def unmoved(session):
    """Each method's result, per placement, for the avatar whose object is not transformed."""
    rec, user = session
    avatar = rt.procedural_avatar()
    return {(m, p): pl.retarget(rec, user, avatar, m, placement=p) for m in pl.METHODS for p in pm.PLACEMENTS}


def test_the_play_area_lands_on_the_avatar_where_it_stands_facing_its_way():
    avatar = rt.procedural_avatar(matrix_world=yaw_scale_move(0.0, 1.0, (2.0, -3.0, 0.0)))
    heading = pm.rest_heading(avatar)
    np.testing.assert_allclose(heading, [0.0, -1.0, 0.0], atol=1e-9)  # a Blender rig faces the front view
    m = pm.play_area_to_world(avatar, "object")
    np.testing.assert_allclose(apply(m, [0.0, 0.0, 0.0]), [2.0, -3.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(m[:3, :3] @ pm.PLAY_AREA_FORWARD, heading, atol=1e-12)
    turned = rt.procedural_avatar(matrix_world=yaw_scale_move(0.5, 1.3, (2.0, -3.0, 0.4)))
    m = pm.play_area_to_world(turned, "object")
    np.testing.assert_allclose(apply(m, [0.0, 0.0, 0.0]), [2.0, -3.0, 0.4], atol=1e-12)
    np.testing.assert_allclose(m[:3, :3] @ pm.PLAY_AREA_FORWARD,
                               [np.sin(0.5), -np.cos(0.5), 0.0], atol=1e-9)
    # the performer placement keeps the room: only the avatar's floor height comes along
    np.testing.assert_allclose(pm.play_area_to_world(turned, "performer"),
                               [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0.4], [0, 0, 0, 1]], atol=1e-12)
    with pytest.raises(BodyCalError, match="unknown placement"):
        pm.play_area_to_world(avatar, "stage")


def test_a_moved_model_is_the_model_calibrated_there():
    """transformed_avatar gives what the calibration measures on the transformed object: the
    fixture builds both from the exact surface, so they agree to rounding."""
    m = yaw_scale_move(0.8, 1.25, (1.0, 2.0, 0.3))
    moved = pm.transformed_avatar(rt.procedural_avatar(), m)
    there = rt.procedural_avatar(matrix_world=m)
    for j, joint in there.joints.items():
        np.testing.assert_allclose(moved.joints[j].world, joint.world, atol=1e-9, err_msg=j)
        if joint.local is not None:
            np.testing.assert_allclose(moved.joints[j].local, joint.local, atol=1e-9, err_msg=j)
    for b, info in there.bones.items():
        assert moved.bones[b].length == pytest.approx(info.length, abs=1e-9), b
        if info.right is None:
            assert moved.bones[b].right is None, b
        else:
            np.testing.assert_allclose(moved.bones[b].right, info.right, atol=1e-9, err_msg=b)
        if info.radius_head is not None:
            assert moved.bones[b].radius_head == pytest.approx(info.radius_head, abs=1e-9), b
    for e in there.surface:
        mine = moved.element(e.id)
        for name, p in e.points.items():
            np.testing.assert_allclose(mine.points[name].local, p.local, atol=1e-9, err_msg=f"{e.id}/{name}")
        if e.radius is not None:
            assert mine.radius == pytest.approx(e.radius, abs=1e-9)
    np.testing.assert_allclose(moved.extra["rig"]["matrix_world"], m, atol=1e-12)
    # the stored model of an object moved since: brought to where it stands now
    again = pm.moved_to(rt.procedural_avatar(), m)
    np.testing.assert_allclose(again.joints["head"].world, there.joints["head"].world, atol=1e-9)
    stretch = np.diag([1.0, 1.0, 1.2, 1.0])
    with pytest.raises(BodyCalError, match="scaled unevenly"):
        pm.moved_to(rt.procedural_avatar(), stretch)


@settings(max_examples=12, deadline=None)
@given(method=st.sampled_from(pl.METHODS), yaw=st.floats(-np.pi, np.pi),
       scale=st.floats(0.5, 2.0), x=st.floats(-5.0, 5.0), y=st.floats(-5.0, 5.0), z=st.floats(-1.0, 1.0))
def test_moving_turning_scaling_the_object_moves_the_result_with_it(session, unmoved, method, yaw, scale, x, y, z):
    """The default placement: the world joints of the posed armature are the object's transform
    times the untransformed result (<= 1 mm; the scaled avatar is a scaled body, and its steps
    scale with it), and the pose-bone values (the baked action) are the same numbers."""
    rec, user = session
    m = yaw_scale_move(yaw, scale, (x, y, z))
    avatar = rt.procedural_avatar(matrix_world=m)
    anim = pl.retarget(rec, user, avatar, method)
    base = unmoved[(method, "object")]
    worst = {j: float(np.max(np.linalg.norm(anim.joints_world[j] - apply(m, base.joints_world[j]), axis=-1)))
             for j in base.joints_world}
    assert max(worst.values()) < 1e-3, sorted(worst.items(), key=lambda kv: -kv[1])[:4]
    np.testing.assert_allclose(np.abs((anim.rotations * base.rotations).sum(-1)), 1.0, atol=1e-6)
    np.testing.assert_allclose(anim.root_location, base.root_location, atol=1e-6)
    # and the joints the engine reports are what the armature's FK puts in the world
    pose = ap.AvatarRig.from_model(avatar).fk(anim.rotations, anim.root_location)
    np.testing.assert_allclose(pose.joints[:, sk.JOINT_INDEX["ankle_l"]], anim.joints_world["ankle_l"], atol=1e-4)


@settings(max_examples=6, deadline=None)
@given(method=st.sampled_from(pl.METHODS), yaw=st.floats(-np.pi, np.pi), scale=st.floats(0.6, 1.6),
       x=st.floats(-5.0, 5.0), y=st.floats(-5.0, 5.0), z=st.floats(-1.0, 1.0))
def test_the_performer_placement_keeps_the_room(session, unmoved, method, yaw, scale, x, y, z):
    """Placement "performer": wherever the object stands and however it faces, the avatar plays
    where the performer was, on its own floor; a scaled avatar's path scales about the floor point
    under the performer's pelvis at the reference time."""
    rec, user = session
    m = yaw_scale_move(yaw, scale, (x, y, z))
    anim = pl.retarget(rec, user, rt.procedural_avatar(matrix_world=m), method, placement="performer")
    base = unmoved[(method, "performer")]
    c = ap.root_centre(user)
    for j in base.joints_world:
        want = c + scale * (base.joints_world[j] - c) + [0.0, 0.0, z]
        assert np.max(np.linalg.norm(anim.joints_world[j] - want, axis=-1)) < 1e-3, j


def walked_off(rec, user, offset):
    """The same session with the performer standing `offset` (x, y) away in the play area."""
    rec = copy.copy(rec)
    t = np.array([offset[0], offset[1], 0.0])
    rec.positions = rec.positions + t
    rec.markers = rec.markers + t
    user = copy.deepcopy(user)
    for j in user.joints.values():
        j.world = j.world + t
    for role, pose in user.extra.get("tpose", {}).items():
        user.extra["tpose"][role] = [*(np.asarray(pose[:3]) + t), *pose[3:]]
    return rec, user


def test_the_placements_differ_where_they_should(session):
    """A performer standing off the play-area origin: with the object placement the avatar's pelvis
    is over its object's origin plus the performer's offset scaled by the legs' ratio and turned
    onto the avatar's heading; with the performer placement, over the performer's pelvis."""
    rec, user = walked_off(*session, (1.5, 0.7))
    up = ua.animate_user(rec, user)
    avatar = rt.procedural_avatar(matrix_world=yaw_scale_move(0.0, 1.0, (2.0, -3.0, 0.0)))
    k = ap.root_scale(user, ap.AvatarRig.from_model(avatar))
    to_world = pm.play_area_to_world(avatar, "object")
    for method in ("rotations", "egocentric"):
        obj = pl.retarget(rec, user, avatar, method).joints_world["pelvis"]
        per = pl.retarget(rec, user, avatar, method, placement="performer").joints_world["pelvis"]
        pelvis = up.joint("pelvis")
        np.testing.assert_allclose(obj[:, :2], apply(to_world, k * pelvis)[:, :2], atol=1e-4)
        np.testing.assert_allclose(per[:, :2], ap.root_centre(user)[:2] + k * (pelvis - ap.root_centre(user))[:, :2],
                                   atol=1e-4)
    # the avatar faces -Y: the play area is turned half round, the performer 1.66 m off its origin
    assert np.linalg.norm(obj[0, :2] - [2.0, -3.0]) > 1.5 * k and np.linalg.norm(per[0, :2] - [1.5, 0.7]) < 0.1


def test_warnings_name_a_stretched_object_and_an_implausible_height():
    assert pm.avatar_warnings(rt.procedural_avatar(matrix_world=yaw_scale_move(0.3, 1.1, (2, -3, 0)))) == []
    stretched = rt.procedural_avatar()
    stretched.extra["rig"]["matrix_world"] = np.diag([1.0, 1.0, 1.3, 1.0]).tolist()
    (line,) = pm.avatar_warnings(stretched)
    assert "not uniform" in line and "1.3" in line and "\n" not in line
    tiny = rt.procedural_avatar(matrix_world=yaw_scale_move(0.0, 0.1, (0, 0, 0)))
    (line,) = pm.avatar_warnings(tiny)
    assert "0.17" in line and "tall" in line  # the 1.76 m avatar at a tenth (head joint to toes)
    huge = rt.procedural_avatar(matrix_world=yaw_scale_move(0.0, 100.0, (0, 0, 0)))
    assert "tall" in pm.avatar_warnings(huge)[0]


def test_a_stretched_rig_is_posed_as_its_mean_scale_and_a_mirrored_one_is_refused(session):
    rec, user = session
    stretched = rt.procedural_avatar()
    stretched.extra["rig"]["matrix_world"] = np.diag([1.0, 1.0, 1.1, 1.0]).tolist()
    rig = ap.AvatarRig.from_model(stretched)
    assert rig.w_scale == pytest.approx(1.1 ** (1 / 3))
    np.testing.assert_allclose(rig.w_rot, np.eye(3), atol=1e-12)
    anim = pl.retarget(rec, user, stretched, "rotations")
    assert np.isfinite(anim.rotations).all()
    mirrored = rt.procedural_avatar()
    mirrored.extra["rig"]["matrix_world"] = np.diag([-1.0, 1.0, 1.0, 1.0]).tolist()
    with pytest.raises(BodyCalError, match="mirrored"):
        ap.AvatarRig.from_model(mirrored)
