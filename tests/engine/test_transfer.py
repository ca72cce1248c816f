"""Animation transfer between characters (DESIGN.md §8) without Blender: the source is the
procedural avatar animated by retargeting a synthetic performance onto it (feet planted, hands on
the belly, squats), posed by the rig's own FK; the targets are that avatar itself, scaled and moved
copies, and other builds."""

from __future__ import annotations

import numpy as np
import pytest

from bodycal_addon.avatar import estimate as body_estimate
from bodycal_addon.avatar.armature import read_armature
from bodycal_addon.body import naming, rest_frames
from bodycal_addon.body import skeleton as sk
from bodycal_addon.body import surface_layout as sl
from bodycal_addon.body.skeleton import BONE_INDEX as BI
from bodycal_addon.body.skeleton import JOINT_INDEX as JI
from bodycal_addon.core.errors import BodyCalError
from bodycal_addon.retarget import avatar_pose as ap
from bodycal_addon.retarget import pipeline as pl
from bodycal_addon.retarget import solver_methods as sm
from bodycal_addon.retarget.placement import transformed_avatar
from bodycal_addon.retarget.pose_source import AnimationSource
from bodycal_addon.retarget.solver import PreparedSolver
from bodycal_addon.retarget.transfer import prepare_transfer, stand_on_floor, transfer
from bodycal_dev import retarget_fixtures as rt
from bodycal_dev import synthetic
from sample_rigs import procedural


@pytest.fixture(scope="module")
def source():
    """(the source avatar model, its animation): a performance baked onto the procedural avatar."""
    perf = synthetic.make_performer(seed=0)
    rec, truth = synthetic.record_session(perf, motions=("hand_on_belly", "squat", "clap"), calibration=False,
                                          motion_seconds=1.0, noise_mm=0.0, wobble_mm=0.0)
    avatar = rt.procedural_avatar()
    return avatar, pl.retarget(rec, truth.body_model(), avatar, "egocentric")


def _joints(anim):
    return np.stack([anim.joints_world[j] for j in sk.JOINTS], axis=1)


def _source_joints(avatar, anim):
    return ap.AvatarRig.from_model(avatar).fk(anim.rotations, anim.root_location).joints


@pytest.mark.parametrize("method", ["egocentric", "rotations"])
def test_the_source_itself_as_target_gets_the_source_pose(source, method):
    avatar, anim = source
    out = transfer(avatar, anim.rotations, anim.root_location, anim.time, avatar, method)
    err = np.linalg.norm(_joints(out) - _source_joints(avatar, anim), axis=-1)
    assert err.max() <= 1e-3, (sk.JOINTS[int(np.argmax(err.max(0)))], err.max())
    assert out.bone_names == ap.AvatarRig.from_model(avatar).names


@pytest.mark.parametrize("method", ["egocentric", "rotations"])
def test_a_uniformly_scaled_moved_target_gets_the_scaled_pose(source, method):
    avatar, anim = source
    s = 1.35
    c, si = np.cos(0.6), np.sin(0.6)
    m = np.array([[c, -si, 0, 0.8], [si, c, 0, -0.4], [0, 0, 1, 0.0], [0, 0, 0, 1.0]]) @ np.diag([s, s, s, 1.0])
    big = transformed_avatar(avatar, m)
    out = transfer(avatar, anim.rotations, anim.root_location, anim.time, big, method)
    want = _source_joints(avatar, anim) @ m[:3, :3].T + m[:3, 3]  # the object placement carries the whole motion
    err = np.linalg.norm(_joints(out) - want, axis=-1)
    assert err.max() <= 1e-3 * s, (sk.JOINTS[int(np.argmax(err.max(0)))], err.max())


