"""Shared by both test lanes (tests/engine: plain pytest, no bpy; tests/blender: inside Blender):
the repository and the test helpers on sys.path, and the sample data."""

from __future__ import annotations

import pathlib
import sys

TESTS = pathlib.Path(__file__).resolve().parent
for p in (TESTS.parent, TESTS):  # the repository (bodycal_addon, bodycal_dev, sample_rigs) and the helpers
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))

import pytest  # noqa: E402


@pytest.fixture(scope="session")
def data_dir() -> pathlib.Path:
    from bodycal_addon.core import paths

    d = paths.data_dir()
    assert d is not None, "sample data not found: sample_data/ is missing (or BODYCAL_DATA points elsewhere)"
    return d


@pytest.fixture(scope="session")
def avatar_files(data_dir) -> list[pathlib.Path]:
    files = sorted((data_dir / "avatars" / "mpfb2_variants").glob("*.glb"))
    assert len(files) == 5
    return files
