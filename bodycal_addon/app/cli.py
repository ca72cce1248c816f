"""The command line of FORMATS.md §4.

One entry point, two ways in: `python -m bodycal_addon <command>` (Blender as a Python module,
from the repository root) and `blender -b -c bodycal <command>` (registered by the extension
with `bpy.utils.register_cli_command`). Exit 0 on success, 2 on bad input with one clear line on
stderr and no traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import tomllib
from collections.abc import Callable

from ..core import paths
from ..core.errors import BodyCalError
from ..core.outputs import describe_os_error
from ..output.keyreduce import DEFAULT_LOCATION_TOLERANCE_MM, DEFAULT_TOLERANCE_DEG, INTERPOLATIONS
from ..output.rigify import RIGIFY_TARGETS
from ..output.root_motion import ROOT_MOTIONS
from ..retarget.methods import methods_for
from ..retarget.placement import PLACEMENTS
from . import console

METHODS = methods_for("recording")  # every method, the default first (retarget/methods.py)
TRANSFER_METHODS = methods_for("animation")

VMC_PORT = 39539  # a VMC Marionette's port (recording/live/vmc.py, which the command loads when it runs)
IDLE_S = 5.0  # `record`: a stream silent this long after its first frame has stopped (FORMATS.md §6.2)
EXIT_OK = 0
EXIT_USAGE = 2
_BONE_MAP_HELP = ("bone map preset (JSON, docs/FORMATS.md §5) for an armature whose bone names no naming scheme "
                  "knows; it replaces the map stored on the armature for this run")
AVATAR_HELP = ("the avatar: a .blend, or an .fbx, .glb, .gltf or .vrm read by Blender's importer "
               "(.vrm needs a VRM importer add-on enabled)")


REC_HELP = ("the recording: .bcrec.json, .csv (+ sidecar .json), .c3d, an A-Frame motion capture .json or a Beat Saber "
            ".bsor replay (docs/FORMATS.md §2)")
HANDS = ("geometry", "labels", "swapped")  # recording/io/hands.py (loaded when a command runs)
USER_HELP = "the performer's body model, written by calibrate-user"
VERBOSE_HELP = "let Blender's own output (importers, file reports) through to stdout (default: BodyCal's lines only)"


class UsageError(BodyCalError):
    """A command line argparse refuses; `prog` is the parser's (`bodycal` or `bodycal <command>`)."""

    def __init__(self, message: str, prog: str):
        super().__init__(message)
        self.prog = prog


class _Parser(argparse.ArgumentParser):
    """argparse that raises instead of exiting, so `blender -c` is not killed by SystemExit."""

    def error(self, message):
        raise UsageError(message, self.prog)


def version() -> str:
    """The extension's version, from its manifest (the one file that holds it)."""
    try:
        return tomllib.loads((paths.ROOT_DIR / "blender_manifest.toml").read_text(encoding="utf-8"))["version"]
    except (OSError, ValueError, KeyError):
        return "unknown"


