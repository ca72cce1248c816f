"""One path from any pose source to baked actions (DESIGN.md §1, "One session path").

    take = ...                       # a pose source read into numpy (retarget/takes.py)
    target = prepare_target(arm)     # the armature and its avatar model, where it stands now
    computed = compute(take, target, settings)         # engine only: a worker thread may run it
    summary = bake(take, target, computed, options)    # the only scene write: one new action

The Retarget and Transfer operators, the `retarget` and `transfer` commands (`run_files`), the
batch jobs (which run those commands) and the demo all go through here, whatever the take: a
tracker recording or another character's action. Compute first, write last: nothing in the scene
changes before `bake`, and a failed bake puts back what it changed. A live stream (blender/live.py)
shares `prepare_target` and the prepared solver with it (DESIGN.md "A file take and a live stream").
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import bpy
import numpy as np

from ..body import naming
from ..body.animation import AvatarAnimation, resample
from ..body.bodymodel import BodyModel
from ..body.bone_presets import load_preset
from ..core import outputs
from ..core.errors import BodyCalError
from ..output import metrics
from ..output import review as review_figures
from ..output.keyreduce import DEFAULT_LOCATION_TOLERANCE_MM as DEFAULT_LOCATION_TOLERANCE_MM  # the sidebar's
from ..output.keyreduce import DEFAULT_TOLERANCE_DEG as DEFAULT_TOLERANCE_DEG  # the sidebar's default
from ..recording.filters import DEFAULT_FILTER
from ..recording.filters import OneEuro as OneEuro  # re-exported: the sidebar's filter settings
from ..recording.io import load_recording
from ..retarget.methods import METHOD_INFO, check_method, methods_for
from ..retarget.placement import avatar_warnings, check_placement
from ..retarget.takes import CharacterTake, RecordingTake, Take
from . import avatar_storage, bake_check, calibration_scene, process, recording_scene, rig_output
from . import bake as baking
from . import review as review_sheet
from .avatar_calibration import avatar_model_for
from .avatar_rig import apply_preset
from .blendfile import find_armature, open_avatar, save_blend
from .character_source import open_source, pick_action, read_source
from .export import export_avatar, output_kind

# The kinds of take the sidebar bakes, each with its methods (retarget/methods.py).
RECORDING, ANIMATION = RecordingTake.kind, CharacterTake.kind


def method_choices(take_kind: str) -> list[tuple[str, str, str]]:
    """(name, label, description) of each method for a kind of take, from the one registry."""
    return [(name, METHOD_INFO[name].label, METHOD_INFO[name].description) for name in methods_for(take_kind)]


@dataclass
class Settings:
    """What the engine needs besides the take and the target (DESIGN.md §1)."""

    method: str = "egocentric"
    plant_feet: bool = True  # hold each foot still and on the floor while the performer stands on it
    placement: str = "object"  # where the performance plays (retarget/placement.py)


@dataclass
class Target:
    """An armature to animate and its avatar model, brought to where its object stands now."""

    armature: object  # bpy.types.Object
    avatar: BodyModel
    calibrated_now: bool  # measured for this bake: stored on the armature with the action
    warnings: list[str] = field(default_factory=list)  # about the object's transform, one line each


@dataclass
class Computed:
    animation: AvatarAnimation
    seconds: float
    placement: str = "object"  # where the performance played (the review brings the source there)


@dataclass
class Summary:
    """What one bake made, for the status bar, the panel, the command line and batch."""

    action: str
    method: str
    frames: int
    keys: int
    compute_s: float
    bake_s: float
    fps: float  # the action's key rate
    samples: int = 0  # keys an every-frame bake would have written
    figures: dict[str, float] = field(default_factory=dict)  # mm
    notes: list[str] = field(default_factory=list)  # what the engine said of this animation, one line each
    dense_bones: tuple[str, ...] = ()  # bones the key reduction could hardly thin (bake.dense_note)
    frame_range: tuple[float, float] | None = None  # the scene frames of the first and last keys
    kind: str = "recording"  # the take's kind (retarget/takes.py): what the dense-bone note suggests
    review: review_figures.Review | None = None  # the bake's review (output/review.py), when asked
    review_plan: review_figures.ReviewPlan | None = None  # what its sheet draws from (blender/review.py)
    review_s: float = 0.0  # the review's figures' time, measured apart from compute_s and bake_s

    def line(self) -> str:
        fig = ", ".join(f"{k} {v:.1f} mm" for k, v in self.figures.items())
        return (baking.baked_line(self.action, self.method, self.frames, self.fps, self.keys,
                                  self.compute_s + self.bake_s, self.samples, self.frame_range)
                + (f"; {fig}" if fig else "") + baking.dense_note(self.dense_bones, self.kind))

    def report_lines(self) -> list[str]:
        """The summary line, then the engine's notes."""
        return [self.line(), *self.notes]


