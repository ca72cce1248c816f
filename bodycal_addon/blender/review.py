"""A bake's review in Blender (DESIGN.md §7 "Review", FORMATS.md §4.5): the evaluated mesh measured
at the frames the engine's review asks for (output/review.py), and the review sheet: the frames
that matter rendered by the Workbench engine (no GPU needed: Blender's software OpenGL in
background mode), each labelled with its figure, the source's stick figure beside the avatar,
and the figures over the take plotted by matplotlib below them.

Decisions:
- The poses are rendered once, side by side in one image (a snapshot of the evaluated mesh per
  frame, each moved so its pelvis is in the middle of its cell: a fixed camera that follows the
  pelvis), not once per frame: one render costs the Workbench's start-up once.
- The sheet is drawn in a scene of its own, made for the render and removed after it: the user's
  scenes, objects and file are never touched (the armature plays its action in its scene only
  while the snapshots are taken, and the frame is put back).
- matplotlib is not in Blender's Python nor in the extension zip (docs/DESIGN.md §7 "Review"):
  without it the sheet is the rendered frames alone, and one note says so; the flags never need it.
"""

from __future__ import annotations

import json
import math
import tempfile
import time
from pathlib import Path

import bpy
import numpy as np

from ..body import skeleton as sk
from ..body.animation import AvatarAnimation
from ..core import outputs
from ..core.errors import BodyCalError
from ..core.transforms import matrix_to_quat
from ..output import review as engine
from ..retarget.avatar_pose import AvatarRig
from . import bake_check, mesh_metrics, review_plots
from .avatar_calibration import avatar_model_for
from .blendfile import deformed_meshes, find_armature, open_avatar

CELL_PX = (300, 420)  # one frame's cell on the sheet, pixels (width, height)
PLOTS_PX = 520  # the plots' height below the frames
AVATAR_COLOUR = (0.80, 0.78, 0.74, 1.0)
SOURCE_COLOUR = (0.25, 0.45, 0.85, 1.0)
FLOOR_COLOUR = (0.55, 0.57, 0.60, 1.0)
TEXT_COLOUR = (0.10, 0.10, 0.10, 1.0)
RED = (0.85, 0.10, 0.10, 1.0)
STICK_WIDTH = 0.025  # m: the source's bones as square bars this thick
FLAG_OF_FRAME = {"worst contact gap": "contact gap", "lowest foot skin": "foot skin",
                 "largest foot slide": "foot slide", "largest wrist acceleration": "wrist acceleration"}


# --- measuring ------------------------------------------------------------------------------------------


def measure(plan: engine.ReviewPlan, arm, avatar) -> engine.Review:
    """The review of the armature's baked action: the evaluated mesh at the plan's frames (each
    foot's skin, the worst contact's gap on the skin), the armature playing what it has; then the
    engine concludes. An armature with no skinned mesh is reviewed on its figures alone."""
    if not deformed_meshes(arm):
        return plan.conclude(None)
    mesh = mesh_metrics.EvaluatedMesh(arm)
    frames = {s: plan.scene_frames[np.asarray(v, int)] for s, v in plan.skin_frames.items()}
    contact_gap = None
    with mesh_metrics.played(arm, mesh.meshes) as at:
        skin = {}
        if frames:
            every = np.concatenate(list(frames.values()))
            lows = mesh_metrics.foot_skin_at(arm, avatar, at, every, mesh)
            k = 0
            for s, f in frames.items():
                if s in lows:
                    skin[s] = lows[s]["low"][k:k + len(f)]
                k += len(f)
        if plan.contact_point is not None:
            index, _effector, target, point, offset = plan.contact_point
            # the touched part's skin, as the model's gap is to the touched element
            tris = mesh.triangles_of(mesh_metrics.target_bones(avatar, target))
            verts = at(plan.scene_frames[index])
            contact_gap = mesh_metrics.gap_to_skin(verts, tris, np.asarray(point, float)) - offset
    return plan.conclude(skin or None, None if contact_gap is None or not np.isfinite(contact_gap) else contact_gap)


# --- the sheet -------------------------------------------------------------------------------------------


def review_files(output) -> tuple[Path, Path]:
    """The review's sheet and record beside a bake's (first) output: `OUT.review.png` and
    `OUT.review.json` (FORMATS.md §4.5)."""
    out = Path(output)
    base = out.with_suffix("").name
    return out.with_name(f"{base}.review.png"), out.with_name(f"{base}.review.json")


