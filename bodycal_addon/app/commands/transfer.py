"""`bodycal transfer SOURCE --avatar AVATAR -o OUT [-o ...] [--source-armature NAME] [--action NAME]
[--armature NAME] [--bone-map FILE] [--method egocentric|rotations] [--filter [MIN_CUTOFF,BETA[,ROT_MIN,ROT_BETA]]]
[--placement object|performer] [--no-plant-feet]
[--root-motion root|pelvis|in-place] [--rigify-target fk|def]
[--tolerance DEG] [--location-tolerance MM] [--interpolation linear|bezier] [--fps N] [--frame-range FIRST LAST]
[--overwrite] [--review]`; SOURCE is a .blend, .bvh,
.fbx, .glb or .gltf with an animated humanoid armature, AVATAR a .blend, .fbx, .glb, .gltf or .vrm."""

from ...recording.filters import OneEuro
from .. import console
from .retarget import bake_options, frame_range


def run(args) -> int:
    from ...blender import session

    cfg = None if getattr(args, "filter", None) is None else OneEuro.parse(args.filter)
    with console.progress("transfer") as step:
        session.transfer_files(args.source, args.avatar, args.output, source_armature=args.source_armature,
                               action=args.action, armature=args.armature, filter=cfg,
                               settings=session.Settings(args.method, args.plant_feet, args.placement),
                               overwrite=args.overwrite, options=bake_options(args), bone_map_path=args.bone_map,
                               frame_range=frame_range(args), review=getattr(args, "review", False),
                               log=console.say, warn=lambda line: console.warn("transfer", line), progress=step)
    return 0