def test_the_offsets_method_and_bad_arrays_are_one_error(source):
    avatar, anim = source
    with pytest.raises(BodyCalError, match="unknown transfer method 'offsets'"):
        transfer(avatar, anim.rotations, anim.root_location, anim.time, avatar, "offsets")
    with pytest.raises(BodyCalError, match="do not match its rig"):
        transfer(avatar, anim.rotations[:, :-1], anim.root_location, anim.time, avatar)
    bad = anim.rotations.copy()
    bad[3, 2] = np.nan
    with pytest.raises(BodyCalError, match="non-finite"):
        transfer(avatar, bad, anim.root_location, anim.time, avatar)
    with pytest.raises(BodyCalError, match="offsets method needs a tracker recording"):
        PreparedSolver(AnimationSource(avatar, anim.rotations, anim.root_location, anim.time), avatar, "offsets")


def test_a_thicker_target_keeps_the_hand_on_its_belly(source):
    """The point of the feature: a hand resting on a slim belly rests on a big belly, not in it."""
    avatar, anim = source
    big = rt.procedural_avatar(belly=0.12)
    ego = transfer(avatar, anim.rotations, anim.root_location, anim.time, big, "egocentric")
    rot = transfer(avatar, anim.rotations, anim.root_location, anim.time, big, "rotations")
    # the source's palm-to-belly distance against the target's, in the frames the source touches
    from bodycal_addon.retarget import egocentric as ego_mod

    def palm_gap(model, out_anim):
        rig = ap.AvatarRig.from_model(model)
        pose = rig.fk(out_anim.rotations, out_anim.root_location)
        surf_model = sm.canonical_surface(sm.surface_bones(model), rig.frames0, rest_frames.complete_joints(model))
        joints = {j: pose.joints[:, i] for i, j in enumerate(sk.JOINTS)}
        frames = {b.name: pose.frames[:, i] for i, b in enumerate(sk.BONES)}
        torso = ego_mod.pose_surface(surf_model, joints, frames, ["mesh:torso"])
        palm = np.mean([p.local for p in surf_model.element("mesh:palm_r").points.values()], axis=0)
        centre = pose.joints[:, JI["wrist_r"]] + np.einsum("fij,j->fi", pose.frames[:, BI["hand_r"]], palm)
        from bodycal_addon.output import metrics

        return metrics.signed_distances(centre[:, None], torso)[:, 0, 0]

    src_gap = palm_gap(avatar, anim)
    touching = np.abs(src_gap) < 0.02
    assert touching.sum() > 20
    e = np.abs(palm_gap(big, ego)[touching] - src_gap[touching])
    r = np.abs(palm_gap(big, rot)[touching] - src_gap[touching])
    assert np.percentile(e, 95) < 0.5 * np.percentile(r, 95), (np.percentile(e, 95), np.percentile(r, 95))


# --- the bare skeleton's estimated body --------------------------------------------------------------


def _bare_rig(scale=1.0, offset=(0.0, 0.0, 0.0)):
    spec = procedural.build_spec()
    bones = {}
    for name, b in spec.bones.items():
        y = (b.tail - b.head) / np.linalg.norm(b.tail - b.head)
        z = b.z_axis - (b.z_axis @ y) * y
        z /= np.linalg.norm(z)
        bones[name] = {"parent": b.parent, "head": b.head * scale + offset, "tail": b.tail * scale + offset,
                       "matrix": np.stack([np.cross(y, z), y, z], 1)}
    return read_armature("bare", np.eye(4), bones, naming.detect_bone_map(list(bones)))


