"""`bodycal retarget REC --user USER.body.json --avatar FILE.blend [--armature NAME] [--bone-map FILE]
[--method M] [--filter [MIN_CUTOFF,BETA[,ROT_MIN,ROT_BETA]]] [--no-plant-feet] [--tolerance DEG]
[--location-tolerance MM] [--fps N] -o OUT.blend|.fbx|.glb|.gltf|.bvh [-o ...] [--overwrite]`."""


def run(args) -> int:
    from ..blender.bake import BakeOptions
    from ..blender.retarget_scene import retarget_files
    from ..filters import OneEuro

    cfg = None if getattr(args, "filter", None) is None else OneEuro.parse(args.filter)
    options = BakeOptions(args.tolerance, args.location_tolerance, args.fps)
    retarget_files(args.recording, args.user, args.avatar, args.output, armature=args.armature, method=args.method,
                   filter=cfg, plant_feet=getattr(args, "plant_feet", True),
                   overwrite=getattr(args, "overwrite", False), options=options,
                   bone_map_path=getattr(args, "bone_map", None))
    return 0
