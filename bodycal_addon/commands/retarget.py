"""`bodycal retarget REC --user USER.body.json --avatar FILE.blend [--armature NAME] [--method M]
[--filter [MIN_CUTOFF,BETA[,ROT_MIN,ROT_BETA]]] [--no-plant-feet] -o OUT.blend [--overwrite]`."""


def run(args) -> int:
    from ..blender.retarget_scene import retarget_files
    from ..filters import OneEuro

    cfg = None if getattr(args, "filter", None) is None else OneEuro.parse(args.filter)
    retarget_files(args.recording, args.user, args.avatar, args.output, armature=args.armature, method=args.method,
                   filter=cfg, plant_feet=getattr(args, "plant_feet", True),
                   overwrite=getattr(args, "overwrite", False))
    return 0