def prepare_target(arm) -> Target:
    if arm is None or getattr(arm, "type", None) != "ARMATURE":
        raise BodyCalError("pick an avatar armature", source=getattr(arm, "name", "no object"))
    avatar, fresh = avatar_model_for(arm)
    return Target(arm, avatar, fresh, avatar_warnings(avatar))


def compute(take: Take, target: Target, settings: Settings, progress: Callable[[float], None] | None = None,
            cancel: Callable[[], bool] | None = None) -> Computed:
    """Pure numpy: safe in a worker thread; `progress(f)` with f in [0, 1], `cancel()` true raises
    Cancelled between chunks."""
    check_method(settings.method, take.kind)
    t0 = time.perf_counter()
    anim = take.animate(target.avatar, settings.method, plant_feet=settings.plant_feet,
                        placement=settings.placement, progress=progress, cancel=cancel)
    return Computed(anim, time.perf_counter() - t0, settings.placement)


def quality_figures(anim: AvatarAnimation) -> dict[str, float]:
    """Figures shown after a bake (mm): how far the IK left the effectors from their retargeted
    targets."""
    figures = {}
    reach = [metrics.reach_error(anim.joints_world[j], anim.targets[j]) for j in anim.targets
             if j in anim.joints_world]
    reach = np.concatenate([np.ravel(r) for r in reach]) if reach else np.empty(0)
    reach = reach[np.isfinite(reach)]  # frames where a method set no target
    if reach.size:
        figures["reach p95"] = float(np.percentile(reach, 95) * 1000)
    return figures


def key_rate(take: Take, fps: float | None) -> tuple[int, float, float, bool]:
    """(scene fps, fps_base, key rate, resample?) for baking `take` at `fps` (None: its own samples,
    on the frames they play at). A take imported timed to the scene's rate (its samples between
    frames) baked at that rate is resampled, so its keys fall on whole frames."""
    own = take.rate
    if fps is None or (abs(fps - own) <= 1e-6 * own and abs(take.sample_rate - own) <= 1e-6 * own):
        return *baking.scene_rate(own), own, False
    return *baking.scene_rate(fps), float(fps), True


