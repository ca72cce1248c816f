"""`bodycal retarget REC --user USER.body.json --avatar FILE.blend [--armature NAME] [--method M] -o OUT.blend`."""


def run(args) -> int:
    from ..blender.retarget_scene import retarget_files

    retarget_files(args.recording, args.user, args.avatar, args.output, armature=args.armature, method=args.method)
    return 0
