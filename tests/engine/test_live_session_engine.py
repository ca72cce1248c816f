"""The live session (retarget/live_session.py), fed by a source stand-in on this thread: the device
table (kinds, roles with the user's first, rates, frames missed), the recorder seeing every frame
while the pump takes only the newest, and a follower that waits for the roles it needs and then
gives LiveSolver's poses."""

import numpy as np
import pytest

from bodycal_addon.core.errors import BodyCalError
from bodycal_addon.recording.live.source import LatestSlot, LiveFrame, SourceStats
from bodycal_addon.retarget.live import LiveSolver
from bodycal_addon.retarget.live_session import LiveSession
from bodycal_dev import synthetic
from bodycal_dev.retarget_fixtures import procedural_avatar


class Source:
    """A LiveSource that delivers what the test gives it, as VmcReceiver does: sinks, then the slot."""

    def __init__(self):
        self.stats, self.sinks, self.slot = SourceStats(), [], LatestSlot()

    def start(self):
        pass

    def stop(self):
        pass

    def latest(self):
        return self.slot.take()

    def wait(self, timeout):
        return self.slot.wait(timeout)

    def add_sink(self, sink):
        self.sinks.append(sink)

    def deliver(self, frame):
        for sink in self.sinks:
            sink(frame)
        self.slot.put(frame)
        self.stats.dropped = self.slot.dropped


@pytest.fixture(scope="module")
def take():
    perf = synthetic.make_performer(seed=4)
    rec, truth = synthetic.record_session(perf, motions=("clap",), calibration=["tpose"], noise_mm=0.0,
                                          wobble_mm=0.0)
    return rec, truth.body_model()


def frame_of(rec, k, *, announce=False, arrival=None, markers=False):
    v = rec.valid[k]
    events = tuple(("device", d.name, d.kind, d.role) for d in rec.devices) if announce else ()
    mv = rec.marker_valid[k] if markers else np.zeros(len(rec.marker_names), bool)
    return LiveFrame(k, float(rec.time[k]) if arrival is None else arrival, float(rec.time[k]),
                     tuple(d.name for d, ok in zip(rec.devices, v, strict=True) if ok), rec.positions[k, v],
                     rec.rotations[k, v], tuple(n for n, ok in zip(rec.marker_names, mv, strict=True) if ok),
                     rec.markers[k, mv], events=events)


def test_the_device_table_says_kinds_roles_rates_and_frames_missed(take):
    rec, _user = take
    source = Source()
    first = rec.devices[0].name
    session = LiveSession(source, roles={first: "pelvis"})  # the user's role wins over the stream's
    for k in range(90):
        frame = frame_of(rec, k, announce=k == 0, arrival=k / 90.0)
        if 30 <= k < 40:  # the last device out of view for ten frames
            frame.devices, frame.positions, frame.rotations = frame.devices[:-1], frame.positions[:-1], \
                frame.rotations[:-1]
        source.deliver(frame)
    table = {d.name: d for d in session.devices(now=89 / 90.0)}
    assert list(table) == [d.name for d in rec.devices]
    assert table[first].role == "pelvis"
    last = rec.devices[-1]
    assert table[last.name].kind == last.kind and table[last.name].role == last.role
    assert table[last.name].missed == 10 and table[last.name].frames == 80
    assert table[rec.devices[1].name].rate_hz == pytest.approx(90.0)
    assert session.frames_seen == 90


def test_the_recorder_gets_every_frame_the_pump_only_the_newest(take):
    rec, _user = take
    source = Source()
    session = LiveSession(source)
    recorder = session.start_recording("take")
    with pytest.raises(BodyCalError, match="already recording"):
        session.start_recording("again")
    for k in range(20):
        source.deliver(frame_of(rec, k, announce=k == 0))
        if k % 5 == 4:
            assert session.pump().frame.index == k  # the newest; the ones before it skipped, counted
    assert session.stop_recording() is recorder and session.recorder is None
    # Drops count from the first take (source.LatestSlot): four replaced between each later pump.
    assert recorder.frames == 20 and source.stats.dropped == 3 * 4
    again = recorder.recording()
    assert [d.role for d in again.devices] == [d.role for d in rec.devices]  # announced before Record: kept


