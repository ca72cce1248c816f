"""`bodycal calibrate-avatar AVATAR [--armature NAME] [--bone-map FILE] -o AVATAR.body.json`
(FORMATS.md §4): surface calibration by raycasting onto the avatar's mesh. AVATAR is a .blend
(read, never written) or an .fbx, .glb, .gltf or .vrm imported by Blender's own importer; a bone
map preset is checked before it is opened. One `warning:` line on stderr per doubt about the
armature object's transform (placement.avatar_warnings)."""

from __future__ import annotations

from ...body.bone_presets import load_preset
from ...core.outputs import check_output
from ...retarget.placement import avatar_warnings
from .. import console


def run(args) -> int:
    # Blender's glue, loaded when the command runs (the module is imported without Blender too)
    from ...blender.avatar_calibration import calibrate_avatar
    from ...blender.avatar_rig import apply_preset
    from ...blender.blendfile import find_armature, open_avatar
    from ...blender.session import avatar_input

    bone_map = getattr(args, "bone_map", None)
    files_read = [avatar_input(args.avatar), ("the bone map (--bone-map)", bone_map)]
    overwrite = getattr(args, "overwrite", False)
    check_output(args.output, inputs=files_read, overwrite=overwrite)  # before opening anything
    preset = load_preset(bone_map) if bone_map else None
    with console.progress("calibrate-avatar") as step:
        step("opening the avatar", 0.0)
        for note in open_avatar(args.avatar):
            console.say(note)
        arm = find_armature(args.armature, str(args.avatar))
        if preset is not None:
            apply_preset(arm, preset)
        step("raycasting its surface", 0.3)
        model = calibrate_avatar(arm)
        for line in avatar_warnings(model):
            console.warn("calibrate-avatar", line)
        step("saving", 0.95)
        out = model.save(args.output, inputs=files_read, overwrite=overwrite)
        step("saving", 1.0)
    q = model.calibration["quality"]
    console.say(f"{out}: avatar {arm.name}, {len(model.joints)} joints, {len(model.surface)} surface elements, "
                f"{sum(v['hit'] for v in q.values())} ray hits, rest pose {model.extra['rig']['rest_pose']}")
    return 0