def bake(take: Take, target: Target, computed: Computed, *, options: baking.BakeOptions | None = None,
         replace: bool = False, push_to_nla: bool = False, action_name: str | None = None,
         set_scene_rate: bool = False, set_scene_range: bool = False,
         release: bool = False, review: bool = False) -> Summary:
    """Bake the computed animation onto the target's armature at `options.fps` (None: one key per
    sample of the take), keys reduced within the options' tolerances; a new action unless
    `replace`. The first key lands on the take's `frame_start` (the frame its source plays at).
    `set_scene_rate` makes the scene play at that rate, `set_scene_range` makes the scene's frame
    range the action's (the command line starts from the avatar's file; the sidebar asks).
    `release`: nothing more will be computed from the take or measured on the animation's joints
    and targets; they are let go before the keys are made (a 10-minute take: ~250 MB less at the
    command's peak). `review`: the bake's review too (output/review.py; the evaluated mesh measured
    once the keys are written: blender/review.py), in `Summary.review`."""
    options = options or baking.BakeOptions()
    arm, anim = target.armature, computed.animation
    name = action_name or baking.default_action_name(take.name, arm.name, anim.method)
    fps, fps_base, rate, resampled = key_rate(take, options.fps)
    frame_start = take.frame_start
    figures = quality_figures(anim)
    check = bake_check.plan(anim, target.avatar)  # before the joints are let go
    t_review = time.perf_counter()
    plan = review_plan(take, target.avatar, computed, frame_start, rate, figures) if review else None
    review_s = time.perf_counter() - t_review

    def verify():
        bake_check.verify(check, arm, baking.key_frames(anim.time, rate, frame_start),
                          in_place=options.root_motion == "in-place")

    if release:
        take.release()
        anim.joints_world, anim.targets = {}, {}
        process.release_freed_memory()
    bone_map = naming.BoneMap.from_dict(target.avatar.extra["rig"]["bone_map"])
    t0 = time.perf_counter()
    with baking.restored_on_failure(arm, bpy.context.scene):
        if set_scene_rate:
            bpy.context.scene.render.fps, bpy.context.scene.render.fps_base = fps, fps_base
        keyed = resample(anim, rate) if resampled else anim
        keyed = rig_output.for_bake(keyed, arm, bone_map, options.root_motion, options.rigify_target,
                                    own=resampled or release)
        if release:
            # Keys are float32 in Blender: the rotations the bake keys from need be no finer (a
            # 10-minute take: 46 MB less while the keys are made; the reduction searches in float64).
            keyed.rotations = np.asarray(keyed.rotations, np.float32)
            anim.rotations = keyed.rotations
        result = baking.bake_animation(keyed, arm, action_name=name, replace=replace, push_to_nla=push_to_nla,
                                       fps=rate, frame_start=frame_start, tolerance_deg=options.tolerance_deg,
                                       location_tolerance_mm=options.location_tolerance_mm,
                                       own=resampled or release, set_scene_range=set_scene_range,
                                       interpolation=options.interpolation, verify=verify)
    bake_s = time.perf_counter() - t0
    if target.calibrated_now:
        avatar_storage.store_model(arm, target.avatar)
        target.calibrated_now = False
    summary = Summary(result.action.name, anim.method, keyed.frame_count, result.keys, computed.seconds, bake_s, rate,
                      result.samples, figures, list(keyed.notes), result.dense_bones, result.frame_range, take.kind)
    if plan is not None:
        t_review = time.perf_counter()
        summary.review, summary.review_plan = review_sheet.measure(plan, arm, target.avatar), plan
        summary.review_s = review_s + time.perf_counter() - t_review
    return summary


def review_plan(take: Take, avatar: BodyModel, computed: Computed, frame_start: float, rate: float,
                figures: dict) -> review_figures.ReviewPlan:
    """The review's figures of a computed animation against its take's source (output/review.py),
    before the keys are made (a released take has let its source go)."""
    anim = computed.animation
    source = review_figures.source_motion(take.pose_source(computed.placement), avatar, anim.method,
                                          computed.placement)
    return review_figures.plan(anim, avatar, source, frame_start, rate, figures)


# --- takes in the scene ------------------------------------------------------------------------------


def scene_take_missing(scene) -> str | None:
    """Why the scene's recording cannot be a take yet, as an instruction; None when it can."""
    if recording_scene.scene_recording_collection(scene) is None:
        return "Import a recording first (File > Import > BodyCal recording)"
    if not calibration_scene.has_user_model(scene):
        return "Calibrate the performer first (BodyCal tab > Calibration)"
    return None


def scene_take(scene, filter: OneEuro | None = None, *, seat_height: float | None = None,
               user: BodyModel | None = None) -> RecordingTake:
    """The scene's recording (its devices' empties, as the importer made them or the user edited
    them) and the performer's body model (`user`, else the scene's calibrated one) as a take, on the
    frames it was imported at (`seat_height`: the performer seated, a kit without foot trackers)."""
    recording = recording_scene.recording_from_scene(scene)
    frame_start, rate = recording_scene.frame_mapping_in_scene(scene)
    return RecordingTake(recording, calibration_scene.load_user_model(scene) if user is None else user, filter,
                         frame_start=frame_start, frame_rate=rate, seat_height=seat_height)


