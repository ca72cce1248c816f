"""Retarget and bake inside Blender: gather the inputs the earlier steps left in the scene, run
the numpy pipeline (`retarget.pipeline.retarget`), bake the result and measure it.

The operator, the `retarget` command and the demo all go through here, so they behave the same:
compute first (nothing in the scene changes), write last (one new action).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from ..body.animation import AvatarAnimation, resample
from ..body.bodymodel import BodyModel
from ..body.bone_presets import load_preset
from ..core import outputs
from ..core.errors import BodyCalError
from ..output import metrics
from ..recording.filters import OneEuro, filter_recording
from ..recording.io import load_recording
from ..recording.model import Recording
from ..retarget.pipeline import retarget
from ..retarget.placement import avatar_warnings, check_placement, moved_to
from . import avatar_storage, bake, calibration_scene, process, recording_scene, rig_output
from .avatar_calibration import calibrate_avatar
from .avatar_rig import apply_preset
from .blendfile import find_armature, open_avatar, save_blend
from .export import export_avatar, output_kind


@dataclass
class RetargetInputs:
    recording: Recording
    user: BodyModel
    avatar: BodyModel
    armature: object  # bpy.types.Object
    method: str
    avatar_calibrated_now: bool = False  # store the avatar model with the bake
    filter: OneEuro | None = None  # One Euro filter on the devices before retargeting
    plant_feet: bool = True
    placement: str = "object"  # where the performance plays (retarget/placement.py)
    warnings: list[str] = field(default_factory=list)  # about the avatar's object transform, one line each


@dataclass
class RetargetSummary:
    action: str
    method: str
    frames: int
    keys: int
    compute_s: float
    bake_s: float
    figures: dict = field(default_factory=dict)
    samples: int = 0  # keys an every-frame bake would have written
    fps: float = 0.0  # the action's key rate
    dense_bones: tuple[str, ...] = ()  # bones the key reduction could hardly thin (bake.dense_note)

    def line(self) -> str:
        fig = ", ".join(f"{k} {v:.1f} mm" for k, v in self.figures.items())
        return (bake.baked_line(self.action, self.method, self.frames, self.fps, self.keys,
                                self.compute_s + self.bake_s, self.samples)
                + (f"; {fig}" if fig else "") + bake.dense_note(self.dense_bones))


def missing_inputs(scene) -> str | None:
    """Why the scene cannot be retargeted yet, as an instruction; None when it can."""
    if recording_scene.scene_recording_collection(scene) is None:
        return "Import a recording first (File > Import > BodyCal recording)"
    if not calibration_scene.has_user_model(scene):
        return "Calibrate the performer first (BodyCal tab > Calibration)"
    return None


def avatar_model_for(arm) -> tuple[BodyModel, bool]:
    """The armature's stored avatar model, brought to where its object stands now (moved, turned
    or scaled since it was calibrated), or a fresh surface calibration (not stored yet)."""
    if avatar_storage.has_model(arm):
        stored = avatar_storage.load_model(arm)
        return moved_to(stored, np.array(arm.matrix_world, dtype=float)), False
    return calibrate_avatar(arm), True


def gather_inputs(scene, arm, method: str, recording: Recording | None = None,
                  user: BodyModel | None = None, *, filter: OneEuro | None = None,
                  plant_feet: bool = True, placement: str = "object") -> RetargetInputs:
    if arm is None or getattr(arm, "type", None) != "ARMATURE":
        raise BodyCalError("pick an avatar armature", source=getattr(arm, "name", "no object"))
    check_placement(placement)
    recording = recording if recording is not None else recording_scene.recording_from_scene(scene)
    user = user if user is not None else calibration_scene.load_user_model(scene)
    avatar, fresh = avatar_model_for(arm)
    return RetargetInputs(recording, user, avatar, arm, method, fresh, filter, plant_feet, placement,
                          avatar_warnings(avatar))


def compute(inputs: RetargetInputs, progress=None, cancel=None) -> AvatarAnimation:
    """Pure numpy: safe to run in a worker thread. The filter, when asked, works on a copy of the
    recording (the scene's and the file's stay as they are)."""
    t0 = time.perf_counter()
    rec = inputs.recording if inputs.filter is None else filter_recording(inputs.recording, inputs.filter)
    anim = retarget(rec, inputs.user, inputs.avatar, inputs.method, progress=progress, cancel=cancel,
                    plant_feet=inputs.plant_feet, placement=inputs.placement)
    anim.notes.append(f"compute_s={time.perf_counter() - t0:.3f}")
    return anim


def quality_figures(anim: AvatarAnimation) -> dict[str, float]:
    """Figures shown after a bake (mm): how far the IK left the effectors from their retargeted
    targets, and how far the lowest ankle is from its standing height."""
    figures = {}
    reach = [metrics.reach_error(anim.joints_world[j], anim.targets[j]) for j in anim.targets
             if j in anim.joints_world]
    if reach:
        figures["reach p95"] = float(np.percentile(np.concatenate([np.ravel(r) for r in reach]), 95) * 1000)
    return figures


def output_rate(recording: Recording, fps: float | None) -> tuple[int, float, float, bool]:
    """(scene fps, fps_base, key rate, resample?) for baking `recording` at `fps` (None: its own
    samples, at the frames the recording import uses: frame = frame_start + (t - t0) x rate)."""
    rec_fps, rec_base, rate = recording_scene.frame_mapping(recording)
    if fps is None or abs(fps - rate) <= 1e-6 * rate:
        return rec_fps, rec_base, rate, False
    return *bake.scene_rate(fps), float(fps), True


def bake_and_measure(inputs: RetargetInputs, anim: AvatarAnimation, *, replace: bool = False,
                     push_to_nla: bool = False, action_name: str | None = None,
                     set_scene_rate: bool = False, options: bake.BakeOptions | None = None,
                     release: bool = False) -> RetargetSummary:
    """Bake `anim` at `options.fps` (None: one key per recording sample), keys reduced within the
    options' tolerances. `set_scene_rate` makes the scene play at that rate (in the UI flow the
    recording import already did, or the user picked the scene's rate; the command line starts
    from the avatar's file). `release`: the caller is done with the recording and with `anim`'s
    joints and targets; they are let go before the keys are made (a 10-minute take: ~250 MB less
    at the command's peak)."""
    import bpy

    options = options or bake.BakeOptions()
    name = action_name or bake.default_action_name(inputs.recording.name, inputs.armature.name, inputs.method)
    fps, fps_base, rate, resampled = output_rate(inputs.recording, options.fps)
    figures = quality_figures(anim)
    if release:
        inputs.recording, anim.joints_world, anim.targets = None, {}, {}
        process.release_freed_memory()
    t0 = time.perf_counter()
    with bake.restored_on_failure(inputs.armature, bpy.context.scene):
        if set_scene_rate:
            bpy.context.scene.render.fps, bpy.context.scene.render.fps_base = fps, fps_base
        keyed = resample(anim, rate) if resampled else anim
        keyed = rig_output.for_bake(keyed, inputs.armature, options.root_motion, options.rigify_target,
                                    own=resampled or release)
        if release:
            # Keys are float32 in Blender: the rotations the bake keys from need be no finer (a
            # 10-minute take: 46 MB less while the keys are made; the reduction searches in float64).
            keyed.rotations = np.asarray(keyed.rotations, np.float32)
            anim.rotations = keyed.rotations
        result = bake.bake_animation(keyed, inputs.armature, action_name=name, replace=replace,
                                     push_to_nla=push_to_nla, fps=rate, tolerance_deg=options.tolerance_deg,
                                     location_tolerance_mm=options.location_tolerance_mm, own=resampled or release)
    if inputs.avatar_calibrated_now:
        avatar_storage.store_model(inputs.armature, inputs.avatar)
    bake_s = time.perf_counter() - t0
    compute_s = next((float(n.split("=")[1]) for n in anim.notes if n.startswith("compute_s=")), 0.0)
    return RetargetSummary(result.action.name, inputs.method, keyed.frame_count, result.keys, compute_s, bake_s,
                           figures, result.samples, rate, result.dense_bones)


def avatar_input(avatar_file) -> tuple[str, object]:
    """The avatar file as an input that no output may be (named by its kind: "the avatar .fbx")."""
    from pathlib import Path

    return f"the avatar {Path(avatar_file).suffix.lower() or 'file'}", avatar_file


def output_inputs(recording_path, user_path, avatar_file, bone_map_path=None) -> list[tuple[str, object]]:
    """What `retarget` reads, named for the message when its output would be one of them."""
    name, path = avatar_input(avatar_file)
    return [*outputs.recording_inputs(recording_path), ("the user file (--user)", user_path),
            (f"{name} (--avatar)", path), ("the bone map (--bone-map)", bone_map_path)]


def retarget_files(recording_path, user_path, avatar_file, output_paths, *, armature: str | None = None,
                   method: str = "egocentric", filter: OneEuro | None = None, plant_feet: bool = True,
                   placement: str = "object", overwrite: bool = True, options: bake.BakeOptions | None = None,
                   log=print, warn=print, bone_map_path=None) -> RetargetSummary:
    """`bodycal retarget`: everything from paths, nothing from a running session. `output_paths`
    (one path or several: a .blend and/or exports) are checked first (not an input, not a link or
    device, replaced only with `overwrite`, each once), so a bad path costs nothing; they are
    written last, each all at once. A bone map preset (`bone_map_path`) is read and checked with
    the other inputs, before the avatar's file is opened. The avatar is a .blend, or an .fbx,
    .glb, .gltf or .vrm imported into an empty scene (blendfile.open_avatar): a .blend output
    then holds the imported avatar with the baked action. `warn` gets one line per doubt about
    the avatar (placement.avatar_warnings), before the work."""
    from pathlib import Path

    import bpy


    avatar_file = Path(avatar_file)
    check_placement(placement)
    files_read = output_inputs(recording_path, user_path, avatar_file, bone_map_path)
    outs = checked_outputs(output_paths, files_read, overwrite)
    bone_map = load_preset(bone_map_path) if bone_map_path else None  # every input checked before opening anything
    recording = load_recording(recording_path)
    user = BodyModel.load(user_path)
    if user.kind != "user":
        raise BodyCalError(f"expected a user body model, got kind '{user.kind}'", source=str(user_path))
    open_avatar(avatar_file)
    arm = find_armature(armature, str(avatar_file))
    if bone_map is not None:

        if apply_preset(arm, bone_map)[1]:
            log(f"{arm.name}: its stored avatar model was made with another bone map; calibrating it again")
    inputs = gather_inputs(bpy.context.scene, arm, method, recording=recording, user=user, filter=filter,
                           plant_feet=plant_feet, placement=placement)
    del recording  # `inputs` holds it until the bake lets it go
    for line in inputs.warnings:
        warn(line)
    anim = compute(inputs)
    summary = bake_and_measure(inputs, anim, set_scene_rate=True, options=options, release=True)
    del anim, inputs  # the keys are in the action now: let the writers have the memory
    log(summary.line())
    write_outputs(arm, outs, files_read, overwrite, log)
    return summary


def checked_outputs(output_paths, files_read, overwrite: bool) -> list:
    """The -o paths (one or several: a .blend and/or exports), each checked before any work: not
    one of `files_read`, not a link or device, replaced only with `overwrite`, each given once."""
    from pathlib import Path


    outs = [Path(p) for p in ([output_paths] if isinstance(output_paths, (str, Path)) else output_paths)]
    seen = set()
    for out in outs:
        outputs.check_output(out, inputs=files_read, overwrite=overwrite)  # the most important reason first
        output_kind(out)
        if str(out.resolve()) in seen:
            raise BodyCalError("is given twice", source=str(out), field="-o", hint="give each output once")
        seen.add(str(out.resolve()))
    return outs


def write_outputs(arm, outs, files_read, overwrite: bool, log=print) -> None:
    """Write the open file (.blend) or the avatar with its baked action (exports), each all at once."""

    for out in outs:
        if output_kind(out) == "blend":
            save_blend(out, inputs=files_read, overwrite=overwrite)
        else:
            export_avatar(arm, out, inputs=files_read, overwrite=overwrite)
        log(f"saved {out}")
