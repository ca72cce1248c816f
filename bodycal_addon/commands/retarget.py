"""`bodycal retarget REC --user USER.body.json --avatar FILE.blend [--armature NAME] [--bone-map FILE]
[--method M] [--filter [MIN_CUTOFF,BETA[,ROT_MIN,ROT_BETA]]] [--no-plant-feet] [--tolerance DEG]
[--location-tolerance MM] [--fps N] -o OUT.blend|.fbx|.glb|.gltf|.bvh [-o ...] [--overwrite]`."""


def run(args) -> int:
    from ..blender.bake import BakeOptions
    from ..blender.retarget_scene import retarget_files
    from ..bone_presets import load_preset
    from ..filters import OneEuro
    from ..outputs import check_output

    cfg = None if getattr(args, "filter", None) is None else OneEuro.parse(args.filter)
    options = BakeOptions(args.tolerance, args.location_tolerance, args.fps)
    bone_map = getattr(args, "bone_map", None)
    preset = None
    if bone_map:  # checked, like every input, before the avatar's .blend is opened
        for out in args.output:
            check_output(out, inputs=[("the bone map (--bone-map)", bone_map)],
                         overwrite=getattr(args, "overwrite", False))
        preset = load_preset(bone_map)
    retarget_files(args.recording, args.user, args.avatar, args.output, armature=args.armature, method=args.method,
                   filter=cfg, plant_feet=getattr(args, "plant_feet", True),
                   overwrite=getattr(args, "overwrite", False), options=options, bone_map=preset)
    return 0