def _method_help(methods) -> str:
    """What each of `methods` does (retarget/methods.py's names)."""
    what = {"egocentric": "keeps self-contacts (Delahaye 2023)", "offsets": "AvatarGo's exact tracker offsets",
            "rotations": "rotation copy, the usual baseline"}
    return "; ".join(f"{m}: {what.get(m, m)}" for m in methods) + f" (default: {methods[0]})"


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog="bodycal", description="BodyCal: VR tracker recordings to animation on any humanoid "
                "avatar, keeping self-contacts.")
    p.add_argument("--version", action="version", version=f"bodycal {version()}")
    p.add_argument("-v", "--verbose", action="store_true", help=VERBOSE_HELP)
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)

    c = sub.add_parser("calibrate-user", help="run every calibration step the recording allows")
    c.add_argument("recording", metavar="REC", help=REC_HELP)
    _hands_argument(c)
    c.add_argument("-o", "--output", required=True, metavar="USER.body.json", help="the body model to write")
    c.add_argument("--allow-defaults", action="store_true",
                   help="accepted for older scripts; changes nothing (a body mostly guessed from the eye height is "
                        "written, with a warning)")
    c.add_argument("--overwrite", action="store_true", help="replace the output file if it exists")

    c = sub.add_parser("calibrate-avatar", help="surface calibration by raycasting onto the avatar's mesh")
    c.add_argument("avatar", metavar="AVATAR", help=AVATAR_HELP)
    c.add_argument("--armature", metavar="NAME", help="armature object (default: the only one in the file)")
    c.add_argument("--bone-map", metavar="FILE", help=_BONE_MAP_HELP)
    c.add_argument("-o", "--output", required=True, metavar="AVATAR.body.json", help="the body model to write")
    c.add_argument("--overwrite", action="store_true", help="replace the output file if it exists")

    c = sub.add_parser("retarget", help="animate the avatar and bake a new action onto its armature")
    c.add_argument("recording", metavar="REC", help=REC_HELP)
    _hands_argument(c)
    c.add_argument("--user", required=True, metavar="USER.body.json", help=USER_HELP)
    c.add_argument("--avatar", required=True, metavar="AVATAR", help=AVATAR_HELP)
    c.add_argument("--armature", metavar="NAME", help="the avatar's armature (default: the only one in the file)")
    c.add_argument("--bone-map", metavar="FILE", help=_BONE_MAP_HELP)
    c.add_argument("--method", choices=METHODS, default="egocentric", help=_method_help(METHODS))
    _filter_argument(c, "the devices before retargeting", on=True)
    _seated_argument(c)
    _bake_arguments(c, "the recording's")

    c = sub.add_parser("batch", help="many recordings x avatars, in parallel worker processes or on a farm")
    c.add_argument("jobs", metavar="JOBS.toml", help="the jobs file: recordings, animations, avatars, methods and "
                   "defaults (docs/FORMATS.md §4.1)")
    where = c.add_mutually_exclusive_group()
    where.add_argument("--cluster", metavar="ADDRESS",
                       help="run the jobs on a Dask cluster: tcp://HOST:PORT (a running scheduler) or local:N "
                            "(N worker processes here); needs dask and distributed (docs/FARM.md)")
    where.add_argument("--export-openjd", metavar="DIR",
                       help="write an Open Job Description job template, one task per job, into DIR; run nothing")
    where.add_argument("--export-flamenco", metavar="FILE.json",
                       help="write a Flamenco job (type bodycal-batch, farm/flamenco/bodycal_batch.js) for the "
                            "Manager's API; run nothing")
    c.add_argument("--retries", type=int, default=0, metavar="N",
                   help="with --cluster: submit a job again, up to N times, when the worker running it died")
    c.add_argument("--review", action="store_true",
                   help="every job reviews its bake (retarget --review) and OUTPUT_DIR/review.html lists them, worst "
                        "first; exported farm jobs get a last step that writes the page (docs/FORMATS.md §4.5)")

    _review_command(sub)
    _live_commands(sub)

    c = sub.add_parser("demo", help="the whole pipeline on the bundled sample recording and sample rigs")
    c.add_argument("-o", "--output-dir", default="out", metavar="DIR",
                   help="where demo.blend is written (default: out)")

    c = sub.add_parser("transfer", help="another character's animation onto the avatar, keeping self-contacts")
    c.add_argument("source", metavar="SOURCE", help="the animated character: a .blend, .bvh, .fbx, .glb or .gltf")
    c.add_argument("--avatar", required=True, metavar="AVATAR", help=AVATAR_HELP)
    c.add_argument("--source-armature", metavar="NAME", help="the source's armature (default: the only one)")
    c.add_argument("--action", metavar="NAME", help="the source's action (default: its active one)")
    c.add_argument("--armature", metavar="NAME", help="the avatar's armature (default: the only one)")
    c.add_argument("--bone-map", metavar="FILE", help=_BONE_MAP_HELP + " (the avatar's)")
    c.add_argument("--method", choices=TRANSFER_METHODS, default=TRANSFER_METHODS[0],
                   help=_method_help(TRANSFER_METHODS))
    _filter_argument(c, "the source's pose (each bone's rotation, and its location in metres) before transferring")
    _bake_arguments(c, "the source's")
    for c in sub.choices.values():  # also after the command: `bodycal retarget ... --verbose`
        c.add_argument("-v", "--verbose", action="store_true", default=argparse.SUPPRESS, help=VERBOSE_HELP)
    return p


