"""`bodycal retarget REC --user USER.body.json --avatar AVATAR [--armature NAME] [--bone-map FILE]
[--method M] [--placement object|performer] [--filter [MIN_CUTOFF,BETA[,ROT_MIN,ROT_BETA]] | --no-filter]
[--no-plant-feet] [--seated HEIGHT] [--root-motion root|pelvis|in-place] [--rigify-target fk|def]
[--tolerance DEG] [--location-tolerance MM] [--interpolation linear|bezier] [--fps N] [--frame-range FIRST LAST]
-o OUT.blend|.fbx|.glb|.gltf|.bvh [-o ...] [--overwrite] [--review]`; AVATAR is a .blend, .fbx, .glb, .gltf or .vrm."""

import math

from ...core.errors import BodyCalError
from ...recording.filters import OneEuro
from .. import console


def run(args) -> int:
    from ...blender import session

    cfg = None if getattr(args, "filter", None) is None else OneEuro.parse(args.filter)
    with console.progress("retarget") as step:
        session.retarget_files(args.recording, args.user, args.avatar, args.output, filter=cfg,
                               seat_height=seat_height(args), hands=getattr(args, "hands", "geometry"),
                               armature=args.armature,
                               settings=session.Settings(args.method, getattr(args, "plant_feet", True),
                                                         getattr(args, "placement", "object")),
                               overwrite=getattr(args, "overwrite", False), options=bake_options(args),
                               frame_range=frame_range(args), review=getattr(args, "review", False),
                               bone_map_path=getattr(args, "bone_map", None),
                               log=console.say, warn=lambda line: console.warn("retarget", line), progress=step)
    return 0


def seat_height(args) -> float | None:
    """--seated HEIGHT (metres), checked: a seat between 0.1 and 1.2 m high."""
    h = getattr(args, "seated", None)
    if h is not None and not (math.isfinite(h) and 0.1 <= h <= 1.2):
        raise BodyCalError(f"--seated {h:g} is not a seat's height", field="--seated",
                           hint="give the seat's height in metres, between 0.1 and 1.2 (a chair: about 0.45)")
    return h


def bake_options(args):
    """The bake options every baking command takes (--tolerance, --location-tolerance, --fps,
    --root-motion, --rigify-target, --interpolation); --fps 0 is the take's own rate, as no --fps."""
    from ...blender.bake import BakeOptions

    fps = None if args.fps == 0 else args.fps
    return BakeOptions(args.tolerance, args.location_tolerance, fps, getattr(args, "root_motion", "root"),
                       getattr(args, "rigify_target", "fk"), getattr(args, "interpolation", "linear"))


def frame_range(args) -> tuple[float, float] | None:
    """--frame-range FIRST LAST, checked: finite, FIRST <= LAST."""
    given = getattr(args, "frame_range", None)
    if given is None:
        return None
    first, last = given
    if not (math.isfinite(first) and math.isfinite(last) and first <= last):
        raise BodyCalError(f"--frame-range {first:g} {last:g} is not a range", field="--frame-range",
                           hint="give FIRST LAST with FIRST <= LAST")
    return first, last
