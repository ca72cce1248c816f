"""Opening a user's .blend from the command line, finding the avatar's armature in it, and
saving the result without risking any file the user has."""

from __future__ import annotations

from pathlib import Path

import bpy

from .. import outputs
from ..errors import BodyCalError


def open_blend(path) -> None:
    path = Path(path)
    if not path.is_file():
        raise BodyCalError("no such file", source=str(path))
    try:
        # A user's file may hold scripts (drivers, registered text blocks): none of them runs here.
        bpy.ops.wm.open_mainfile(filepath=str(path.resolve()), load_ui=False, use_scripts=False)
    except RuntimeError as exc:
        raise BodyCalError(f"Blender cannot open it ({str(exc).strip().splitlines()[-1][:120]})",
                           source=str(path)) from None


def find_armature(name: str | None, source: str):
    """The armature object named `name`, else the only armature in the file."""
    armatures = [o for o in bpy.data.objects if o.type == "ARMATURE"]
    if name:
        arm = bpy.data.objects.get(name)
        if arm is None or arm.type != "ARMATURE":
            have = ", ".join(sorted(o.name for o in armatures)) or "none"
            raise BodyCalError(f"no armature named '{name}' (armatures in the file: {have})", source=source,
                               field="--armature")
        return arm
    if not armatures:
        raise BodyCalError("the file has no armature", source=source)
    if len(armatures) > 1:
        raise BodyCalError(f"several armatures ({', '.join(sorted(o.name for o in armatures))}): pick one",
                           source=source, hint="use --armature NAME")
    return armatures[0]


def save_blend(path, *, overwrite: bool = True, inputs=(), field: str = "-o") -> Path:
    """Save the open file as `path` through `outputs.replacing`: Blender writes a temporary file
    beside it, renamed over `path` only once complete; a symlink, a device or one of `inputs` is
    refused. The session keeps its own file path (`copy=True`), so nothing points at the temp."""
    with outputs.replacing(path, inputs=inputs, overwrite=overwrite, field=field) as tmp:
        tmp.unlink()  # else Blender keeps the empty placeholder as a `.blend1` backup
        try:
            bpy.ops.wm.save_as_mainfile(filepath=str(tmp), copy=True, compress=True)
        except RuntimeError as exc:
            raise BodyCalError(f"Blender cannot save it ({str(exc).strip().splitlines()[-1][:120]})",
                               source=str(path), field=field, hint="check the disk space and the folder") from None
    return Path(path)