def test_a_bare_skeleton_gets_every_element_scaled_with_it_and_marked_estimated():
    small = body_estimate.estimate_surface(_bare_rig(), "bare")
    big = body_estimate.estimate_surface(_bare_rig(1.5), "bare")
    assert small.calibration["method"] == "estimated"
    assert {e.id for e in small.surface} == set(sl.element_ids())
    assert all(small.calibration["quality"][e.id] == {"estimated": True} for e in small.surface)
    for b in ("thigh_l", "forearm_r", "index_2_l"):
        assert big.bones[b].radius_head == pytest.approx(1.5 * small.bones[b].radius_head, rel=1e-9)
        assert 0.04 < small.bones[b].radius_head / small.bones[b].length < 0.5
    assert big.element("sphere:skull").radius == pytest.approx(1.5 * small.element("sphere:skull").radius, rel=1e-9)
    # The torso's front is in front of the spine, its back behind it, each riding on a vertebra.
    torso = small.element("mesh:torso")
    assert all(p.bone.startswith("spine_") for p in torso.points.values())
    rig = ap.AvatarRig.from_model(small)
    model = sm.canonical_surface(sm.surface_bones(small), rig.frames0, rest_frames.complete_joints(small))
    world = {n: rig.joint_world[JI[sk.BONE_BY_NAME[p.bone].head]] + rig.frames0[BI[p.bone]] @ p.local
             for n, p in model.element("mesh:torso").points.items()}
    fwd = body_estimate.trunk_axes({j: v.world for j, v in small.joints.items()})[:, 1]
    pelvis = small.joints["pelvis"].world
    assert all((world[n] - pelvis) @ fwd > 0.05 for n in ("sternum", "belly_ul", "belly_c1"))
    assert all((world[n] - pelvis) @ fwd < -0.03 for n in ("back_ul", "back_low"))


def test_a_hanging_skeleton_is_stood_on_its_floor_without_moving_its_motion(source):
    """A BVH's rest hangs from the hips at the origin: the rest is lifted onto its soles, the
    motion's lowest soles put on the floor, and the posed bones move only by that second lift."""
    avatar, anim = source
    bare = body_estimate.estimate_surface(_bare_rig(offset=(0.0, 0.0, -0.95)), "bare")
    rig = ap.AvatarRig.from_model(bare)
    n = len(rig.names)
    basis = np.zeros((40, n, 4))
    basis[..., 0] = 1.0
    locations = np.zeros((40, n, 3))
    locations[:, rig.root] = rig.rest[rig.root].T @ [0.0, 0.0, 0.3]  # the whole body 30 cm up (still below z = 0)
    time = np.arange(40) / 30.0
    before = AnimationSource(bare, basis, locations, time).pose(0, 40).joints
    stood, loc2, lift, motion = stand_on_floor(bare, locations, basis, time)
    after = AnimationSource(stood, basis, loc2, time).pose(0, 40).joints
    # the estimated soles are about where the procedural avatar's feet were before it was hung
    assert lift == pytest.approx(0.95, abs=0.03)
    low = min(before[:, JI[f"ankle_{s}"], 2].min() - body_estimate.sole_depth(bare, s) for s in sk.SIDES)
    assert motion == pytest.approx(-low, abs=1e-9) and motion == pytest.approx(0.95 - 0.3, abs=0.03)
    np.testing.assert_allclose(after, before + [0.0, 0.0, motion], atol=1e-9)
    sole = min(stood.joints[f"ankle_{s}"].world[2] - body_estimate.sole_depth(stood, s) for s in sk.SIDES)
    assert sole == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("method", ["egocentric", "rotations"])
def test_a_prepared_transfer_solves_any_frame_as_the_bake_does(source, method):
    avatar, anim = source
    big = transformed_avatar(avatar, np.diag([1.3, 1.3, 1.3, 1.0]))
    whole = transfer(avatar, anim.rotations, anim.root_location, anim.time, big, method)
    prepared = prepare_transfer(avatar, anim.rotations, anim.root_location, anim.time, big, method)
    for f in np.random.default_rng(2).permutation(len(anim.time))[:15]:  # one frame in mathutils: float32
        one = prepared.solve(f, f + 1)
        np.testing.assert_allclose(one.rotations[0], whole.rotations[f], atol=rt.one_frame_atol("basis"),
                                   err_msg=f"frame {f}")
        np.testing.assert_allclose(one.root_location[0], whole.root_location[f], atol=rt.one_frame_atol("root"))