def test_a_follower_waits_for_its_roles_then_gives_live_solvers_poses(take):
    rec, user = take
    avatar = procedural_avatar()
    source = Source()
    session = LiveSession(source)
    follower = session.follow("avatar", user, avatar, "egocentric")
    source.deliver(frame_of(rec, 0))  # nothing announced: no role yet
    assert session.pump().poses["avatar"] is None and "head" in follower.waiting_for
    session.user_roles.update({d.name: d.role for d in rec.devices if d.role})
    ref = None
    for k in range(1, 30):
        source.deliver(frame_of(rec, k))
        update = session.pump()
        solved = update.poses["avatar"]
        if ref is None:
            ref = LiveSolver(user, avatar, "egocentric", devices=follower.solver.recording.devices)
        v = rec.valid[k]
        order = [i for i, d in enumerate(rec.devices) if d.name in follower.order]
        want = ref.push(rec.time[k], rec.positions[k, order], rec.rotations[k, order], v[order])
        session.posed(update, "avatar")
    assert follower.waiting_for == [] and follower.stats.frames == 29
    np.testing.assert_array_equal(solved.basis, want.basis)
    assert len(follower.stats.latency_ms) == 29 and "latency" in follower.stats.line()


def test_a_follower_poses_the_fingers_from_the_streams_markers(take):
    """LED glove markers in the stream pose the avatar's fingers as they do in a bake: the follower
    gives what a LiveSolver fed the same markers gives, and not what one without them gives."""
    rec, user = take
    assert rec.marker_names  # the full profile's gloves
    avatar = procedural_avatar()
    source = Source()
    session = LiveSession(source, roles={d.name: d.role for d in rec.devices if d.role})
    follower = session.follow("avatar", user, avatar, "egocentric")
    order = [i for i, d in enumerate(rec.devices) if d.role]
    devices = [rec.devices[i] for i in order]
    with_markers = LiveSolver(user, avatar, "egocentric", devices=devices, marker_names=list(rec.marker_names))
    without = LiveSolver(user, avatar, "egocentric", devices=devices)
    for k in range(20):
        source.deliver(frame_of(rec, k, markers=True))
        solved = session.pump().poses["avatar"]
        f = slice(k, k + 1)
        want = with_markers.push(rec.time[f], rec.positions[f][:, order], rec.rotations[f][:, order],
                                 rec.valid[f][:, order], rec.markers[f], rec.marker_valid[f])
        bare = without.push(rec.time[f], rec.positions[f][:, order], rec.rotations[f][:, order],
                            rec.valid[f][:, order])
    assert list(follower.marker_order) == list(rec.marker_names)
    np.testing.assert_array_equal(solved.basis, want.basis)
    fingers = [i for i, n in enumerate(follower.bone_names) if "index" in n.lower() or "thumb" in n.lower()]
    assert fingers and np.abs(solved.basis[:, fingers] - bare.basis[:, fingers]).max() > 1e-3


def test_the_pump_learns_the_streams_beat_and_says_when_to_look_again(take):
    rec, _user = take
    source = Source()
    session = LiveSession(source)
    for k in range(10):  # frames arriving every 1/90 s (the arrival clock is the test's), each pumped
        source.deliver(frame_of(rec, k, arrival=1.0 + k / 90.0))
        assert session.next_delay(now=1.0 + k / 90.0) == 0.0  # a frame waits: at once
        update = session.pump()
        assert update.frame.index == k and update.solved_at == {}
        assert session.pump() is None  # never the same frame twice
    assert session.clock.period == pytest.approx(1 / 90.0)
    now = 1.0 + 9 / 90.0 + 0.004  # 4 ms after the last frame: the next is due 1/90 s after it
    assert session.next_delay(now) == pytest.approx(1 / 90.0 - 0.004 + session.clock.margin_s)
