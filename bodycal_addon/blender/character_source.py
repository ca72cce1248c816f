"""Another character as a pose source: its armature, body model and action read into numpy
(`read_source` -> `retarget.takes.CharacterTake`), and the files such a source comes in
(`open_source`: a .blend, or a .bvh / .fbx / .glb / .gltf imported into an empty scene).

Reading an action never steps the scene frame by frame: every F-Curve is sampled once (its keys
when they sit on the sampled frames, as a BVH import's do; else `FCurve.evaluate` per frame),
Euler and axis-angle rotations are turned into quaternions in numpy, and the pose is evaluated by
the engine's FK (`AvatarRig.fk`, the same Blender pose rule). What the F-Curves do not say (NLA
strips, constraints, drivers, the armature object's own animation) is not read.
"""

from __future__ import annotations

from pathlib import Path

import bpy
import numpy as np

from ..avatar.estimate import ESTIMATED
from ..core.errors import BodyCalError
from ..core.paths import ANIMATION_SUFFIXES
from ..core.transforms import axis_angle_to_quat, euler_matrices, matrix_to_quat, quat_normalize
from ..retarget.avatar_pose import AvatarRig
from ..retarget.takes import CharacterTake
from ..retarget.transfer import stand_on_floor
from .avatar_calibration import avatar_model_for
from .blendfile import open_avatar
from .fcurves import object_fcurves, sample_fcurve
from .process import stderr_to_stdout

# Metres per file unit a BVH may be written in (m, cm, inch, CMU's inch / 0.45, mm): the one that
# makes the skeleton's rest height closest to a human's is taken (BLENDER_NOTES.md, BVH import).
BVH_UNITS = {"m": 1.0, "cm": 0.01, "in": 0.0254, "cmu": 0.0254 / 0.45, "mm": 0.001}
HUMAN_HEIGHT_M = 1.7