def source_take(source, action=None, smooth: bool = False) -> CharacterTake:
    """Another character's action as a take (`smooth`: the default One Euro filter on its pose)."""
    take = read_source(source, action)
    take.filter = OneEuro() if smooth else None
    return take


# --- the command line: everything from paths, nothing from a running session -----------------------


def avatar_input(avatar_file) -> tuple[str, object]:
    """The avatar file as an input that no output may be (named by its kind: "the avatar .fbx")."""
    return f"the avatar {Path(avatar_file).suffix.lower() or 'file'}", avatar_file


def checked_outputs(output_paths, files_read, overwrite: bool) -> list[Path]:
    """The -o paths (one or several: a .blend and/or exports), each checked before any work: not
    one of `files_read`, not a link or device, replaced only with `overwrite`, each given once."""
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


# The share of a command's run each stage takes on its progress line (the engine's compute is the rest).
_STAGES = {"reading": 0.0, "opening the avatar": 0.04, "measuring the avatar": 0.08, "computing": 0.14,
           "baking": 0.86, "saving": 0.94, "reviewing": 0.97}


def run_files(read_take: Callable[[], Take], kind: str, files_read: list, avatar_file, output_paths, *,
              armature: str | None = None, settings: Settings | None = None, overwrite: bool = True,
              options: baking.BakeOptions | None = None, log=print, warn=print, bone_map_path=None,
              frame_range: tuple[float, float] | None = None,
              progress: Callable[[str, float], None] | None = None, review: bool = False) -> Summary:
    """A take of `kind` (read by `read_take`, which may open its own file) onto the avatar of
    `avatar_file`, baked and written to `output_paths`. Every path is checked first (the outputs:
    not an input, not a link or device, replaced only with `overwrite`, each once; the bone map
    preset read and checked) so a bad path costs nothing; the outputs are written last, each all
    at once. The avatar is a .blend, or an .fbx, .glb, .gltf or .vrm imported into an empty scene
    (blendfile.open_avatar): a .blend output then holds the imported avatar with the baked action.
    `frame_range` (first, last) limits the take to those frames (a recording's first sample is
    frame 1, a character's action keeps its own frames); the scene's range becomes the baked one.
    `warn` gets one line per doubt about the avatar (placement.avatar_warnings), before the work;
    `log` the take's notes, the summary line and the engine's notes; `progress(stage, fraction)`
    how far the run is (the command line's progress line). `review`: the bake's review too, its
    sheet and record beside the first output (blender/review.py, FORMATS.md §4.5), written after
    the outputs; a bake that fails after the checks leaves a record saying why."""
    settings = settings or Settings()
    check_method(settings.method, kind)
    check_placement(settings.placement)
    name, path = avatar_input(avatar_file)
    files_read = [*files_read, (f"{name} (--avatar)", path), ("the bone map (--bone-map)", bone_map_path)]
    outs = checked_outputs(output_paths, files_read, overwrite)
    reviewed = review_sheet.review_files(outs[0]) if review else ()
    for out in reviewed:
        outputs.check_output(out, inputs=files_read, overwrite=overwrite)
    bone_map = load_preset(bone_map_path) if bone_map_path else None  # every input checked before opening any
    try:
        summary, arm = _read_and_bake(read_take, kind, avatar_file, armature, settings, options, log, warn, bone_map,
                                      frame_range, progress, review)
    except BodyCalError as exc:
        if reviewed:  # what went wrong, for the batch's review page (the error itself is what is said)
            with contextlib.suppress(BodyCalError, OSError):
                review_sheet.write_failure(reviewed[1], exc, inputs=files_read, overwrite=True)
        raise
    step = progress or (lambda stage, fraction: None)
    step("saving", _STAGES["saving"])
    write_outputs(arm, outs, files_read, overwrite, log)
    if reviewed:
        step("reviewing", _STAGES["reviewing"])
        for note in review_sheet.write_review(summary, arm, *reviewed, outs, inputs=files_read, overwrite=True):
            log(note)
        log(f"saved {reviewed[0]}")
        log(f"saved {reviewed[1]}")
    step("saving", 1.0)
    return summary


