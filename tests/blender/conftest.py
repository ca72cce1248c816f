"""The Blender lane: tests run inside Blender (the `bpy` module, background mode), per
docs/BLENDER_NOTES.md: an isolated user folder, the extension enabled through Blender's own
extension machinery, the scene reset before every test, and an exit that cannot hang."""

from __future__ import annotations

import os
import pathlib
import tempfile

from repo_paths import REPO

# Before `import bpy`: Blender reads its user folder once, at import.
os.environ["BLENDER_USER_RESOURCES"] = tempfile.mkdtemp(prefix="bodycal-test-user-")

import bpy  # noqa: E402, I001  (first: addon_utils and mathutils import only after it)
import addon_utils  # noqa: E402
import pytest  # noqa: E402

from bodycal_addon.blender.process import exit_now  # noqa: E402

EXTENSION_MODULE = "bl_ext.user_default.bodycal"
_exit_status = 0


def _raise(exc):
    raise exc


def enable_extension():
    """Symlink the repository into the user extension repository and enable it like a user would;
    a register() that raises fails the run instead of passing silently."""
    ext_dir = pathlib.Path(bpy.utils.user_resource("EXTENSIONS", path="user_default", create=True))
    link = ext_dir / "bodycal"
    if not link.exists():
        link.symlink_to(REPO, target_is_directory=True)
    addon_utils.modules_refresh()
    addon_utils.enable(EXTENSION_MODULE, default_set=True, handle_error=_raise)


def disable_extension():
    addon_utils.disable(EXTENSION_MODULE, default_set=True, handle_error=_raise)


def pytest_configure(config):
    enable_extension()


def pytest_sessionfinish(session, exitstatus):
    global _exit_status
    _exit_status = int(exitstatus)


def pytest_unconfigure(config):
    # Blender 4.5 can hang at exit while Python classes are registered (BLENDER_NOTES.md):
    # unregister what we registered, then leave without Blender's atexit handlers.
    try:
        disable_extension()
    finally:
        if bpy.app.version < (5, 0, 0):
            exit_now(_exit_status)


@pytest.fixture(autouse=True)
def empty_scene():
    """Every test starts from an empty file (keeps enabled extensions)."""
    bpy.ops.wm.read_homefile(use_empty=True)
    yield


@pytest.fixture(scope="session")
def rigify_blend(tmp_path_factory):
    """A generated Rigify rig on a skinned body, saved (sample_rigs/rigify_rig.py; built in a
    subprocess: Rigify hangs 4.5 at exit)."""
    import subprocess
    import sys

    path = tmp_path_factory.mktemp("rigify") / "rigify_avatar.blend"
    out = subprocess.run([sys.executable, "-m", "sample_rigs.rigify_rig", str(path)], cwd=REPO, capture_output=True,
                         text=True, timeout=600)
    assert out.returncode == 0 and path.is_file(), out.stderr[-2000:]
    return path
