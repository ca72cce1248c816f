"""`bodycal retarget REC --user USER.body.json --avatar AVATAR [--armature NAME] [--method M]
[--placement object|performer] [--filter [MIN_CUTOFF,BETA[,ROT_MIN,ROT_BETA]]] [--no-plant-feet]
-o OUT.blend [--overwrite]`; AVATAR is a .blend, .fbx, .glb, .gltf or .vrm."""

import sys


def run(args) -> int:
    from ..blender.retarget_scene import retarget_files
    from ..filters import OneEuro

    cfg = None if getattr(args, "filter", None) is None else OneEuro.parse(args.filter)
    retarget_files(args.recording, args.user, args.avatar, args.output, armature=args.armature, method=args.method,
                   filter=cfg, plant_feet=getattr(args, "plant_feet", True),
                   placement=getattr(args, "placement", "object"), overwrite=getattr(args, "overwrite", False),
                   warn=lambda line: print(f"bodycal retarget: warning: {line}", file=sys.stderr, flush=True))
    return 0
