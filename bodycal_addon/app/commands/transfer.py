"""`bodycal transfer SOURCE --avatar AVATAR -o OUT [-o ...] [--source-armature NAME] [--action NAME]
[--armature NAME] [--bone-map FILE] [--method egocentric|rotations] [--placement object|performer] [--no-plant-feet]
[--root-motion root|pelvis|in-place] [--rigify-target fk|def]
[--tolerance DEG] [--location-tolerance MM] [--interpolation linear|bezier] [--fps N] [--frame-range FIRST LAST]
[--overwrite]`; SOURCE is a .blend, .bvh,
.fbx, .glb or .gltf with an animated humanoid armature, AVATAR a .blend, .fbx, .glb, .gltf or .vrm."""

from .. import console


def run(args) -> int:
    from ...blender import session
    from .retarget import bake_options, frame_range

    session.transfer_files(args.source, args.avatar, args.output, source_armature=args.source_armature,
                           action=args.action, armature=args.armature,
                           settings=session.Settings(args.method, args.plant_feet, args.placement),
                           overwrite=args.overwrite, options=bake_options(args), bone_map_path=args.bone_map,
                           frame_range=frame_range(args),
                           log=console.say, warn=lambda line: console.warn("transfer", line))
    return 0
