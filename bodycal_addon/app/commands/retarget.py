"""`bodycal retarget REC --user USER.body.json --avatar AVATAR [--armature NAME] [--bone-map FILE]
[--method M] [--placement object|performer] [--filter [MIN_CUTOFF,BETA[,ROT_MIN,ROT_BETA]]]
[--no-plant-feet] [--root-motion root|pelvis|in-place] [--rigify-target fk|def]
[--tolerance DEG] [--location-tolerance MM] [--fps N]
-o OUT.blend|.fbx|.glb|.gltf|.bvh [-o ...] [--overwrite]`; AVATAR is a .blend, .fbx, .glb, .gltf or .vrm."""

from .. import console


def run(args) -> int:
    from ...blender import session
    from ...recording.filters import OneEuro

    cfg = None if getattr(args, "filter", None) is None else OneEuro.parse(args.filter)
    session.retarget_files(args.recording, args.user, args.avatar, args.output, filter=cfg, armature=args.armature,
                           settings=session.Settings(args.method, getattr(args, "plant_feet", True),
                                                     getattr(args, "placement", "object")),
                           overwrite=getattr(args, "overwrite", False), options=bake_options(args),
                           bone_map_path=getattr(args, "bone_map", None),
                           log=console.say, warn=lambda line: console.warn("retarget", line))
    return 0


def bake_options(args):
    """The bake options every baking command takes (--tolerance, --location-tolerance, --fps,
    --root-motion, --rigify-target)."""
    from ...blender.bake import BakeOptions

    return BakeOptions(args.tolerance, args.location_tolerance, args.fps, getattr(args, "root_motion", "root"),
                       getattr(args, "rigify_target", "fk"))
