"""`bodycal demo [-o DIR]`."""

from pathlib import Path

from .. import console


def run(args) -> int:
    from ...blender.demo import run_demo

    run_demo(Path(args.output_dir), log=console.say)
    return 0