def write_review(summary, arm, sheet: Path, record: Path, written: list, **checks) -> list[str]:
    """The sheet (`write_sheet`) and the record (FORMATS.md §4.5) of a bake's review
    (`Summary.review`, `Summary.review_plan`), each written whole; `written` the bake's outputs
    (the record lists them); `checks` as `outputs.replacing` takes them. The notes to say."""
    t0 = time.perf_counter()
    notes = write_sheet(summary.review, summary.review_plan, arm, sheet, **checks)
    sheet_s = time.perf_counter() - t0
    data = {"format": engine.FORMAT, "version": engine.VERSION, "status": "ok", "error": None, "verified": True,
            "action": summary.action, "method": summary.method, "frame_count": summary.frames, "fps": summary.fps,
            "frame_range": list(summary.frame_range) if summary.frame_range else None,
            "outputs": [str(p) for p in written], "sheet": sheet.name,
            "seconds": {"compute": round(summary.compute_s, 3), "bake": round(summary.bake_s, 3),
                        "review": round(summary.review_s, 3), "sheet": round(sheet_s, 3)},
            **summary.review.to_dict()}
    data["notes"] = [*data["notes"], *notes]
    outputs.write_text(record, json.dumps(_plain(data), allow_nan=False), **checks)
    return notes


def write_failure(record: Path, error: BodyCalError, **checks) -> None:
    """The record of a bake that failed (FORMATS.md §4.5): its one line, and whether it was the
    check on the evaluated rig (then one flag, `verification`, which puts it first)."""
    verification = isinstance(error, bake_check.VerificationFailed)
    review = engine.verification_failed(error.line()) if verification else engine.Review([])
    data = {"format": engine.FORMAT, "version": engine.VERSION, "status": "failed", "error": error.line(),
            "verified": False if verification else None, "outputs": [], "sheet": None, **review.to_dict()}
    outputs.write_text(record, json.dumps(_plain(data), allow_nan=False), **checks)


def _plain(value):
    """`value` as plain JSON: numpy's numbers and arrays as Python's, a NaN or infinite number as null."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple, np.ndarray)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_sheet(review: engine.Review, plan: engine.ReviewPlan, arm, path, **checks) -> list[str]:
    """The review sheet of the armature's baked action as a PNG at `path` (written whole,
    `outputs.replacing` with `checks`); the notes to say (the plots left out without matplotlib)."""
    path = Path(path)
    notes = []
    with tempfile.TemporaryDirectory(prefix="bodycal-review-") as tmp:
        frames_png = Path(tmp) / "frames.png"
        render_frames(review, plan, arm, frames_png)
        with outputs.replacing(path, **checks) as partial:
            if review_plots.available():
                review_plots.compose(review, frames_png, partial, PLOTS_PX)
            else:
                notes.append("the review sheet has no plots: matplotlib is not installed in this Python "
                             "(docs/DESIGN.md §7, Review)")
                partial.write_bytes(frames_png.read_bytes())
    return notes


def render_frames(review: engine.Review, plan: engine.ReviewPlan, arm, path: Path) -> None:
    """The sheet's frames, side by side, rendered by the Workbench engine to `path` (PNG)."""
    shots = review.frames or [engine.SheetFrame("middle of the take", 0, float(plan.scene_frames[0]), "")]
    meshes = deformed_meshes(arm)
    scene = bpy.data.scenes.new("BodyCal Review")
    made: list = []
    try:
        forward = np.asarray(plan.forward, float)
        right = np.array([-forward[1], forward[0], 0.0])  # the camera's right, seen from the front
        height = plan.height
        spacing = 1.3 * height
        over = {f.name for f in review.flags if f.over}
        with mesh_metrics.played(arm, meshes) as at:
            for k, shot in enumerate(shots):
                at(shot.frame)
                pelvis = _pelvis(arm, plan.pelvis_bone)
                centre = right * (k * spacing) + np.array([0.0, 0.0, plan.floor])
                shift = centre - np.array([pelvis[0], pelvis[1], plan.floor])
                for obj in meshes:
                    made.append(_snapshot(obj, scene, shift))
                ghost = plan.ghost(shot.index)
                if ghost is not None:
                    g_pelvis = ghost["pelvis"]
                    g_shift = centre + right * (0.45 * height) - np.array([g_pelvis[0], g_pelvis[1], plan.floor])
                    made.append(_stick_figure(scene, ghost, g_shift))
                colour = RED if FLAG_OF_FRAME.get(shot.title) in over else TEXT_COLOUR
                label = f"{shot.title}\n{shot.label}\nframe {shot.frame:g}"
                made.append(_text(scene, label, centre + np.array([0.0, 0.0, 1.12 * height]) + right * 0.15 * height,
                                  forward, right, 0.055 * height, colour))
        made.append(_floor(scene, right, forward, plan.floor, len(shots), spacing, height))
        made.append(_camera(scene, right, forward, plan.floor, len(shots), spacing, height))
        _render(scene, path, len(shots))
    finally:
        for obj in made:
            data = obj.data
            bpy.data.objects.remove(obj, do_unlink=True)
            if data is not None and data.users == 0:
                for collection in (bpy.data.meshes, bpy.data.curves, bpy.data.cameras):
                    if data.name in collection and collection[data.name] == data:
                        collection.remove(data)
                        break
        world = scene.world
        bpy.data.scenes.remove(scene)
        if world is not None and world.users == 0:
            bpy.data.worlds.remove(world)


