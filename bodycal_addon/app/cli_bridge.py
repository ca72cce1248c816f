"""`blender -b -c bodycal ...`: the extension registers `run` with `bpy.utils.register_cli_command`."""

from __future__ import annotations

import sys

from .cli import main


def run(argv: list[str]) -> int:
    code = main(list(argv))
    sys.stdout.flush()
    sys.stderr.flush()
    return code
