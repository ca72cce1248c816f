"""Where things are: the extension root, the shared sample data, the sample rigs package."""

from __future__ import annotations

import importlib
import os
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent
ROOT_DIR = PACKAGE_DIR.parent  # the repository / extension root


def data_dir() -> Path | None:
    """The shared sample data (avatars, mocap, C3D files): $BODYCAL_DATA, else `../shared/data`
    beside the repository. None when neither exists (an installed extension has no samples)."""
    env = os.environ.get("BODYCAL_DATA")
    candidates = [Path(env)] if env else []
    candidates.append(ROOT_DIR.parent / "shared" / "data")
    return next((c for c in candidates if (c / "avatars").is_dir()), None)


def shared_avatar_files() -> list[Path]:
    d = data_dir()
    if d is None:
        return []
    return sorted((d / "avatars" / "mpfb2_variants").glob("*.glb"))


def sample_rigs():
    """The root `sample_rigs` package, whichever way BodyCal was loaded: as the extension
    (`bl_ext.<repo>.bodycal.sample_rigs`) or from the repository root (`sample_rigs`)."""
    parent = __package__.rpartition(".")[0]
    return importlib.import_module(f"{parent}.sample_rigs" if parent else "sample_rigs")