def read_action(arm, action, names: list[str], frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(basis (F, N, 4), locations (F, N, 3)) of `action` on armature object `arm` for the pose
    bones `names`, at `frames`. A channel without an F-Curve keeps the pose bone's current value."""
    ad = arm.animation_data or arm.animation_data_create()
    previous = ad.action
    try:
        if ad.action != action:
            ad.action = action
        curves = object_fcurves(arm)
    finally:
        if previous != action:
            ad.action = previous
    if not any(path.startswith(f'pose.bones["{name}"]') for path, _ in curves for name in names):
        # (4.4+: an action whose slot is for another data-block gives the object no F-Curves)
        raise BodyCalError(f"the action '{action.name}' animates none of the armature's bones", source=arm.name,
                           field="--action", hint="pick the armature's own action")
    nf, n = len(frames), len(names)
    basis = np.empty((nf, n, 4))
    locations = np.empty((nf, n, 3))

    def channel(bone, prop, size, current):
        out = np.empty((nf, size))
        for k in range(size):
            fc = curves.get((f'pose.bones["{bone}"].{prop}', k))
            out[:, k] = sample_fcurve(fc, frames) if fc is not None else current[k]
        return out

    for i, name in enumerate(names):
        pb = arm.pose.bones[name]
        locations[:, i] = channel(name, "location", 3, list(pb.location))
        mode = pb.rotation_mode
        if mode == "QUATERNION":
            basis[:, i] = quat_normalize(channel(name, "rotation_quaternion", 4, list(pb.rotation_quaternion)))
        elif mode == "AXIS_ANGLE":
            v = channel(name, "rotation_axis_angle", 4, list(pb.rotation_axis_angle))  # (angle, x, y, z)
            basis[:, i] = axis_angle_to_quat(v[:, 1:], v[:, 0])
        else:
            basis[:, i] = matrix_to_quat(euler_matrices(channel(name, "rotation_euler", 3, list(pb.rotation_euler)),
                                                         mode))
    return basis, locations


def pick_action(arm, name: str | None, source: str):
    """The action named `name`, else the armature's active action, else the file's only action."""
    if name:
        action = bpy.data.actions.get(name)
        if action is None:
            have = ", ".join(sorted(a.name for a in bpy.data.actions)) or "none"
            raise BodyCalError(f"no action named '{name}' (actions in the file: {have})", source=source,
                               field="--action")
        return action
    if arm.animation_data is not None and arm.animation_data.action is not None:
        return arm.animation_data.action
    actions = list(bpy.data.actions)
    if len(actions) == 1:
        return actions[0]
    if not actions:
        raise BodyCalError("the source has no animation (no action)", source=source)
    raise BodyCalError(f"several actions ({', '.join(sorted(a.name for a in actions))}) and none is active: pick "
                       "one", source=source, hint="use --action NAME")


def read_source(arm, action=None, *, frame_range: tuple[int, int] | None = None, fps: float | None = None
                ) -> CharacterTake:
    """The source armature `arm` and its action (default: the active one) in numpy, every frame
    of the action's range (or `frame_range`) at the scene's rate (or `fps`)."""
    if arm is None or getattr(arm, "type", None) != "ARMATURE":
        raise BodyCalError("pick a source armature", source=getattr(arm, "name", "no object"))
    action = action or pick_action(arm, None, arm.name)
    scene = bpy.context.scene
    fps = float(fps or scene.render.fps / scene.render.fps_base)
    f0, f1 = frame_range or (int(np.floor(action.frame_range[0])), int(np.ceil(action.frame_range[1])))
    if f1 < f0:
        raise BodyCalError("the action's frame range is empty", source=action.name)
    frames = np.arange(f0, f1 + 1, dtype=float)
    model = avatar_model_for(arm)[0]  # its stored model, else the calibration's (read at rest), else the estimate
    names = AvatarRig.from_model(model).names
    basis, locations = read_action(arm, action, names, frames)
    notes = []
    if model.calibration.get("method") == ESTIMATED:
        model, locations, lift, motion = stand_on_floor(model, locations, basis, (frames - f0) / fps)
        notes.append(f"{arm.name}: no mesh, body surface estimated from its bone lengths; its rest pose stood "
                     f"on the floor ({lift * 1000:+.0f} mm), its motion's feet on it ({motion * 1000:+.0f} mm)")
    return CharacterTake(model, basis, locations, (frames - f0) / fps, fps, action.name, arm.name, notes,
                         frame_start=float(f0))


def bvh_unit(path) -> tuple[str, float]:
    """(name, metres per unit) of a BVH file: the unit of BVH_UNITS that makes the rest skeleton's
    vertical extent (Y up, end sites included) closest to a human's height."""
    toks = Path(path).read_text(errors="replace").split()
    ys, stack, y = [], [], 0.0
    i = 0
    try:
        while i < len(toks) and toks[i] != "MOTION":
            t = toks[i]
            if t == "{":
                stack.append(y)
            elif t == "}":
                y = stack.pop() if stack else 0.0
                if stack:
                    y = stack[-1]
            elif t == "OFFSET":
                y = (stack[-1] if stack else 0.0) + float(toks[i + 2])
                ys.append(y)
                i += 3
            i += 1
    except (ValueError, IndexError):
        raise BodyCalError("not a BVH file Blender can read (its HIERARCHY is malformed)", source=str(path)) from None
    extent = (max(ys) - min(ys)) if ys else 0.0
    if not extent > 0:
        raise BodyCalError("the BVH skeleton has no height", source=str(path))
    return min(BVH_UNITS.items(), key=lambda kv: abs(np.log(extent * kv[1] / (HUMAN_HEIGHT_M * 0.9))))


def open_source(path) -> list[str]:
    """Make the source file the open file (a .blend opened, a .bvh / .fbx / .glb / .gltf imported
    into an empty scene); returns notes (a BVH's unit, skins an FBX import had to bind again)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in ANIMATION_SUFFIXES:
        raise BodyCalError(f"not an animation source this version reads (it reads {', '.join(ANIMATION_SUFFIXES)})",
                           source=str(path))
    if not path.is_file():
        raise BodyCalError("no such file", source=str(path))
    if suffix != ".bvh":
        return open_avatar(path)
    unit, scale = bvh_unit(path)
    bpy.ops.wm.read_homefile(use_empty=True)
    with stderr_to_stdout():
        try:
            # Blender's importer turns the BVH's Y up into Z up, keys every BVH frame from frame 1
            # and sets the scene's rate to the file's.
            result = bpy.ops.import_anim.bvh(filepath=str(path.resolve()), global_scale=scale, frame_start=1,
                                             use_fps_scale=False, update_scene_fps=True,
                                             update_scene_duration=True, rotate_mode="NATIVE")
        except (RuntimeError, ValueError, IndexError) as exc:
            raise BodyCalError(f"Blender's BVH importer cannot read it ({str(exc).strip().splitlines()[-1][:120]})",
                               source=str(path)) from None
    if "FINISHED" not in result:
        raise BodyCalError("Blender's BVH importer gave up on it", source=str(path))
    return [f"{path.name}: BVH read in {unit} ({scale:.6g} m per unit)"]
