"""`bodycal calibrate-avatar FILE.blend [--armature NAME] -o AVATAR.body.json` (FORMATS.md §4):
surface calibration by raycasting onto the avatar's mesh. The .blend is read, never written."""

from __future__ import annotations

import sys
from pathlib import Path

from ..errors import BodyCalError


def pick_armature(name: str | None, source: str):
    import bpy

    armatures = [o for o in bpy.data.objects if o.type == "ARMATURE"]
    if name:
        arm = bpy.data.objects.get(name)
        if arm is None or arm.type != "ARMATURE":
            have = ", ".join(sorted(o.name for o in armatures)) or "none"
            raise BodyCalError(f"no armature named '{name}' (armatures in the file: {have})", source=source,
                               field="--armature")
        return arm
    if not armatures:
        raise BodyCalError("the file has no armature", source=source)
    if len(armatures) > 1:
        raise BodyCalError(f"several armatures ({', '.join(sorted(o.name for o in armatures))}): pick one",
                           source=source, hint="use --armature NAME")
    return armatures[0]


def run(args) -> int:
    path = Path(args.blend)
    if not path.is_file():
        raise BodyCalError("no such file", source=str(path))
    import bpy

    from ..blender.avatar_calibration import calibrate_avatar

    try:
        bpy.ops.wm.open_mainfile(filepath=str(path.resolve()), load_ui=False)
    except RuntimeError as exc:
        raise BodyCalError(f"Blender cannot open it ({str(exc).strip().splitlines()[-1][:120]})",
                           source=str(path)) from None
    arm = pick_armature(args.armature, str(path))
    model = calibrate_avatar(arm)
    out = model.save(args.output)
    q = model.calibration["quality"]
    print(f"{out}: avatar {arm.name}, {len(model.joints)} joints, {len(model.surface)} surface elements, "
          f"{sum(v['hit'] for v in q.values())} ray hits, rest pose {model.extra['rig']['rest_pose']}")
    sys.stdout.flush()
    return 0
