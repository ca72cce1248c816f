"""The one session path (blender/session.py): any object with a take's attributes bakes through it
as a recording does (a live stream will be such a take), and what the engine says of the
animation reaches the user as report lines, with the compute time as a field."""

from __future__ import annotations

import bpy
import numpy as np
import pytest

import sample_rigs as rigs
from bodycal_addon.blender import session
from bodycal_addon.blender.bake import BakeOptions
from bodycal_addon.blender.fcurves import object_fcurves, read_keys
from bodycal_addon.retarget.takes import RecordingTake
from bodycal_dev import synthetic


@pytest.fixture(scope="module")
def recorded():
    perf = synthetic.make_performer(seed=11)
    rec, truth = synthetic.record_session(perf, motions=("hand_on_belly",), calibration=False, motion_seconds=0.6,
                                          noise_mm=0.3, wobble_mm=0.0)
    rec.valid[5:9, 0] = False  # a device lost for a few frames: the engine says so
    return rec, truth.body_model()


class StreamedTake:
    """A take no module of BodyCal defines: frames that came from elsewhere (a stream), with the
    attributes and methods retarget/takes.Take asks for, and nothing else."""

    kind = "recording"

    def __init__(self, recording, user):
        self._inner = RecordingTake(recording, user)
        self.name, self.notes = "streamed", ["received over the wire"]
        self.frame_start = 1.0

    @property
    def rate(self):
        return self._inner.rate

    @property
    def sample_rate(self):
        return self._inner.sample_rate

    def animate(self, avatar, method, **kwargs):
        return self._inner.animate(avatar, method, **kwargs)

    def window(self, first, last):
        raise NotImplementedError  # not asked of a take the session bakes whole

    def release(self):
        self._inner.release()


def _bake(take, method="egocentric"):
    bpy.ops.wm.read_homefile(use_empty=True)
    arm, _mesh, _spec = rigs.build_procedural_avatar()
    target = session.prepare_target(arm)
    computed = session.compute(take, target, session.Settings(method))
    summary = session.bake(take, target, computed, options=BakeOptions(tolerance_deg=0.0))
    keys = {k: np.stack(read_keys(fc)) for k, fc in object_fcurves(arm).items()}
    return summary, keys, arm


def test_any_take_bakes_through_the_one_path(recorded):
    rec, user = recorded
    want_summary, want, _ = _bake(RecordingTake(rec, user))
    got_summary, got, arm = _bake(StreamedTake(rec, user))
    assert got.keys() == want.keys()
    for k in want:
        np.testing.assert_array_equal(got[k], want[k], err_msg=str(k))
    assert got_summary.action == f"streamed|{arm.name}|egocentric" == arm.animation_data.action.name
    assert got_summary.keys == want_summary.keys and got_summary.frames == rec.frame_count


def test_the_engines_notes_and_timing_reach_the_summary(recorded):
    rec, user = recorded
    summary, _keys, _arm = _bake(RecordingTake(rec, user), method="rotations")
    lines = summary.report_lines()
    assert lines[0] == summary.line() and lines[0].startswith("Baked ")
    lost = [n for n in lines[1:] if "frames without tracking" in n]
    assert lost and lost[0].startswith(f"{rec.devices[0].role}: 4 frames"), lines
    assert "4 bridged" in lost[0], lines  # a short gap inside the take: bridged (DESIGN.md §6)
    assert summary.compute_s > 0 and summary.bake_s > 0
    assert not any("compute_s" in n for n in lines)
