"""`bodycal demo` / `make demo`: the whole pipeline on the bundled synthetic recording (full
profile, sample_rigs/recordings) onto the procedural avatar and the shared MakeHuman avatars,
with all three methods; saves `out/demo.blend`, prints contact gap and floor error per avatar
and method, and reviews every bake: `out/review/review.html` lists their sheets and flags
(blender/review.py, FORMATS.md §4.5). Then a real take of a three-point kit (an HTC Vive's HMD
and wands, sample_data's real_vr: no calibration steps, the pelvis and feet estimated) onto the
adult avatar, every method, saved as `out/demo_three_point.blend`.

In the saved file each avatar stands in a column, one row per method (egocentric at the front),
each armature playing its own baked action; the recording's empties and the performer's
calibration helpers are in their own collections.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import bpy
import numpy as np

from ..calibration import calibrate_user
from ..core import paths
from ..core.errors import BodyCalError
from ..core.paths import shared_avatar_files as shared_avatar_files  # re-exported: the sidebar's sample avatars
from ..output import metrics
from ..output.review_page import write_page
from ..recording.io import load_recording
from ..retarget.pipeline import METHODS
from ..retarget.takes import RecordingTake
from . import avatar_storage, calibration_scene, mesh_metrics, recording_scene, session
from .avatar_calibration import calibrate_avatar
from .review import review_files, write_review

DEMO_RECORDING = paths.ROOT_DIR / "sample_rigs" / "recordings" / "demo_full.bcrec.json"
COLUMN_SPACING = 1.0
ROW_SPACING = 1.6


def _ranges_to_mask(ranges, n: int) -> np.ndarray:
    mask = np.zeros(n, bool)
    for first, last in ranges:  # inclusive [first, last] index ranges (synthetic truth files)
        mask[int(first):int(last) + 1] = True
    return mask


def read_truth(path: Path, frame_count: int) -> tuple[list[dict], dict[str, np.ndarray]]:
    """Contacts and planted feet of a synthetic ground-truth file, as frame masks."""
    data = json.loads(Path(path).read_text())
    contacts = [dict(c, frames=_ranges_to_mask(c["frames"], frame_count)) for c in data.get("contacts", [])]
    planted = {k: _ranges_to_mask(v, frame_count) for k, v in data.get("planted", {}).items()}
    return contacts, planted


def _avatar_loaders(only=None):
    rigs = paths.sample_rigs()
    loaders = [("procedural", lambda: rigs.build_procedural_avatar()[0])]
    for f in paths.shared_avatar_files():
        loaders.append((f.stem, lambda f=f: rigs.load_glb_avatar(f)[0]))
    return [(n, load) for n, load in loaders if only is None or n in only]


def _floor_error(arm, avatar, anim, planted) -> np.ndarray:
    errors = []
    for side in ("l", "r"):
        mask = planted.get(f"foot_{side}")
        if mask is None or not mask.any():
            continue
        soles = mesh_metrics.sole_points(avatar, anim, side)
        errors.append(metrics.floor_error(soles, mask[:anim.frame_count]))
    return np.concatenate(errors) if errors else np.array([np.nan])


def run_demo(output_dir: Path, log=print, only_avatars=None, three_point: bool = True) -> Path:
    t_start = time.perf_counter()
    output_dir = Path(output_dir)
    output_dir.mkdir(parents=True, exist_ok=True)
    if not DEMO_RECORDING.is_file():
        raise BodyCalError("the bundled demo recording is missing", source=str(DEMO_RECORDING),
                           hint="regenerate it with bodycal_dev/make_demo_recording.py")
    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene

    rec = load_recording(DEMO_RECORDING)
    truth = DEMO_RECORDING.with_name("demo_full.truth.json")  # development file, not in the extension zip
    contacts, planted = read_truth(truth, rec.frame_count) if truth.is_file() else ([], {})
    if not truth.is_file():
        log(f"no ground truth ({truth.name}): contact gaps and floor errors are not measured")
    recording_scene.import_recording_to_scene(rec, scene)
    log(f"recording {rec.name}: {rec.frame_count} frames at {rec.fps:.0f} Hz, {len(rec.devices)} devices, "
        f"{len(rec.marker_names)} markers, {len(rec.segments)} steps")

    user = calibrate_user(rec)
    calibration_scene.store_user_model(scene, user)
    calibration_scene.show_helpers(scene, user)
    cal = user.calibration
    log(f"performer calibrated from {len(cal.get('steps_used', []))} steps; defaulted: "
        f"{', '.join(cal.get('defaulted', {})) or 'nothing'}")

    take = RecordingTake(rec, user)
    rows = []
    noted: set[str] = set()
    for col, (name, load) in enumerate(_avatar_loaders(only_avatars)):
        avatar = None
        for row, method in enumerate(METHODS):
            arm = load()
            if avatar is None:
                t0 = time.perf_counter()
                avatar = calibrate_avatar(arm)
                log(f"avatar {name}: surface calibrated in {time.perf_counter() - t0:.2f} s")
            avatar_storage.store_model(arm, avatar)
            arm.name = f"{name}.{method}"
            target = session.prepare_target(arm)
            computed = session.compute(take, target, session.Settings(method))
            summary = session.bake(take, target, computed, action_name=f"{rec.name}|{name}|{method}", review=True)
            anim = computed.animation
            sheet, record = review_files(output_dir / "review" / f"{name}__{method}.blend")
            for note in write_review(summary, arm, sheet, record, [output_dir / "demo.blend"], overwrite=True):
                if note not in noted:  # said once (matplotlib missing), not per bake
                    noted.add(note)
                    log(note)
            touching = [c for c in contacts if c["effector"].split("_")[0] in ("palm", "wrist", "tip")]
            gaps = mesh_metrics.contact_gaps(arm, target.avatar, anim, touching, max_frames=8)
            gap = np.abs(np.concatenate(gaps)) if gaps else np.array([np.nan])
            floor = np.abs(_floor_error(arm, target.avatar, anim, planted))
            rows.append((name, method, np.nanmedian(gap) * 1000, np.nanpercentile(gap, 95) * 1000,
                         np.nanmedian(floor) * 1000, summary.keys))
            # Measured where it was calibrated; then stood aside. The performance plays relative to
            # the armature object (the default placement) and the action is in armature space, so
            # moving the object afterwards moves the whole performance with it: one avatar per
            # column, one method per row.
            arm.location = (COLUMN_SPACING * col, ROW_SPACING * row, 0.0)
    scene.frame_set(scene.frame_start)
    out = output_dir / "demo.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(out.resolve()), compress=True)

    log("")
    log(f"{'avatar':<18}{'method':<12}{'contact gap median':>20}{'p95':>9}{'floor error median':>20}{'keys':>10}")
    for name, method, g_med, g_p95, f_med, keys in rows:
        log(f"{name:<18}{method:<12}{g_med:>17.1f} mm{g_p95:>6.1f} mm{f_med:>17.1f} mm{keys:>10}")
    three = run_three_point_demo(output_dir, log) if three_point else None
    page = write_page(output_dir / "review")
    log("")
    log(f"saved {out}{f', {three}' if three else ''} and the bakes' review page {page} "
        f"({time.perf_counter() - t_start:.1f} s)")
    return out


THREE_POINT_TAKE = ("real_vr", "aframe_vive", "tracked-recording.json")
THREE_POINT_AVATAR = "adult_male"


def run_three_point_demo(output_dir: Path, log=print) -> Path | None:
    """A real three-point take (HMD and two controllers) onto the adult avatar with every method,
    one row per method, in `demo_three_point.blend`; None (and a line) when the sample data lacks
    it."""
    data = paths.data_dir()
    take_path = data.joinpath(*THREE_POINT_TAKE) if data else None
    avatar_file = next((f for f in paths.shared_avatar_files() if f.stem == THREE_POINT_AVATAR), None)
    if take_path is None or not take_path.is_file() or avatar_file is None:
        log("no real three-point take or adult avatar in the sample data: the three-point demo is skipped")
        return None
    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    rec = load_recording(take_path)
    recording_scene.import_recording_to_scene(rec, scene)
    user = calibrate_user(rec)
    calibration_scene.store_user_model(scene, user)
    log(f"three-point take {rec.name}: {rec.frame_count} frames at {rec.fps:.0f} Hz, "
        f"{', '.join(d.role for d in rec.devices)}; {len(user.extra.get('estimated_devices', {}))} devices "
        "estimated from the head and hands")
    take = RecordingTake(rec, user)
    avatar = None
    for row, method in enumerate(METHODS):
        arm = paths.sample_rigs().load_glb_avatar(avatar_file)[0]
        avatar = avatar or calibrate_avatar(arm)
        avatar_storage.store_model(arm, avatar)
        arm.name = f"{THREE_POINT_AVATAR}.{method}"
        target = session.prepare_target(arm)
        computed = session.compute(take, target, session.Settings(method))
        summary = session.bake(take, target, computed, action_name=f"{rec.name}|{THREE_POINT_AVATAR}|{method}",
                               review=True)
        log(f"  {summary.line()}")
        sheet, record = review_files(Path(output_dir) / "review" / f"three_point_{THREE_POINT_AVATAR}__{method}.blend")
        write_review(summary, arm, sheet, record, [Path(output_dir) / "demo_three_point.blend"], overwrite=True)
        for note in computed.animation.notes:
            if "estimated" in note:
                log(f"  {note}")
        arm.location = (0.0, ROW_SPACING * row, 0.0)
    scene.frame_set(scene.frame_start)
    out = Path(output_dir) / "demo_three_point.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(out.resolve()), compress=True)
    return out
