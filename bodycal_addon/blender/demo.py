"""`bodycal demo`: the pipeline on the bundled sample recording and the sample rigs.

Stages that have not landed yet are listed, not faked.
"""

from __future__ import annotations

from pathlib import Path

import bpy

from .. import paths

PLANNED_STAGES = (
    "import the bundled synthetic recording (full profile)",
    "calibrate the performer's body from the recording's calibration steps",
    "calibrate each avatar's surface by raycasting",
    "retarget with the egocentric, offsets and rotations methods and bake actions",
    "print contact gap and floor error per avatar and method",
)


def run_demo(output_dir: Path, log=print) -> Path:
    output_dir.mkdir(parents=True, exist_ok=True)
    bpy.ops.wm.read_homefile(use_empty=True)
    rigs = paths.sample_rigs()
    arm, _mesh, spec = rigs.build_procedural_avatar()
    log(f"avatar {arm.name}: procedural, {spec.truth['height']:.3f} m, {len(arm.data.bones)} bones")
    files = paths.shared_avatar_files()
    if not files:
        log("no shared sample avatars found (set BODYCAL_DATA): using the procedural avatar only")
    for i, path in enumerate(files, start=1):
        arm, mesh = rigs.load_glb_avatar(path)
        arm.location.x = 0.8 * i
        log(f"avatar {arm.name}: {path.name}, {len(arm.data.bones)} bones, {len(mesh.data.vertices)} vertices")
    for stage in PLANNED_STAGES:
        log(f"not yet: {stage}")
    out = output_dir / "demo.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(out.resolve()))
    log(f"saved {out}")
    return out