def _pelvis(arm, bone: str | None) -> np.ndarray:
    """The pelvis's world position as the armature plays it now."""
    if bone in arm.pose.bones:
        return np.array(arm.matrix_world @ arm.pose.bones[bone].head)
    return np.array(arm.matrix_world.translation)


def _snapshot(obj, scene, shift: np.ndarray):
    """A still copy of the skinned mesh as evaluated now, moved by `shift`, in `scene`."""
    dg = bpy.context.evaluated_depsgraph_get()
    mesh = bpy.data.meshes.new_from_object(obj.evaluated_get(dg), preserve_all_data_layers=False, depsgraph=dg)
    copy = bpy.data.objects.new(f"review.{obj.name}", mesh)
    m = np.array(obj.matrix_world)
    m[:3, 3] += shift
    copy.matrix_world = m.T.tolist()
    copy.color = AVATAR_COLOUR
    scene.collection.objects.link(copy)
    return copy


def _stick_figure(scene, joints: dict, shift: np.ndarray):
    """The source's skeleton as square bars between its joints, moved by `shift`."""
    verts, faces = [], []
    corners = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], float) * STICK_WIDTH / 2
    for a, b in engine.GHOST_BONES:
        if a not in joints or b not in joints:
            continue
        p, q = np.asarray(joints[a], float) + shift, np.asarray(joints[b], float) + shift
        axis = q - p
        n = np.linalg.norm(axis)
        if n < 1e-6:
            continue
        axis /= n
        u = np.cross(axis, [0.0, 0.0, 1.0] if abs(axis[2]) < 0.9 else [1.0, 0.0, 0.0])
        u /= np.linalg.norm(u)
        v = np.cross(axis, u)
        base = len(verts)
        for end in (p, q):
            verts += [end + c[0] * u + c[1] * v for c in corners]
        faces += [[base + i, base + (i + 1) % 4, base + 4 + (i + 1) % 4, base + 4 + i] for i in range(4)]
        faces += [[base + 3, base + 2, base + 1, base], [base + 4, base + 5, base + 6, base + 7]]
    mesh = bpy.data.meshes.new("review.source")
    mesh.from_pydata([tuple(map(float, x)) for x in verts], [], faces)
    obj = bpy.data.objects.new("review.source", mesh)
    obj.color = SOURCE_COLOUR
    scene.collection.objects.link(obj)
    return obj


def _text(scene, body: str, where: np.ndarray, forward: np.ndarray, right: np.ndarray, size: float, colour):
    curve = bpy.data.curves.new("review.label", type="FONT")
    curve.body = body
    curve.size = size
    curve.align_x = "CENTER"
    obj = bpy.data.objects.new("review.label", curve)
    # the text's plane faces the camera: its x along the camera's right, its y up
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2] = right, [0.0, 0.0, 1.0], forward
    m[:3, 3] = where
    obj.matrix_world = m.T.tolist()
    obj.color = colour
    scene.collection.objects.link(obj)
    return obj


def _floor(scene, right, forward, floor: float, cells: int, spacing: float, height: float):
    half_w, half_d = 0.5 * spacing, 0.6 * height
    a, b = -half_w, (cells - 1) * spacing + half_w + 0.3 * height
    corners = [right * x + forward * y + np.array([0.0, 0.0, floor]) for x, y in
               ((a, -half_d), (b, -half_d), (b, half_d), (a, half_d))]
    mesh = bpy.data.meshes.new("review.floor")
    mesh.from_pydata([tuple(map(float, c)) for c in corners], [], [[0, 1, 2, 3]])
    obj = bpy.data.objects.new("review.floor", mesh)
    obj.color = FLOOR_COLOUR
    scene.collection.objects.link(obj)
    return obj


