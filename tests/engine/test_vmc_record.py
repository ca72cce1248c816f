"""The live recorder (recording/live/recorder.py): frames in arrival order into a FORMATS.md
recording, gaps as untracked frames, the sender's clock or the arrival clock, calibration steps
marked while recording, roles, and files written whole."""

import json

import numpy as np
import pytest
from recording_fixtures import tpose_recording

from bodycal_addon.core.errors import BodyCalError
from bodycal_addon.recording.io import load_recording
from bodycal_addon.recording.live.recorder import LiveRecorder
from bodycal_addon.recording.live.source import LiveFrame
from bodycal_addon.recording.model import Segment

ID = (1.0, 0.0, 0.0, 0.0)


def frame(k, devices, arrival=None, sender=None, markers=(), events=()):
    """Frame k with `devices` at x = k (device i at y = i), arriving as the sender's clock says."""
    names = tuple(devices)
    pos = np.array([[float(k), float(int(n[-1])), 1.0] for n in names]).reshape(-1, 3)
    pts = np.array([[float(k), 5.0, 1.0] for _ in markers]).reshape(-1, 3)
    if arrival is None:  # a sender whose clock keeps to arrival's (else the take follows arrival)
        arrival = 100.0 + (k / 90 if sender is None else sender)
    return LiveFrame(k, arrival, sender, names, pos,
                     np.tile(ID, (len(names), 1)), tuple(markers), pts, tuple(events))


def test_gaps_are_untracked_frames_and_a_late_device_is_untracked_before():
    rec = LiveRecorder("take")
    for k, devs in enumerate([["d0"], ["d0", "d1"], ["d1"], [], ["d0", "d1"]]):
        rec(frame(k, devs, sender=k / 90, markers=["m1"] if k % 2 else []))
    r = rec.recording()
    assert [d.name for d in r.devices] == ["d0", "d1"]
    assert r.valid.tolist() == [[True, False], [True, True], [False, True], [False, False], [True, True]]
    assert r.marker_valid[:, 0].tolist() == [False, True, False, True, False]
    np.testing.assert_allclose(r.positions[4], [[4, 0, 1], [4, 1, 1]])
    np.testing.assert_allclose(r.time, np.arange(5) / 90)


def test_the_senders_clock_when_it_moves_forward_else_the_arrival_clock():
    rec = LiveRecorder()
    arrivals = [10.0, 10.5, 10.52, 11.0, 11.01]
    senders = [2.0, 2.1, 2.05, None, 2.3]  # back in time, then missing
    for k, (a, s) in enumerate(zip(arrivals, senders)):
        rec(frame(k, ["d0"], arrival=a, sender=s))
    r = rec.recording()
    # 2.0; +0.1 (sender); +0.02 (arrival: the sender went back); +0.48 (arrival: none); +0.01 (arrival)
    np.testing.assert_allclose(r.time, [2.0, 2.1, 2.12, 2.6, 2.61])
    assert not rec.sender_clock
    same = LiveRecorder()
    for k in range(3):
        same(frame(k, ["d0"], arrival=5.0, sender=None))  # one datagram ended three frames
    assert np.all(np.diff(same.recording().time) > 0)


def test_calibration_steps_marked_while_recording():
    rec = LiveRecorder()
    rec(frame(0, ["d0"], sender=0.0))
    assert rec.mark_segment_start("tpose") == 0.0
    for k in range(1, 10):
        rec(frame(k, ["d0"], sender=k * 0.1))
    seg = rec.mark_segment_end()
    assert (seg.step, seg.start, seg.end) == ("tpose", 0.0, pytest.approx(0.9))
    rec.mark_segment_start("touch", point="chin", by="d0")
    rec(frame(10, ["d0"], sender=1.0))
    rec.mark_segment_start("motion")  # ends the open touch first
    rec(frame(11, ["d0"], sender=1.1))
    rec.mark_segment_end()
    labels = [(s.label, s.start, s.end) for s in rec.recording().segments]
    assert labels == [("tpose", 0.0, pytest.approx(0.9)), ("touch:chin:d0", pytest.approx(0.9), 1.0),
                      ("motion", 1.0, pytest.approx(1.1))]
    with pytest.raises(BodyCalError, match="unknown step"):
        rec.mark_segment_start("cartwheel")
    with pytest.raises(BodyCalError, match="unknown touch point"):
        rec.mark_segment_start("touch", point="elbow_tip_l")
    with pytest.raises(BodyCalError, match="no calibration step is open"):
        rec.mark_segment_end()