def _hands_argument(c) -> None:
    """--hands: which controller of an A-Frame capture or a Beat Saber replay is the right hand
    (FORMATS.md §2.6, §2.7); the other formats name their roles."""
    c.add_argument("--hands", choices=HANDS, default=HANDS[0],
                   help="A-Frame .json and Beat Saber .bsor recordings: geometry: the controller on the headset's "
                        "right most of the time is the right hand (default; the file's labels when that does not "
                        "decide); labels: as the file labels them; swapped: the labels swapped")


def _review_command(sub) -> None:
    c = sub.add_parser("review", help="the review sheet of a baked avatar file, or a batch's review page")
    c.add_argument("output", metavar="OUTPUT|DIR",
                   help="a baked avatar (.blend, .fbx, .glb, .gltf: what retarget, transfer or batch wrote): its "
                        "sheet OUTPUT.review.png and record OUTPUT.review.json; or a batch's output folder: "
                        "DIR/review.html from its jobs' reviews (docs/FORMATS.md §4.5)")
    c.add_argument("--armature", metavar="NAME", help="the baked armature (default: the only one in the file)")
    c.add_argument("--source", metavar="SOURCE",
                   help="what the output was made from, to compare with: a recording (.bcrec.json, .csv, .c3d; "
                        "with --user) or an animated character (.blend, .bvh, .fbx, .glb, .gltf)")
    c.add_argument("--user", metavar="USER.body.json", help="the performer's body model, for a recording --source")
    c.add_argument("--source-armature", metavar="NAME", help="a character --source's armature (default: the only one)")
    c.add_argument("--action", metavar="NAME", help="a character --source's action (default: its active one)")
    c.add_argument("--no-filter", action="store_true",
                   help="a recording --source as recorded (default: smoothed as retarget smooths it)")
    c.add_argument("--placement", choices=PLACEMENTS, default=PLACEMENTS[0],
                   help="where the bake played the performance (as retarget --placement): where the sheet draws "
                        "the source beside the avatar")
    c.add_argument("-o", "--sheet", metavar="SHEET.png",
                   help="where the sheet goes (default: beside OUTPUT); its record beside it")
    c.add_argument("--overwrite", action="store_true", help="replace the sheet and record if they exist")


