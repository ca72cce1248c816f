"""Role identification from the T-pose (AvatarGo, paper 004 §3.2): shuffled device names, null
roles, any facing direction, both profiles, and through every file convention."""

from __future__ import annotations

import json

import numpy as np
import pytest
from recording_fixtures import recording_doc, tpose_recording

from bodycal_addon import recording_io as rio
from bodycal_addon import roles
from bodycal_addon import transforms as tf
from bodycal_addon.errors import BodyCalError


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
    assert "paper 004" in note and "HMD view direction" in note and "=head" in note


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


def test_facing_from_geometry_when_the_hmd_looks_up():
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
    assert "in front of the body plane" in rec2.notes[-1]


def test_no_tpose_or_too_few_devices(tmp_path):
    rec = tpose_recording(roles=False, profile="minimal")
    rec.segments = [s for s in rec.segments if s.step != "tpose"]
    with pytest.raises(BodyCalError, match="no tpose segment"):
        roles.identify_roles(rec)
    path = tmp_path / "r.bcrec.json"
    path.write_text(json.dumps(recording_doc(rec)))
    loaded = rio.load_recording(path)  # no tpose: roles stay unknown, no error at load
    assert all(d.role is None for d in loaded.devices)
    rec = tpose_recording(roles=False, profile="minimal")
    rec.valid[:, 1:4] = False
    with pytest.raises(BodyCalError, match="only 3 devices tracked"):
        roles.identify_roles(rec)
