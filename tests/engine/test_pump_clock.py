"""The pump's clock (live/pump_clock.py) on an injected clock: a simulated stream whose frames
arrive at a known period (with the network's delays, late frames, pauses) and a simulated pump that
takes the newest frame when it looks, solves it for a while and asks the clock when to look again.
No wall clock: every time here is a number the test chose."""

import threading

import numpy as np
import pytest

from bodycal_addon.live.pump_clock import PumpClock
from bodycal_addon.recording.live.source import LatestSlot, LiveFrame

P = 1.0 / 90.0


def simulate(arrivals, solve_s: float, clock: PumpClock | None = None, *, fixed_s: float | None = None,
             start: float = 0.0):
    """The pump's loop over frames arriving at `arrivals` (frame k at arrivals[k], in order): at
    each look the newest frame arrived and not yet taken is taken (latest wins), solved for
    `solve_s`, then the next look is `clock.next_delay` later (or every `fixed_s`, a fixed timer).
    Returns {index: (arrival, taken)} and the times the pump looked."""
    arrivals = np.asarray(arrivals, float)
    now, last, taken, looks = start, -1, {}, []
    while now <= arrivals[-1] + 0.1:
        looks.append(now)
        newest = int(np.searchsorted(arrivals, now, side="right")) - 1
        if newest > last:
            taken[newest] = (arrivals[newest], now)
            last = newest
            if clock is not None:
                clock.taken(newest, arrivals[newest])
            now += solve_s
        if fixed_s is not None:
            now = looks[-1] + fixed_s if now < looks[-1] + fixed_s else now
            continue
        pending = int(np.searchsorted(arrivals, now, side="right")) - 1 > last
        delay = clock.next_delay(now, pending)
        assert delay >= 0.0
        now += delay
    return taken, np.asarray(looks)


def waits(taken, first: int = 0):
    return np.array([t - a for k, (a, t) in sorted(taken.items()) if k >= first])


def test_a_steady_stream_is_taken_a_margin_after_each_arrival_with_one_look_per_frame():
    clock = PumpClock()
    arrivals = 0.3 + P * np.arange(300)
    taken, looks = simulate(arrivals, 0.006, clock, start=0.0)
    assert sorted(taken) == list(range(300))  # every frame, each once
    # Frames 0 and 1 are taken at the display rate (no beat yet: frame 1 waits for frame 0's solve,
    # frame 2 for frame 1's); from frame 3 on the pump looks when each frame is due.
    w = waits(taken, first=3)
    assert w.max() <= clock.margin_s + 1e-9
    assert clock.period == pytest.approx(P, rel=1e-9)
    locked = looks[(looks > arrivals[3]) & (looks <= arrivals[-1] + clock.margin_s)]
    assert len(locked) == 300 - 3  # frames 3..299: a look per frame, no polling while the beat holds


def test_the_clock_waits_far_less_than_a_fixed_timer_unsynchronised_with_the_stream():
    arrivals = 0.0037 + P * np.arange(300)
    fixed, _ = simulate(arrivals, 0.002, fixed_s=P)
    locked, _ = simulate(arrivals, 0.002, PumpClock())
    assert waits(fixed, 2).mean() > 4.0 * waits(locked, 2).mean()


def test_frames_delayed_by_the_network_are_taken_within_a_poll_of_their_arrival():
    rng = np.random.default_rng(7)
    jitter = 0.002
    clock = PumpClock()
    arrivals = np.sort(P * np.arange(600) + rng.uniform(0.0, jitter, 600))
    taken, _ = simulate(arrivals, 0.005, clock)
    assert sorted(taken) == list(range(600))
    # The beat is projected from the least delayed recent frame: a frame is looked for at most a
    # margin after it should have come, and a later one is found by the next poll.
    assert waits(taken, first=10).max() <= jitter + clock.margin_s + clock.poll_s
    assert np.median(waits(taken, first=10)) <= clock.margin_s + clock.poll_s


def test_a_late_frame_is_still_taken_and_the_beat_kept():
    clock = PumpClock()
    arrivals = P * np.arange(100)
    arrivals[50] += 0.6 * P  # held up, still before frame 51
    taken, looks = simulate(arrivals, 0.004, clock)
    assert sorted(taken) == list(range(100))
    a, t = taken[50]
    assert 0.0 <= t - a <= clock.poll_s + 1e-9
    assert waits(taken, first=52).max() <= clock.margin_s + 1e-9  # the beat was not lost to one late frame
    polled = looks[(looks > P * 50) & (looks < a)]
    assert len(polled) >= 2 and np.diff(polled).max() <= clock.poll_s + 1e-9  # looked for often meanwhile


def test_a_pause_falls_back_to_the_display_rate_and_the_next_frames_relock():
    clock = PumpClock()
    arrivals = np.concatenate([P * np.arange(60), 3.0 + 0.004 + P * np.arange(60)])  # a new phase after it
    taken, looks = simulate(arrivals, 0.004, clock)
    assert sorted(taken) == list(range(120))
    idle = np.diff(looks[(looks > 1.0) & (looks < 2.9)])
    assert idle.min() == pytest.approx(clock.display_s)  # no busy polling while nothing comes
    assert waits({k: v for k, v in taken.items() if k >= 63}).max() <= clock.margin_s + 1e-9


def test_a_pump_slower_than_the_stream_takes_the_newest_frame_at_once_and_keeps_the_period():
    clock = PumpClock()
    arrivals = P * np.arange(200)
    taken, _ = simulate(arrivals, 2.5 * P, clock)  # every second or third frame skipped
    assert len(taken) < 100
    assert clock.period == pytest.approx(P, rel=1e-9)  # the skipped frames counted by their indices
    ks = sorted(taken)
    assert all(b > a for a, b in zip(ks, ks[1:], strict=False))  # never a frame twice, never an older one


def test_a_waiting_frame_is_taken_at_once_and_the_delay_never_exceeds_a_display_interval():
    clock = PumpClock()
    assert clock.next_delay(5.0) == pytest.approx(clock.display_s)  # no beat yet
    clock.taken(0, 1.0)
    clock.taken(1, 1.0 + 0.1)  # a 10 Hz stream
    assert clock.next_delay(1.1001) == pytest.approx(clock.display_s)
    assert clock.next_delay(1.1001, pending=True) == 0.0
    assert clock.next_delay(1.2 - 0.002) == pytest.approx(0.002 + clock.margin_s)


def test_a_restarted_source_starts_the_beat_again():
    clock = PumpClock()
    for k in range(10):
        clock.taken(k, 1.0 + k * P)
    clock.taken(0, 2.0)  # its indices start again
    assert clock.period is None and clock.next_delay(2.001) == pytest.approx(clock.display_s)


def test_the_slot_wakes_a_waiting_consumer_and_is_clear_once_taken():
    slot = LatestSlot()
    assert slot.wait(0) is False
    frame = LiveFrame(0, 0.0, None, (), np.zeros((0, 3)), np.zeros((0, 4)))
    putter = threading.Thread(target=slot.put, args=(frame,))
    putter.start()
    assert slot.wait(30.0) is True  # woken by the put (the timeout only guards a broken test)
    putter.join()
    assert slot.wait(0) is True
    assert slot.take() is frame
    assert slot.wait(0) is False and slot.take() is None