def _camera(scene, right, forward, floor: float, cells: int, spacing: float, height: float):
    cam = bpy.data.cameras.new("review.camera")
    cam.type = "ORTHO"
    width = cells * spacing
    cam.ortho_scale = width
    obj = bpy.data.objects.new("review.camera", cam)
    centre = right * ((cells - 1) * spacing / 2 + 0.15 * height) + np.array([0.0, 0.0, floor + 0.62 * height])
    tilt = math.radians(8.0)  # a little from above: the floor and the feet on it show
    back = forward * math.cos(tilt) + np.array([0.0, 0.0, math.sin(tilt)])
    m = np.eye(4)
    z = back / np.linalg.norm(back)  # a camera looks down its -Z
    x = right
    y = np.cross(z, x)
    m[:3, 0], m[:3, 1], m[:3, 2], m[:3, 3] = x, y, z, centre + z * 10.0 * height
    obj.matrix_world = m.T.tolist()
    cam.clip_end = 40.0 * height
    scene.collection.objects.link(obj)
    scene.camera = obj
    return obj


def _render(scene, path: Path, cells: int) -> None:
    render = scene.render
    render.engine = "BLENDER_WORKBENCH"
    render.resolution_x, render.resolution_y = CELL_PX[0] * cells, CELL_PX[1]
    render.resolution_percentage = 100
    render.image_settings.file_format = "PNG"
    render.image_settings.color_mode = "RGB"
    scene.display.render_aa = "FXAA"
    shading = scene.display.shading
    shading.light = "STUDIO"
    shading.color_type = "OBJECT"
    shading.show_cavity = False
    shading.show_shadows = False
    scene.view_settings.view_transform = "Standard"
    scene.world = bpy.data.worlds.new("review.world")
    scene.world.color = (0.96, 0.96, 0.96)
    bpy.ops.render.render(write_still=False, scene=scene.name)
    result = bpy.data.images.get("Render Result")
    if result is None:
        raise BodyCalError("the Workbench render made no image", source=str(path))
    result.save_render(str(path), scene=scene)


# --- an existing output ------------------------------------------------------------------------------------


def played_animation(arm, avatar, name: str = "") -> AvatarAnimation:
    """The animation the armature plays (its action over the action's frame range, at the scene's
    rate, constraints and drivers included) in the engine's terms for `avatar`'s rig: every rig
    bone's pose read back from Blender's evaluated pose matrices by inverting the rig's FK
    (`AvatarRig.fk`), the canonical joints from it. The scene's frame is put back."""
    ad = arm.animation_data
    action = ad.action if ad is not None else None
    if action is None:
        raise BodyCalError("the armature has no action: nothing to review", source=arm.name,
                           hint="give a file with a baked avatar (bodycal retarget, transfer or batch)")
    rig = AvatarRig.from_model(avatar)
    scene = bpy.context.scene
    first, last = (int(math.floor(action.frame_range[0])), int(math.ceil(action.frame_range[1])))
    frames = np.arange(first, max(first, last) + 1)
    order = {pb.name: i for i, pb in enumerate(arm.pose.bones)}
    missing = [n for n in rig.names if n not in order]
    if missing:
        raise BodyCalError(f"the armature has no bones named {', '.join(missing[:6])}", source=arm.name,
                           hint="calibrate the avatar again after renaming bones")
    pick = np.array([order[n] for n in rig.names])
    buf = np.empty(len(arm.pose.bones) * 16, np.float32)
    pose = np.empty((len(frames), len(rig.names), 4, 4))
    hidden = [m for m in deformed_meshes(arm) if not m.hide_viewport]
    was = scene.frame_current, scene.frame_subframe
    try:
        for m in hidden:  # the meshes are not needed to read the bones: 3x faster frame changes
            m.hide_viewport = True
        for k, f in enumerate(frames):
            scene.frame_set(int(f))
            arm.pose.bones.foreach_get("matrix", buf)
            pose[k] = buf.reshape(-1, 4, 4)[pick].swapaxes(-1, -2)  # Blender's matrices are column-major
    finally:
        for m in hidden:
            m.hide_viewport = False
        scene.frame_set(was[0], subframe=was[1])
    basis, locations = rig_basis(rig, pose)
    fps = scene.render.fps / scene.render.fps_base
    time_s = (frames - frames[0]) / fps
    others = {rig.names[i]: locations[:, i] for i in range(len(rig.names))
              if i != rig.root and np.abs(locations[:, i]).max() > 1e-7}
    joints = {}
    for a in range(0, len(frames), engine.CHUNK):
        b = min(len(frames), a + engine.CHUNK)
        fk = rig.fk(basis[a:b], locations[a:b, rig.root], locations=locations[a:b])
        for i, j in enumerate(sk.JOINTS):
            joints.setdefault(j, np.empty((len(frames), 3)))[a:b] = fk.joints[:, i]
    method = action.name.rsplit("|", 1)[-1] if "|" in action.name else "egocentric"
    return AvatarAnimation(rig.armature, list(rig.names), basis, rig.names[rig.root], locations[:, rig.root],
                           time_s, method, joints, {}, [name] if name else [], others)


