"""VMC out (output/vmc_bones.py): the avatar's pose as Unity humanoid bones, checked with
python-osc's own server: a known pose arrives as the same pose (hand-derived quaternions in
Unity's axes), the rest pose relative to a T-pose, and a receiver rebuilding the skeleton from the
messages puts the joints where the pose has them."""

import math

import numpy as np
import pytest
from osc_server import OscServer

from bodycal_addon.body.animation import AvatarAnimation
from bodycal_addon.core import transforms as tf
from bodycal_addon.output.vmc_bones import HUMANOID, AvatarMessages, AvatarVmcOut, VmcHumanoid, animation_pose
from bodycal_addon.recording.live.sender import VmcSender, replay
from bodycal_addon.retarget.avatar_pose import AvatarRig
from bodycal_dev.retarget_fixtures import procedural_avatar

UNITY_NAMES = {"Hips", "Spine", "Chest", "UpperChest", "Neck", "Head", "LeftShoulder", "LeftUpperArm",
               "LeftLowerArm", "LeftHand", "LeftThumbProximal", "LeftThumbIntermediate", "LeftThumbDistal",
               "LeftIndexProximal", "LeftLittleDistal", "RightUpperLeg", "RightLowerLeg", "RightFoot", "RightToes"}


def world_turns(rig: AvatarRig, turns: dict[str, np.ndarray], frames: int = 1) -> AvatarAnimation:
    """An animation of the procedural avatar (armature at the world origin, its rest pose in Blender's
    axes: facing -Y, its left at +X) in which each named bone is turned by a world rotation matrix
    about its head, its parents at rest (basis = M^-1 R M)."""
    basis = np.zeros((frames, len(rig.names), 4))
    basis[..., 0] = 1.0
    for name, r in turns.items():
        i = rig.bone_index[name]
        basis[:, i] = tf.matrix_to_quat(rig.rest[i].T @ r @ rig.rest[i])
    return AvatarAnimation(rig.armature, list(rig.names), basis, rig.names[rig.root], np.zeros((frames, 3)),
                           np.arange(frames) / 30.0)


def rot(axis, deg):
    return tf.quat_to_matrix(tf.axis_angle_to_quat(np.asarray(axis, float), math.radians(deg)))


def bones_of(messages):
    return {args[0]: args[1:] for address, args in messages if address == "/VMC/Ext/Bone/Pos"}


@pytest.fixture(scope="module")
def t_avatar():
    av = procedural_avatar()
    return av, AvatarRig.from_model(av)


def test_a_known_pose_arrives_as_the_same_pose(t_avatar):
    av, rig = t_avatar
    # The left arm lowered 60 degrees (world: about +Y takes +X down), the head turned 30 degrees to
    # the avatar's left (world: about +Z takes its forward -Y toward its left +X).
    anim = world_turns(rig, {"upperarm_l": rot([0, 1, 0], 60), "head": rot([0, 0, 1], 30)})
    rest = world_turns(rig, {})
    with OscServer() as srv, VmcSender("127.0.0.1", srv.port) as sender:
        out = AvatarVmcOut(av, sender)
        out.send_animation_frame(rest, 0)
        srv.wait_for("/VMC/Ext/T", 1)
        before = bones_of(srv.messages)
        srv.messages.clear()
        out.send_animation_frame(anim, 0)
        srv.wait_for("/VMC/Ext/T", 1)
        after = bones_of(srv.messages)
        roots = [args for a, args in srv.messages if a == "/VMC/Ext/Root/Pos"]
    assert UNITY_NAMES <= set(after) and len(after) == len(HUMANOID)
    assert roots == [["root", 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0]]
    for args in after.values():
        assert len(args) == 7 and all(type(v) is float for v in args)
    # Unity: the avatar faces +Z, its left is -X, y up. Lowering the left arm turns -X toward -Y:
    # +60 degrees about +Z, (x, y, z, w) = (0, 0, sin 30, cos 30). Turning the head to its left takes
    # +Z toward -X: -30 degrees about +Y, (0, -sin 15, 0, cos 15).
    s30, c30, s15, c15 = 0.5, math.sqrt(0.75), math.sin(math.radians(15)), math.cos(math.radians(15))
    np.testing.assert_allclose(after["LeftUpperArm"][3:], [0, 0, s30, c30], atol=1e-6)
    np.testing.assert_allclose(after["Head"][3:], [0, -s15, 0, c15], atol=1e-6)
    np.testing.assert_allclose(before["LeftUpperArm"][3:], [0, 0, 0, 1], atol=1e-6)  # a T-pose rig at rest
    np.testing.assert_allclose(before["Head"][3:], [0, 0, 0, 1], atol=1e-6)
    for name in set(after) - {"LeftUpperArm", "Head"}:  # everything else as it was, its children too
        np.testing.assert_allclose(after[name], before[name], atol=1e-6, err_msg=name)
    # Local positions: the hips 0.95 m up; the left upper leg to the avatar's left (-X) of the hips.
    np.testing.assert_allclose(after["Hips"][:3], [0, 0.95, 0], atol=1e-6)
    assert after["LeftUpperLeg"][0] < -0.05 and after["RightUpperLeg"][0] > 0.05