def _read_and_bake(read_take, kind, avatar_file, armature, settings, options, log, warn, bone_map, frame_range,
                   progress, review) -> tuple[Summary, object]:
    """`run_files`' work between the checks and the writes: the take read, the avatar opened and
    measured, the animation computed and baked (and reviewed); the summary and the armature."""
    step = progress or (lambda stage, fraction: None)
    step("reading", _STAGES["reading"])
    take = read_take()
    if frame_range is not None:
        take = take.window(*frame_range)
    for note in take.notes:
        log(note)
    step("opening the avatar", _STAGES["opening the avatar"])
    for note in open_avatar(Path(avatar_file)):
        log(note)
    arm = find_armature(armature, str(avatar_file))
    if bone_map is not None and apply_preset(arm, bone_map)[1]:
        log(f"{arm.name}: its stored avatar model was made with another bone map; calibrating it again")
    step("measuring the avatar", _STAGES["measuring the avatar"])
    target = prepare_target(arm)
    for line in target.warnings:
        warn(line)
    start, span = _STAGES["computing"], _STAGES["baking"] - _STAGES["computing"]
    step(settings.method, start)
    computed = compute(take, target, settings, progress=lambda f: step(settings.method, start + span * f))
    step("baking", _STAGES["baking"])
    summary = bake(take, target, computed, options=options, set_scene_rate=True, set_scene_range=True, release=True,
                   review=review)
    del computed, take  # the keys are in the action now: let the writers have the memory
    for line in summary.report_lines():
        log(line)
    for flag in summary.review.flags if summary.review is not None else ():
        log(f"review: {'OVER ' if flag.over else ''}{flag.text}")
    return summary, arm


def retarget_files(recording_path, user_path, avatar_file, output_paths, *, filter: OneEuro | None = DEFAULT_FILTER,
                   hands: str = "geometry", seat_height: float | None = None, log=print, **kwargs) -> Summary:
    """`bodycal retarget`: a recording of the performer whose body model is `user_path` (`hands`:
    how a three-point kit's own file tells its hands, recording/io/hands.py; `seat_height`:
    seated, a kit without foot trackers)."""

    def read() -> RecordingTake:
        recording = load_recording(recording_path, hands=hands)
        user = BodyModel.load(user_path)
        if user.kind != "user":
            raise BodyCalError(f"expected a user body model, got kind '{user.kind}'", source=str(user_path))
        return RecordingTake(recording, user, filter, seat_height=seat_height)

    files_read = [*outputs.recording_inputs(recording_path), ("the user file (--user)", user_path)]
    return run_files(read, RecordingTake.kind, files_read, avatar_file, output_paths, log=log, **kwargs)


def read_character_take(source_path, source_armature: str | None = None, action: str | None = None,
                        log=print) -> CharacterTake:
    """A character's action in a file (`transfer`'s SOURCE) read as a take; the file becomes the open one."""
    for note in open_source(Path(source_path)):
        log(note)
    src_arm = find_armature(source_armature, str(source_path))
    return read_source(src_arm, pick_action(src_arm, action, str(source_path)))


def transfer_files(source_path, avatar_file, output_paths, *, source_armature: str | None = None,
                   action: str | None = None, filter: OneEuro | None = None, log=print, **kwargs) -> Summary:
    """`bodycal transfer`: the action of a character in `source_path` (.blend, .bvh, .fbx, .glb,
    .gltf; character_source.open_source), its pose One-Euro filtered first with `filter`."""
    source_path = Path(source_path)

    def read():
        take = read_character_take(source_path, source_armature, action, log)
        take.filter = filter
        return take

    files_read = [(f"the source {source_path.suffix.lower() or 'file'}", source_path)]
    return run_files(read, CharacterTake.kind, files_read, avatar_file, output_paths, log=log, **kwargs)
