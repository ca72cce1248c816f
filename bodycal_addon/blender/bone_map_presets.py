"""Bone map presets in Blender (FORMATS.md §5): the built-in ones (one per naming scheme) and the
user's, kept as JSON files in the extension's user folder (`bpy.utils.extension_path_user`,
`bone_maps/`), or in Blender's user config folder (`bodycal/bone_maps/`) when BodyCal is imported
as a plain module. A preset is named by an identifier: "builtin:<scheme>" or "user:<file name>".
"""

from __future__ import annotations

from pathlib import Path

import bpy

from ..body import naming
from ..body.bone_presets import BonePreset, load_preset, preset_from_bone_map
from ..core import outputs, paths
from ..core.errors import BodyCalError
from ..core.outputs import safe_part
from . import avatar_rig

USER_FOLDER = "bone_maps"
BUILTIN = "builtin:"
USER = "user:"


def user_preset_dir(create: bool = True) -> Path:
    package = paths.extension_package()
    if package:
        return Path(bpy.utils.extension_path_user(package, path=USER_FOLDER, create=create))
    return Path(bpy.utils.user_resource("CONFIG", path=f"bodycal/{USER_FOLDER}", create=create))


def preset_entries() -> list[tuple[str, str, str]]:
    """(identifier, label, description) of every preset: the built-in ones, then the user's files
    in name order; a file that cannot be read is listed with the reason (applying it says it)."""
    out = [(f"{BUILTIN}{s.name}", s.title, f"Built-in: the {s.title} naming scheme") for s in naming.SCHEMES]
    for path in sorted(user_preset_dir().glob("*.json")):
        try:
            out.append((f"{USER}{path.name}", load_preset(path).name, f"Your preset ({path.name})"))
        except BodyCalError as exc:
            out.append((f"{USER}{path.name}", f"{path.stem} (unreadable)", exc.line()))
    return out


def builtin_entries(why: str) -> list[tuple[str, str, str]]:
    """The built-in presets alone, each described with `why` (the user folder could not be read)."""
    return [(f"{BUILTIN}{s.name}", s.title, f"Built-in ({why})") for s in naming.SCHEMES]


def check_fits(path, arm) -> None:
    """Refuse (BodyCalError) the preset file at `path` when it does not map `arm`'s bones."""
    load_preset(path).resolve([b.name for b in arm.data.bones])


def preset_for(identifier: str) -> BonePreset:
    if identifier.startswith(BUILTIN):
        scheme = naming.SCHEME_BY_NAME.get(identifier[len(BUILTIN):])
        if scheme is None:
            raise BodyCalError(f"no built-in bone map preset '{identifier}'")
        return BonePreset(scheme.title, scheme.name, source=f"built-in: {scheme.name}")
    if identifier.startswith(USER):
        name = identifier[len(USER):]
        if not name or Path(name).name != name:
            raise BodyCalError(f"not a preset file name: '{name}'")
        return load_preset(user_preset_dir() / name)
    raise BodyCalError(f"unknown bone map preset '{identifier}'", hint="pick one in the Avatar panel")


def export_bone_map(arm, path, name: str | None = None) -> tuple[Path, BonePreset]:
    """Write the armature's bone map (as the panel shows it) as a preset file that needs no
    naming scheme: applied to this armature again, it gives the same map."""
    bm = avatar_rig.bone_map_for(arm)
    if not bm.bones and not any(bm.chains.values()):
        raise BodyCalError("its bone map maps nothing yet", source=arm.name,
                           hint="assign bones or apply a preset first")
    preset = preset_from_bone_map(bm, name or arm.name)
    return preset.save(path), preset


def import_preset_file(path) -> tuple[str, BonePreset]:
    """Check a preset file and keep a copy among the user's presets (named after the preset; one
    of the same name is replaced). Returns its identifier and the preset."""
    preset = load_preset(path)
    dest = user_preset_dir() / f"{safe_part(preset.name)}.json"
    outputs.write_text(dest, preset.to_json(), overwrite=True)
    preset.source = str(dest)
    return f"{USER}{dest.name}", preset
