"""`bodycal review OUTPUT [--armature NAME] [--source SOURCE [--user USER.body.json | --source-armature NAME
--action NAME] [--no-filter]] [--placement object|performer] [-o SHEET.png] [--overwrite]`: the review of a
baked avatar file (its sheet and record, FORMATS.md §4.5); `bodycal review DIR`: a batch's review page,
DIR/review.html, from its summary and its jobs' records."""

from pathlib import Path

from ...body.bodymodel import BodyModel
from ...core import paths
from ...core.errors import BodyCalError
from ...core.outputs import recording_inputs
from ...output.review_page import write_page
from ...recording.filters import DEFAULT_FILTER
from ...recording.io import load_recording
from ...retarget.takes import RecordingTake
from .. import console


def run(args) -> int:
    target = Path(args.output)
    if target.is_dir():
        if args.source or args.sheet:
            raise BodyCalError("is a folder: its review page is made from its jobs' records; --source and -o "
                               "review one output file", source=str(target))
        console.say(f"saved {write_page(target)}")
        return 0
    from ...blender import review

    if not target.is_file():
        raise BodyCalError("no such file or folder", source=str(target))
    take, inputs = None, []
    if args.source:
        take, inputs = _read_source(Path(args.source), args)
    elif args.user:
        raise BodyCalError("--user goes with --source (the recording it calibrates)", source="--user")
    if target.suffix.lower() not in paths.AVATAR_SUFFIXES or target.suffix.lower() == ".vrm":
        raise BodyCalError("not a baked avatar file (a .blend, .fbx, .glb or .gltf) or a batch's output folder",
                           source=str(target))
    with console.progress("review") as step:
        step("reviewing", 0.0)
        review.review_output(target, armature=args.armature, take=take, placement=args.placement,
                             sheet=Path(args.sheet) if args.sheet else None, overwrite=args.overwrite,
                             inputs=inputs, log=console.say)
    return 0


def _read_source(source: Path, args):
    """The take the output was made from: a recording of the performer (with --user), or an
    animated character's action; read before the output is opened (a character's file replaces
    the open one)."""
    from ...blender import session

    name = source.name.lower()
    if name.endswith((".bcrec.json", ".csv", ".c3d")):
        if not args.user:
            raise BodyCalError("a recording needs the performer's body model: give --user USER.body.json",
                               source=str(source))
        user = BodyModel.load(args.user)
        if user.kind != "user":
            raise BodyCalError(f"expected a user body model, got kind '{user.kind}'", source=str(args.user))
        take = RecordingTake(load_recording(source), user, None if args.no_filter else DEFAULT_FILTER)
        return take, [*recording_inputs(source), ("the user file (--user)", Path(args.user))]
    take = session.read_character_take(source, args.source_armature, args.action)
    return take, [("the source (--source)", source)]