def _live_commands(sub) -> None:
    """`record`, `stream` and `live`: the VMC protocol (FORMATS.md §6)."""
    c = sub.add_parser("record", help="record a live VMC stream (OSC over UDP) into a recording file")
    c.add_argument("-o", "--output", required=True, metavar="TAKE.bcrec.json|.csv", help="the recording to write "
                   "(docs/FORMATS.md §2; .csv also writes its sidecar .json)")
    c.add_argument("--port", type=int, default=VMC_PORT, metavar="N",
                   help=f"UDP port to listen on (default {VMC_PORT}, a VMC Marionette's)")
    c.add_argument("--bind", default="127.0.0.1", metavar="ADDRESS",
                   help="address to listen on: 127.0.0.1 hears this machine only (default), 0.0.0.0 every network")
    c.add_argument("--duration", type=float, default=None, metavar="S",
                   help="stop S seconds (wall clock) after the first frame arrived (default: when Ctrl-C is pressed)")
    c.add_argument("--idle", type=float, default=IDLE_S, metavar="S",
                   help=f"end the take when no frame has come for S seconds after the first: the sender stopped "
                        f"(default {IDLE_S:g}; 0 waits for Ctrl-C)")
    c.add_argument("--role", action="append", metavar="NAME=ROLE",
                   help="a device's role (its serial = head, hand_l, pelvis, ...); devices without one get theirs "
                        "from the T-pose when the file is read")
    c.add_argument("--name", metavar="NAME", help="the recording's name (default: the file's)")
    c.add_argument("--wizard", action="store_true",
                   help="run the calibration steps with the performer: each step's instruction, its progress, "
                        "ended by itself once enough data is in; the take ends after the last step")
    c.add_argument("--pause", type=float, default=3.0, metavar="S",
                   help="--wizard: seconds between a step's instruction and its start (default 3)")
    c.add_argument("--step-timeout", type=float, default=None, metavar="S",
                   help="--wizard: skip a step not done after S seconds (default: wait, Ctrl-C ends the take)")
    c.add_argument("--overwrite", action="store_true", help="replace the output file if it exists")

    c = sub.add_parser("stream", help="send a recording, or the avatar retargeted from it, as a VMC stream in real "
                       "time")
    c.add_argument("take", metavar="TAKE", help=REC_HELP)
    _hands_argument(c)
    c.add_argument("--host", default="127.0.0.1", metavar="H", help="where to send (default 127.0.0.1)")
    c.add_argument("--port", type=int, default=VMC_PORT, metavar="N", help=f"UDP port (default {VMC_PORT})")
    c.add_argument("--speed", type=float, default=1.0, metavar="X", help="X times real time (default 1)")
    c.add_argument("--loop", action="store_true", help="start over at the end, until Ctrl-C")
    c.add_argument("--local-only", action="store_true",
                   help="send each device's /VMC/Ext/*/Pos/Local message only (default: the plain one too)")
    c.add_argument("--retarget", action="store_true",
                   help="send the avatar retargeted from TAKE as VMC bones (needs --user and --avatar)")
    c.add_argument("--user", metavar="USER.body.json", help=USER_HELP)
    c.add_argument("--avatar", metavar="AVATAR", help="the avatar: its *.body.json from calibrate-avatar, or "
                   + AVATAR_HELP[len("the avatar: "):])
    c.add_argument("--armature", metavar="NAME", help="the avatar file's armature (default: the only one)")
    c.add_argument("--bone-map", metavar="FILE", help=_BONE_MAP_HELP)
    c.add_argument("--method", choices=METHODS, default="egocentric", help=_method_help(METHODS))
    _filter_argument(c, "the devices before retargeting", on=True)
    c.add_argument("--no-plant-feet", dest="plant_feet", action="store_false",
                   help="let the feet follow the method (default: planted while the performer stands on them)")

    c = sub.add_parser("live", help="retarget a live VMC stream frame by frame and send the avatar on as VMC bones")
    c.add_argument("--user", required=True, metavar="USER.body.json", help=USER_HELP)
    c.add_argument("--avatar", required=True, metavar="AVATAR.body.json",
                   help="the avatar's body model (calibrate-avatar's output: its surface and rig)")
    c.add_argument("--send", required=True, metavar="HOST:PORT", help="where the avatar's VMC bones go")
    c.add_argument("--method", choices=METHODS, default="egocentric", help=_method_help(METHODS))
    c.add_argument("--port", type=int, default=VMC_PORT, metavar="N",
                   help=f"UDP port to listen on for the performer's devices (default {VMC_PORT})")
    c.add_argument("--bind", default="127.0.0.1", metavar="ADDRESS",
                   help="address to listen on: 127.0.0.1 hears this machine only (default), 0.0.0.0 every network")
    c.add_argument("--role", action="append", metavar="NAME=ROLE",
                   help="a device's role (its serial = head, hand_l, pelvis, ...) when the stream does not say it")
    c.add_argument("--duration", type=float, default=None, metavar="S", help="stop after S seconds (default: Ctrl-C)")
    c.add_argument("--worker", action="store_true",
                   help="solve in a worker process of its own (the receiver's thread then never waits for the solve)")
    _filter_argument(c, "the devices (forward only, as they arrive)", on=True)
    c.add_argument("--no-plant-feet", dest="plant_feet", action="store_false",
                   help="let the feet follow the method (default: planted while the performer stands on them)")
    _seated_argument(c)


def _seated_argument(c) -> None:
    c.add_argument("--seated", type=float, default=None, metavar="HEIGHT",
                   help="the performer sits on a seat HEIGHT metres high (a kit without foot trackers: the estimated "
                        "pelvis stays on the seat, the feet planted in front; default: standing and stepping)")


def _filter_argument(c, what: str, on: bool = False) -> None:
    """--filter [PARAMETERS], and --no-filter where smoothing is the default (DESIGN.md §6b)."""
    group = c.add_mutually_exclusive_group()
    group.add_argument("--filter", nargs="?", const="on", default="on" if on else None,
                       metavar="MIN_CUTOFF,BETA[,ROT_MIN,ROT_BETA]",
                       help=f"the One Euro filter on {what}{', on by default' if on else ''} (default parameters "
                            "3,5,4,1: Hz, Hz per m/s, Hz, Hz per rad/s)")
    if on:
        group.add_argument("--no-filter", dest="filter", action="store_const", const=None,
                           help=f"do not smooth {what}")


