"""Where things are: the extension root, the sample data, the sample rigs package."""

from __future__ import annotations

import importlib
import os
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parents[1]  # bodycal_addon/ (this file is in core/)
ROOT_DIR = PACKAGE_DIR.parent  # the repository / extension root
# The avatar files the command line and batch jobs read (blender.blendfile.open_avatar): a .blend,
# or what Blender's importers read (.vrm: a VRM importer add-on the user installs).
# The package holding `bodycal_addon` ("bl_ext.<repository>.bodycal" as an installed extension, ""
# when imported from the repository): this module is `<that>.bodycal_addon.core.paths`.
EXTENSION_ROOT = __package__.removesuffix("bodycal_addon.core").rstrip(".")
AVATAR_SUFFIXES = (".blend", ".fbx", ".glb", ".gltf", ".vrm")
# The files a character's animation is read from (`bodycal transfer`, batch `[[animations]]`):
# a .blend, or what Blender's importers read.
ANIMATION_SUFFIXES = (".blend", ".bvh", ".fbx", ".glb", ".gltf")


def data_dir() -> Path | None:
    """The sample data (avatars, mocap, C3D files; sources and licences in its README):
    $BODYCAL_DATA when set, else the repository's `sample_data/`. None when neither exists (the
    extension zip does not carry the samples)."""
    env = os.environ.get("BODYCAL_DATA")
    candidates = [Path(env)] if env else []
    candidates.append(ROOT_DIR / "sample_data")
    return next((c for c in candidates if (c / "avatars").is_dir()), None)


def shared_avatar_files() -> list[Path]:
    d = data_dir()
    if d is None:
        return []
    return sorted((d / "avatars" / "mpfb2_variants").glob("*.glb"))


def outside_avatar_files() -> list[Path]:
    """Characters no one on the project made (sample_data/avatars/outside/README.md)."""
    d = data_dir()
    if d is None:
        return []
    return sorted((d / "avatars" / "outside").glob("*.glb"))


def extension_package() -> str | None:
    """The extension's package ("bl_ext.<repository>.bodycal", what Blender's
    `bpy.utils.extension_path_user` wants) when BodyCal runs as an installed extension; None when
    it is imported from the repository as `bodycal_addon` (the command line, the tests' engine)."""
    return EXTENSION_ROOT if EXTENSION_ROOT.startswith("bl_ext.") else None


def sample_rigs():
    """The root `sample_rigs` package, whichever way BodyCal was loaded: as the extension
    (`bl_ext.<repo>.bodycal.sample_rigs`) or from the repository root (`sample_rigs`)."""
    return importlib.import_module(f"{EXTENSION_ROOT}.sample_rigs" if EXTENSION_ROOT else "sample_rigs")