def rig_basis(rig: AvatarRig, pose: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(basis (F, N, 4), locations (F, N, 3)): the pose-bone values that put the rig's bones where
    `pose` (F, N, 4, 4) armature-space matrices (Blender's `PoseBone.matrix`) says: `AvatarRig.fk`
    inverted bone by bone, parents first (a bone's scale is left out)."""
    P = pose[..., :3, :3] / np.linalg.norm(pose[..., :3, :3], axis=-2, keepdims=True)
    H = pose[..., :3, 3]
    nf, n = pose.shape[:2]
    basis = np.empty((nf, n, 3, 3))
    locations = np.empty((nf, n, 3))
    for i in range(n):
        p = rig.parent[i]
        if p < 0:
            basis[:, i] = rig.rest[i].T @ P[:, i]
            locations[:, i] = (H[:, i] - rig.head[i]) @ rig.rest[i]
        else:
            pr = P[:, p] @ (rig.rest[p].T @ rig.rest[i])  # (F, 3, 3): the parent's pose carried onto i's rest
            basis[:, i] = pr.swapaxes(-1, -2) @ P[:, i]
            offset = H[:, i] - H[:, p] - P[:, p] @ (rig.rest[p].T @ (rig.head[i] - rig.head[p]))
            locations[:, i] = (pr.swapaxes(-1, -2) @ offset[..., None])[..., 0]
    return matrix_to_quat(basis), locations


def review_output(output, *, armature: str | None = None, take=None, placement: str = "object",
                  sheet=None, overwrite: bool = False, inputs=(), log=print) -> engine.Review:
    """`bodycal review OUTPUT`: the review of a baked avatar file (a .blend, .fbx, .glb, .gltf), its
    sheet and record beside it (or `sheet` and the record beside that); `take` the source it was
    made from (retarget/takes.py's, read before the output is opened), None for none."""
    output = Path(output)
    png, record = review_files(sheet if sheet is not None else output)
    if sheet is not None:
        png = Path(sheet)
    files_read = [("the reviewed file", output), *inputs]
    for path in (png, record):
        outputs.check_output(path, inputs=files_read, overwrite=overwrite)
    open_avatar(output)
    arm = find_armature(armature, str(output))
    avatar, _ = avatar_model_for(arm)
    t0 = time.perf_counter()
    anim = played_animation(arm, avatar)
    first = float(math.floor(arm.animation_data.action.frame_range[0]))
    source = None
    if take is not None:
        pose_source = take.pose_source(placement)
        motion = engine.source_motion(pose_source, avatar, anim.method, placement)
        source = motion.at(_sample_of(take, pose_source.time, first + np.arange(anim.frame_count)))
    rate = bpy.context.scene.render.fps / bpy.context.scene.render.fps_base
    plan = engine.plan(anim, avatar, source, first, rate)
    review = measure(plan, arm, avatar)
    notes = write_sheet(review, plan, arm, png, inputs=files_read, overwrite=True)
    data = {"format": engine.FORMAT, "version": engine.VERSION, "status": "ok", "error": None, "verified": None,
            "action": arm.animation_data.action.name, "method": anim.method, "frame_count": anim.frame_count,
            "fps": rate, "frame_range": [first, first + anim.frame_count - 1], "outputs": [str(output)],
            "sheet": png.name, "seconds": {"review": round(time.perf_counter() - t0, 3)}, **review.to_dict()}
    data["notes"] = [*data["notes"], *notes]
    outputs.write_text(record, json.dumps(_plain(data), allow_nan=False), inputs=files_read, overwrite=True)
    for note in notes:
        log(note)
    for flag in review.flags:
        log(f"review: {'OVER ' if flag.over else ''}{flag.text}")
    log(f"saved {png}")
    log(f"saved {record}")
    return review


def _sample_of(take, time_s, scene_frames: np.ndarray) -> np.ndarray:
    """The take's sample (times `time_s`) played at each scene frame (the nearest; `retarget` and
    `transfer` key sample k at frame_start + (t_k - t_0) x rate)."""
    t = np.asarray(time_s, float)
    frames = take.frame_start + (t - t[0]) * take.rate
    return np.clip(np.rint(np.interp(scene_frames, frames, np.arange(len(frames)))).astype(int), 0, len(frames) - 1)