def _bake_arguments(c, rate_of: str) -> None:
    """Placement, feet, root motion, Rigify target, key reduction, output rate and outputs: what
    `retarget` and `transfer` both take."""
    c.add_argument("--placement", choices=PLACEMENTS, default=PLACEMENTS[0],
                   help="object: the motion plays relative to the armature object's place and heading "
                        "(default); performer: where the performer was in the room")
    c.add_argument("--no-plant-feet", dest="plant_feet", action="store_false",
                   help="let the feet follow the method (default: feet planted while the performer stands on them)")
    c.add_argument("--root-motion", choices=ROOT_MOTIONS, default=ROOT_MOTIONS[0],
                   help="root: the travel and heading on the rig's root bone when it has one above the pelvis "
                        "(default; else on the pelvis); pelvis: on the pelvis, the root at rest; in-place: no "
                        "horizontal travel")
    c.add_argument("--rigify-target", choices=RIGIFY_TARGETS, default=RIGIFY_TARGETS[0],
                   help="a generated Rigify rig: fk keys its FK controls, IK switched to FK (default, to edit); "
                        "def keys the DEF- bones (for export)")
    c.add_argument("--tolerance", type=float, default=DEFAULT_TOLERANCE_DEG, metavar="DEG",
                   help="key reduction: each bone's rotation stays within DEG degrees of every sample "
                        f"(default {DEFAULT_TOLERANCE_DEG:g}; 0 keys every sample)")
    c.add_argument("--location-tolerance", type=float, default=DEFAULT_LOCATION_TOLERANCE_MM, metavar="MM",
                   help="key reduction of the root's location, in millimetres "
                        f"(default {DEFAULT_LOCATION_TOLERANCE_MM:g})")
    c.add_argument("--interpolation", choices=INTERPOLATIONS, default=INTERPOLATIONS[0],
                   help="the baked keys: linear (default), or bezier (Auto Clamped handles; keys are added where "
                        "the curve would stray beyond the tolerances)")
    c.add_argument("--fps", type=float, default=None, metavar="N",
                   help="output frame rate: the action is resampled to N frames per second, timing kept "
                        f"(default, or 0: one key per sample, the scene set to {rate_of} rate)")
    c.add_argument("--frame-range", type=float, nargs=2, default=None, metavar=("FIRST", "LAST"),
                   help=f"bake only {rate_of} frames FIRST..LAST (a recording's first "
                        "sample is frame 1, a source action keeps its own frames; default: all of them)")
    c.add_argument("-o", "--output", required=True, action="append", metavar="OUT.blend|.fbx|.glb|.gltf|.bvh",
                   help="a .blend (the avatar's file with the new action), or an export of the avatar "
                        "and its baked action for game engines; give -o several times for several files")
    c.add_argument("--overwrite", action="store_true", help="replace the output file if it exists")
    c.add_argument("--review", action="store_true",
                   help="also review the bake: OUT.review.png (the frames that matter and the figures over the take, "
                        "flagged against their limits) and OUT.review.json beside the first -o (docs/FORMATS.md §4.5)")


def _handler(command: str) -> Callable[[argparse.Namespace], int]:
    """Each command lives in its own module under `commands/`, imported only when run, so that
    `--help` and argument errors never load Blender."""
    module_name = "commands." + command.replace("-", "_")
    return importlib.import_module(f".{module_name}", __package__).run


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exc:  # --help, --version
        return int(exc.code or 0)
    except UsageError as exc:
        console.error(exc.prog, exc.line())
        return EXIT_USAGE
    if not args.command:
        parser.print_help()
        return EXIT_USAGE
    with console.own_lines_only(verbose=args.verbose):
        return _run(args)


def _run(args) -> int:
    prog = f"bodycal {args.command}"
    try:
        return int(_handler(args.command)(args) or 0)
    except BodyCalError as exc:
        console.error(prog, exc.line())
        return EXIT_USAGE
    except OSError as exc:  # a file the checks could not foresee (vanished, disk full, permissions changed)
        console.error(prog, describe_os_error(exc))
        return EXIT_USAGE
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=console.stderr(), flush=True)
        return 130

