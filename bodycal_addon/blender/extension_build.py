"""Build the extension zip with Blender's own `extension build` tool (`make zip`)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import bpy

from ..core import paths


def blender_ext_tool() -> Path:
    """Blender's bundled `blender_ext.py` (the tool behind `blender --command extension build`)."""
    scripts = Path(bpy.utils.system_resource("SCRIPTS"))
    tool = scripts / "addons_core" / "bl_pkg" / "cli" / "blender_ext.py"
    if not tool.is_file():
        raise FileNotFoundError(f"Blender's extension tool not found at {tool}")
    return tool


def build_zip(output_dir: Path, source_dir: Path = paths.ROOT_DIR) -> Path:
    output_dir = Path(output_dir).resolve()
    output_dir.mkdir(parents=True, exist_ok=True)
    for old in output_dir.glob("bodycal-*.zip"):
        old.unlink()
    out = subprocess.run([sys.executable, str(blender_ext_tool()), "build", "--source-dir", str(source_dir),
                          "--output-dir", str(output_dir)], capture_output=True, text=True)
    if out.returncode != 0:
        raise RuntimeError(f"extension build failed: {(out.stdout + out.stderr).strip()}")
    (zip_path,) = output_dir.glob("bodycal-*.zip")
    return zip_path


if __name__ == "__main__":
    print(build_zip(Path(sys.argv[1] if len(sys.argv) > 1 else "dist")))
    from .process import exit_now

    exit_now(0)
