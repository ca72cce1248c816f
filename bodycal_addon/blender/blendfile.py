"""Opening a user's .blend from the command line and finding the avatar's armature in it."""

from __future__ import annotations

from pathlib import Path

import bpy

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