def test_announced_steps_that_do_not_fit_are_left_out_with_a_note():
    rec = LiveRecorder()
    rec(frame(0, ["d0"], sender=0.0, events=[("segment", Segment("touch", 0.0, 0.05, "chin", "ghost_tip"))]))
    rec(frame(1, ["d0"], sender=0.1, events=[("segment", Segment("tpose", 0.0, 0.1)),
                                              ("segment", Segment("stand", 0.5, 0.9))]))
    r = rec.recording()
    assert [s.step for s in r.segments] == ["tpose"]
    assert len([n for n in r.notes if n.startswith("calibration step left out")]) == 2


def test_roles_the_users_win_over_the_streams_and_are_checked():
    rec = LiveRecorder(roles={"d1": "pelvis"})
    rec(frame(0, ["d0", "d1", "d2"], events=[("device", "d0", "hmd", "head"), ("device", "d1", "tracker", "chest"),
                                             ("device", "d2", "tracker", "head")]))
    r = rec.recording()
    assert [(d.name, d.kind, d.role) for d in r.devices] == [("d0", "hmd", "head"), ("d1", "tracker", "pelvis"),
                                                             ("d2", "tracker", None)]
    assert any("role head of d2 left out" in n for n in r.notes)
    with pytest.raises(BodyCalError, match="unknown role"):
        LiveRecorder(roles={"d0": "tail"})
    with pytest.raises(BodyCalError, match="given to both"):
        LiveRecorder(roles={"d0": "head", "d1": "head"})


def test_limit_records_that_many_seconds_then_says_full():
    rec = LiveRecorder(limit_s=0.25)
    for k in range(10):
        rec(frame(k, ["d0"], sender=k * 0.1))
    assert rec.full.is_set() and rec.frames == 3 and rec.duration == pytest.approx(0.2)


def test_nothing_recorded_is_one_clear_error():
    with pytest.raises(BodyCalError, match="no device or marker arrived"):
        LiveRecorder().recording()


@pytest.mark.parametrize("suffix", [".bcrec.json", ".csv"])
def test_saved_whole_and_read_back_as_recorded(tmp_path, suffix):
    rec = LiveRecorder("take")
    rec(frame(0, ["d0", "d1"], sender=0.0, markers=["index_tip_r"],
              events=[("device", "d0", "hmd", None), ("marker", "index_tip_r")]))
    rec(frame(1, ["d1"], sender=0.1, markers=["index_tip_r"]))
    rec(frame(2, ["d0", "d1"], sender=0.2))
    out = tmp_path / f"take{suffix}"
    written = rec.save(out)
    assert written[0] == out and all(p.is_file() for p in written)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(p.name for p in written)  # no temporary left
    back = load_recording(out, raw=True)
    mem = rec.recording()
    np.testing.assert_allclose(back.time, mem.time)
    np.testing.assert_allclose(back.positions[back.valid], mem.positions[mem.valid])
    assert back.valid.tolist() == mem.valid.tolist() and back.marker_valid.tolist() == mem.marker_valid.tolist()
    assert [(d.name, d.kind) for d in back.devices] == [("d0", "hmd"), ("d1", "tracker")]
    header = json.loads((out if suffix == ".bcrec.json" else out.with_suffix(".json")).read_text())
    assert header["extra"]["live"]["clock"] == "sender" and header["coords"]["up"] == "Z"
    with pytest.raises(BodyCalError, match="already exists"):
        rec.save(out)


def test_roles_from_a_t_pose_recorded_live():
    take = tpose_recording(roles=False, shuffle=True, yaw=0.7)
    truth = {d.name: r for d, r in zip(take.devices, tpose_recording(roles=True, shuffle=True, yaw=0.7).devices)}
    rec = LiveRecorder(roles={"LHR-00": truth["LHR-00"].role})
    for k in range(take.frame_count):
        rec(LiveFrame(k, float(k), float(take.time[k]), tuple(d.name for d in take.devices), take.positions[k],
                      take.rotations[k]))
        if k == 10:
            rec.mark_segment_start("tpose")
        if k == 150:
            rec.mark_segment_end()
    found = rec.identify_roles()
    assert "LHR-00" not in found  # the user's role stays the user's
    assert {d.name: d.role for d in rec.recording().devices} == {n: d.role for n, d in truth.items()}
    with pytest.raises(BodyCalError, match="no tpose segment"):
        _no_tpose()


def _no_tpose():
    rec = LiveRecorder()
    rec(frame(0, ["d0"]))
    rec.identify_roles()
