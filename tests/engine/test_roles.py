"""Role identification from the T-pose (AvatarGo §3.2): shuffled device names, null
roles, any facing direction, both profiles, and through every file convention."""

from __future__ import annotations

import json

import numpy as np
import pytest
from recording_fixtures import body_axes, recording_doc, tpose_recording

from bodycal_addon.core import transforms as tf
from bodycal_addon.core.errors import BodyCalError
from bodycal_addon.recording import io as rio
from bodycal_addon.recording import roles


def _truth(**kw):
    rec = tpose_recording(roles=True, **kw)
    return {d.name: d.role for d in rec.devices}


@pytest.mark.parametrize("profile", ["full", "minimal"])
@pytest.mark.parametrize("yaw", [0.0, 0.9, 2.4, -1.7, np.pi])
def test_roles_from_tpose_any_facing(profile, yaw):
    kw = dict(yaw=yaw, profile=profile, shuffle=True, seed=int(10 * (yaw + 4)))
    rec = tpose_recording(roles=False, **kw)
    assert all(d.name.startswith("LHR-") for d in rec.devices)
    assert roles.identify_roles(rec) == _truth(**kw)


def test_load_applies_roles_and_reports_them(tmp_path):
    kw = dict(yaw=0.5, profile="full", shuffle=True, seed=7)
    path = tmp_path / "nameless.bcrec.json"
    path.write_text(json.dumps(recording_doc(tpose_recording(roles=False, **kw))))
    rec = rio.load_recording(path)
    assert {d.name: d.role for d in rec.devices} == _truth(**kw)
    note = next(n for n in rec.notes if n.startswith("roles identified"))
    assert "AvatarGo" in note and "ahead of the body plane" in note and "=head" in note


@pytest.mark.parametrize("coords", [("Y", "right", "m"), ("Y", "left", "cm"), ("Z", "left", "mm")])
def test_roles_survive_file_conventions(tmp_path, coords):
    kw = dict(yaw=-0.6, profile="minimal", shuffle=True, seed=3)
    rec = tpose_recording(roles=False, **kw)
    rio.save_recording(rec, tmp_path / "r.bcrec.json", up=coords[0], handedness=coords[1], units=coords[2])
    back = rio.load_recording(tmp_path / "r.bcrec.json")
    assert {d.name: d.role for d in back.devices} == _truth(**kw)


def test_given_roles_are_kept_and_not_reused():
    kw = dict(yaw=1.2, profile="full", shuffle=True, seed=5)
    rec = tpose_recording(roles=False, **kw)
    truth = _truth(**kw)
    # The performer labelled two devices; one of them wrongly (a thigh tracker called the chest).
    thigh = next(n for n, r in truth.items() if r == "thigh_l")
    head = next(n for n, r in truth.items() if r == "head")
    for d in rec.devices:
        d.role = {thigh: "chest", head: "head"}.get(d.name)
    found = roles.identify_roles(rec)
    assert found[thigh] == "chest" and found[head] == "head"
    assert list(found.values()).count("chest") == 1
    real_chest = next(n for n, r in truth.items() if r == "chest")
    assert found.get(real_chest) != "chest"
    assert found[next(n for n, r in truth.items() if r == "hand_r")] == "hand_r"


def test_facing_from_geometry_even_when_the_hmd_looks_up():
    kw = dict(yaw=2.0, profile="full", shuffle=True, seed=11)
    rec = tpose_recording(roles=False, **kw)
    h = next(i for i, d in enumerate(rec.devices) if d.kind == "hmd")
    # Looking at the ceiling: the view direction says nothing about the facing.
    look_up = np.array([0.0, 1.0, 0.0, 0.0])  # half turn about X: local -Z (the view) to world +Z
    rec.rotations[:, h] = look_up
    assert np.allclose(tf.rotate(look_up, [0, 0, -1.0]), [0, 0, 1])
    rec2 = tpose_recording(roles=False, **kw)
    rec2.rotations[:, h] = look_up
    rec2.notes = []
    assert roles.identify_roles(rec) == _truth(**kw)
    roles.apply_roles(rec2)
    assert "HMD and feet ahead of the body plane" in rec2.notes[-1]


def _flatten_onto_body_plane(rec, yaw):
    """Every device moved into the frontal plane: geometry can no longer tell front from back."""
    _left, fwd, _up = body_axes(yaw)
    rec.positions -= ((rec.positions - rec.positions[:1].mean(axis=1, keepdims=True)) @ fwd)[..., None] * fwd


def test_upright_hmd_view_decides_when_geometry_cannot():
    kw = dict(yaw=0.4, profile="full", shuffle=True, seed=2)
    rec = tpose_recording(roles=False, **kw)
    _flatten_onto_body_plane(rec, 0.4)
    assert roles.identify_roles(rec) == _truth(**kw)
    roles.apply_roles(rec)
    assert "HMD view direction" in rec.notes[-1]
    # The same devices with the HMD turned round (still upright): left and right swap.
    back = tpose_recording(roles=False, **kw)
    _flatten_onto_body_plane(back, 0.4)
    h = next(i for i, d in enumerate(back.devices) if d.kind == "hmd")
    back.rotations[:, h] = tf.quat_mul(tf.axis_angle_to_quat(np.array([0, 0, 1.0]), np.pi), back.rotations[:, h])
    mirrored = {n: r.replace("_l", "_X").replace("_r", "_l").replace("_X", "_r") for n, r in _truth(**kw).items()}
    assert roles.identify_roles(back) == mirrored


