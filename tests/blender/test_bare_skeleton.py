"""A target armature without a mesh (a game skeleton, a BVH): its body is estimated from its bone
lengths (avatar/estimate.py, DESIGN.md §8) and every method bakes onto it; the report says so in one
line, and the estimate is not stored on the armature (a mesh added later is measured)."""

import bpy
import numpy as np
import pytest

from bodycal_addon.blender import avatar_storage, session
from bodycal_addon.core import paths
from bodycal_addon.retarget.methods import methods_for
from bodycal_addon.retarget.takes import RecordingTake
from bodycal_dev import synthetic

rigs = paths.sample_rigs()


@pytest.fixture(scope="module")
def take():
    perf = synthetic.make_performer(seed=3)
    rec, truth = synthetic.record_session(perf, motions=("clap",), calibration=["tpose"], seed=3)
    return RecordingTake(rec, truth.body_model())


def _procedural(mesh: bool):
    bpy.ops.wm.read_homefile(use_empty=True)
    arm, skin, _ = rigs.build_procedural_avatar()
    if not mesh:
        bpy.data.objects.remove(skin)
    return arm


@pytest.mark.parametrize("method", methods_for("recording"))
def test_every_method_bakes_onto_a_skeleton_without_a_mesh(take, method):
    arm = _procedural(mesh=False)
    target = session.prepare_target(arm)  # "no mesh is skinned ... nothing to raycast" before
    assert target.avatar.calibration["method"] == "estimated" and not target.calibrated_now
    computed = session.compute(take, target, session.Settings(method))
    assert np.isfinite(computed.animation.rotations).all() and np.isfinite(computed.animation.root_location).all()
    summary = session.bake(take, target, computed)
    said = [ln for ln in summary.report_lines() if "estimated from its bone lengths" in ln]
    assert len(said) == 1 and arm.name in said[0]
    assert arm.animation_data.action.name == summary.action
    assert not avatar_storage.has_model(arm)


def test_rotation_copy_on_the_bare_skeleton_is_the_one_on_the_skinned_avatar(take):
    """Rotation Copy reads no surface: the same rig with or without its mesh gives the same bone
    rotations (feet left to the method: planting reads the soles)."""
    out = {}
    for mesh in (True, False):
        target = session.prepare_target(_procedural(mesh))
        settings = session.Settings("rotations", plant_feet=False)
        out[mesh] = session.compute(take, target, settings).animation.rotations
    np.testing.assert_allclose(out[False], out[True], atol=1e-9)
