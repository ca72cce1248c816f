"""`bodycal demo [-o DIR]`."""

from pathlib import Path


def run(args) -> int:
    from ...blender.demo import run_demo

    run_demo(Path(args.output_dir))
    return 0
