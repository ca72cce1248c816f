"""`bodycal calibrate-avatar FILE.blend [--armature NAME] -o AVATAR.body.json` (FORMATS.md §4):
surface calibration by raycasting onto the avatar's mesh. The .blend is read, never written."""

from __future__ import annotations

import sys


def run(args) -> int:
    from ..blender.avatar_calibration import calibrate_avatar
    from ..blender.blendfile import find_armature, open_blend
    from ..outputs import check_output

    files_read = [("the avatar .blend", args.blend)]
    overwrite = getattr(args, "overwrite", False)
    check_output(args.output, inputs=files_read, overwrite=overwrite)  # before opening anything
    open_blend(args.blend)
    arm = find_armature(args.armature, str(args.blend))
    model = calibrate_avatar(arm)
    out = model.save(args.output, inputs=files_read, overwrite=overwrite)
    q = model.calibration["quality"]
    print(f"{out}: avatar {arm.name}, {len(model.joints)} joints, {len(model.surface)} surface elements, "
          f"{sum(v['hit'] for v in q.values())} ray hits, rest pose {model.extra['rig']['rest_pose']}")
    sys.stdout.flush()
    return 0