def test_an_a_pose_rig_at_rest_sends_its_arms_lowered_from_the_t_pose():
    av = procedural_avatar(arm_drop_deg=35)
    h = VmcHumanoid(av)
    rig = AvatarRig.from_model(av)
    local, _ = h.local_poses(*animation_pose(world_turns(rig, {}), rig))
    q = {b.name: local[0, i] for i, b in enumerate(HUMANOID)}  # w, x, y, z in Unity's axes
    s, c = math.sin(math.radians(17.5)), math.cos(math.radians(17.5))
    np.testing.assert_allclose(q["LeftUpperArm"], [c, 0, 0, s], atol=1e-9)
    np.testing.assert_allclose(q["RightUpperArm"], [c, 0, 0, -s], atol=1e-9)
    np.testing.assert_allclose(q["LeftLowerArm"], [1, 0, 0, 0], atol=1e-9)  # straight at rest: with its parent


def rebuild(h: VmcHumanoid, local: np.ndarray, hips: np.ndarray) -> np.ndarray:
    """A receiver's FK in Unity's axes: each bone's world turn and head from its parent's and the
    T-pose offsets BodyCal sends (F, U, 3)."""
    offsets = np.array(h._unity_offsets)
    m = tf.quat_to_matrix(local)
    world = np.empty_like(m)
    head = np.empty(local.shape[:2] + (3,))
    for u, p in enumerate(h.parent):
        if p < 0:
            world[:, u], head[:, u] = m[:, u], hips
        else:
            world[:, u] = world[:, p] @ m[:, u]
            head[:, u] = head[:, p] + world[:, p] @ offsets[u]
    return head


@pytest.mark.parametrize("drop", [0.0, 30.0])
def test_a_receiver_rebuilding_the_skeleton_puts_every_joint_where_the_pose_has_it(drop):
    av = procedural_avatar(arm_drop_deg=drop)
    rig = AvatarRig.from_model(av)
    h = VmcHumanoid(av)
    rng = np.random.default_rng(7)
    limbs = [n for n in rig.names if n.rsplit("_", 1)[0] in {"upperarm", "lowerarm", "hand", "thigh", "calf", "foot",
                                                              "head"} or n.startswith(("index", "thumb", "pinky"))]
    anim = world_turns(rig, {}, frames=4)
    for n in limbs:  # random turns of every limb bone, the pelvis moved and turned
        i = rig.bone_index[n]
        anim.rotations[:, i] = tf.axis_angle_to_quat(rng.normal(size=(4, 3)), rng.uniform(0, 1.0, 4))
    anim.root_location[:] = rng.normal(0, 0.2, (4, 3))
    pelvis = rig.bone_index[rig.names[rig.root]]
    anim.rotations[:, pelvis] = tf.axis_angle_to_quat(rng.normal(size=(4, 3)), rng.uniform(0, 0.5, 4))
    frames, joints = animation_pose(anim, rig)
    local, hips = h.local_poses(frames, joints)
    heads = rebuild(h, local, hips)
    # The procedural armature stands at the origin facing -Y: its frame is Blender's turned half
    # round; in Unity's axes (x, y, z) <- (-x, z, -y) of the world.
    want = joints[:, h.head] * [-1, -1, 1]
    want = want[..., [0, 2, 1]]
    limb_bones = [u for u, b in enumerate(HUMANOID) if b.name not in ("UpperChest", "Neck", "Head")
                  and "Shoulder" not in b.name and "Arm" not in b.name and "Hand" not in b.name
                  and not any(f in b.name for f in ("Thumb", "Index", "Middle", "Ring", "Little"))]
    np.testing.assert_allclose(heads[:, limb_bones], want[:, limb_bones], atol=1e-9)
    arm = [u for u, b in enumerate(HUMANOID) if "Arm" in b.name or "Hand" in b.name or "Index" in b.name]
    # The arms hang from the clavicles, whose canonical joint rides the spine here: rigid with the
    # UpperChest the spine is at rest in these poses, so exact too.
    np.testing.assert_allclose(heads[:, arm], want[:, arm], atol=1e-9)


def test_an_engine_animation_streams_every_bone_every_frame(t_avatar):
    av, rig = t_avatar
    anim = world_turns(rig, {"upperarm_l": rot([0, 1, 0], 20)}, frames=5)
    take = AvatarMessages(anim, av, chunk=2)
    with OscServer() as srv, VmcSender("127.0.0.1", srv.port) as sender:
        replay(take, sender, speed=50.0)
        srv.wait_for("/VMC/Ext/T", 5)
    bones = [args[0] for a, args in srv.messages if a == "/VMC/Ext/Bone/Pos"]
    assert len(bones) == 5 * len(HUMANOID) and set(bones) == {b.name for b in HUMANOID}
    assert [args for a, args in srv.messages if a == "/VMC/Ext/T"] == [[float(np.float32(t))] for t in anim.time]
