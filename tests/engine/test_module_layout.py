"""The recording readers' layout: the C3D reader and the shared leaves never import the
recording_io package (which imports them), so there is no import cycle and no import inside a
function to hide one."""

import ast
import pathlib

import pytest

ADDON = pathlib.Path(__file__).resolve().parents[2] / "bodycal_addon"
LEAVES = ("c3d.py", "coords.py", "segments.py", "gaps.py", "led_gloves.py", "errors.py")


def _imported_modules(path: pathlib.Path) -> list[str]:
    """Every module named by an import statement anywhere in the file (functions included)."""
    names = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names += [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = "." * node.level + (node.module or "")
            names += [base] + [f"{base}.{a.name}" if node.module else base + a.name for a in node.names]
    return names


@pytest.mark.parametrize("name", LEAVES)
def test_readers_leaves_do_not_import_recording_io(name):
    imported = _imported_modules(ADDON / name)
    assert imported, name
    assert not [m for m in imported if "recording_io" in m], name


def test_c3d_imports_only_the_leaves():
    local = {m for m in _imported_modules(ADDON / "c3d.py") if m.startswith(".") and m.count(".") == 1}
    assert {".coords", ".segments"} <= local
    assert not any("recording_io" in m for m in local)