def test_no_tpose_or_too_few_devices(tmp_path):
    rec = tpose_recording(roles=False, profile="minimal")
    rec.segments = [s for s in rec.segments if s.step != "tpose"]
    with pytest.raises(BodyCalError, match="no tpose segment"):
        roles.identify_roles(rec)
    path = tmp_path / "r.bcrec.json"
    path.write_text(json.dumps(recording_doc(rec)))
    loaded = rio.load_recording(path)  # no tpose: roles stay unknown, no error at load, a note says so
    assert all(d.role is None for d in loaded.devices)
    assert any("no tpose segment" in n for n in loaded.notes)
    rec = tpose_recording(roles=False, profile="minimal")
    rec.valid[:, 1:4] = False
    with pytest.raises(BodyCalError, match="only 3 devices tracked"):
        roles.identify_roles(rec)


@pytest.mark.parametrize("profile", ["full", "minimal"])
@pytest.mark.parametrize("build, seed", [("child", 1), ("average", 0), ("heavy", 3), ("long_arms", 2)])
def test_roles_of_the_synthetic_performer(profile, build, seed):
    from bodycal_dev import synthetic
    perf = synthetic.make_performer(build=build, seed=seed)
    rec, _truth_ = synthetic.record_session(perf, profile=profile, calibration=["tpose"], motions=(), seed=seed)
    truth = {d.name: d.role for d in rec.devices}
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(rec.devices))  # shuffled names, no roles
    rec.devices = [rec.devices[i] for i in order]
    rec.positions, rec.rotations, rec.valid = rec.positions[:, order], rec.rotations[:, order], rec.valid[:, order]
    for k, d in enumerate(rec.devices):
        truth[f"dev{k}"] = truth.pop(d.name)
        d.name, d.role = f"dev{k}", None
    assert roles.identify_roles(rec) == truth


@pytest.mark.parametrize("missing", ["forearm_l", "forearm_r", "shin_l", "shin_r", "upperarm_l", "thigh_r"])
@pytest.mark.parametrize("yaw", [0.0, 2.4])
def test_one_limb_role_left_empty_is_identified(missing, yaw):
    """Every role given but one limb tracker's: the T-pose names it (FORMATS §2.1), whichever of the
    limb's two devices it is (issue 40: a free forearm was offered the given upper arm's role and
    dropped; a free shin the given thigh's)."""
    kw = dict(yaw=yaw, profile="full", shuffle=True, seed=4)
    rec = tpose_recording(roles=True, **kw)
    truth = {d.name: d.role for d in rec.devices}
    name = next(n for n, r in truth.items() if r == missing)
    next(d for d in rec.devices if d.name == name).role = None
    assert roles.identify_roles(rec) == truth
    roles.apply_roles(rec)
    assert next(d for d in rec.devices if d.name == name).role == missing
    assert "no role for" not in rec.notes[-1]


def test_both_forearms_and_both_shins_left_empty_are_identified():
    kw = dict(yaw=-0.9, profile="full", shuffle=True, seed=8)
    rec = tpose_recording(roles=True, **kw)
    truth = {d.name: d.role for d in rec.devices}
    for d in rec.devices:
        if d.role.startswith(("forearm", "shin")):
            d.role = None
    assert roles.identify_roles(rec) == truth


def _with_extra_device(rec, like: str, name: str = "LHR-EXTRA", shift=(0.0, 0.0, -0.04)):
    """`rec` with one more tracker without a role, strapped a few cm from the `like` role's."""
    from bodycal_addon.recording.model import Device, Recording
    k = rec.device_index(like)
    return Recording(rec.name, rec.time, rec.devices + [Device(name, "tracker", None)],
                     np.concatenate([rec.positions, rec.positions[:, k:k + 1] + np.asarray(shift)], axis=1),
                     np.concatenate([rec.rotations, rec.rotations[:, k:k + 1]], axis=1),
                     np.concatenate([rec.valid, rec.valid[:, k:k + 1]], axis=1), segments=rec.segments)


def test_unused_devices_say_where_they_are_and_what_they_could_be():
    """A device left without a role: where the T-pose places it and the roles free there (issue 40:
    what `calibrate-user` warns about)."""
    rec = tpose_recording(roles=True, yaw=0.7)
    assert roles.unused_devices(rec) == {}
    # A third tracker on the left arm beside the given upper arm and forearm: nothing free there.
    extra = _with_extra_device(rec, "forearm_l")
    assert roles.identify_roles(extra).get("LHR-EXTRA") is None
    assert roles.unused_devices(extra) == {"LHR-EXTRA": ("on the left arm", ())}
    # The right shin's tracker hidden through the T-pose: it cannot be placed, so it may be any role
    # no device holds (here only its own).
    hidden = tpose_recording(roles=True, yaw=0.7)
    k = hidden.device_index("shin_r")
    hidden.devices[k].role = None
    tpose = hidden.segments_of("tpose")[0]
    hidden.valid[hidden.frames(tpose.start, tpose.end), k] = False
    assert roles.identify_roles(hidden).get("shin_r") is None
    assert roles.unused_devices(hidden) == {"shin_r": ("not tracked in the tpose segment", ("shin_r",))}
    # Seen in the T-pose (the roles not identified yet): on the right leg, where both roles are free.
    seen = tpose_recording(roles=True, yaw=0.7)
    seen.devices[seen.device_index("shin_r")].role = None
    seen.devices[seen.device_index("thigh_r")].role = None
    placed = roles.unused_devices(seen)
    assert placed == {"thigh_r": ("on the right leg", ("thigh_r", "shin_r")),
                      "shin_r": ("on the right leg", ("thigh_r", "shin_r"))}
    # No T-pose at all.
    seen.segments = [s for s in seen.segments if s.step != "tpose"]
    where, could = roles.unused_devices(seen)["shin_r"]
    assert where.startswith("the T-pose cannot place it: no tpose segment") and could == ("thigh_r", "shin_r")
