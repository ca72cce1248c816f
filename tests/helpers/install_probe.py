"""Run in a fresh Python process: install the extension zip like a user, report what got
registered, disable it, report what is left. Prints one JSON line."""

import importlib
import importlib.machinery
import json
import os
import shutil
import sys
import tempfile

os.environ["BLENDER_USER_RESOURCES"] = tempfile.mkdtemp(prefix="bodycal-install-")

import bpy  # noqa: E402, I001  (first: addon_utils imports only after it)
import addon_utils  # noqa: E402


def registered():
    ops = sorted(name for name in dir(bpy.ops.bodycal) if not name.startswith("_"))
    panels = sorted(name for name in dir(bpy.types) if name.startswith("BODYCAL_PT_"))
    # The sidebar tabs (the bake presets popover is a header panel: it has none).
    categories = sorted({getattr(bpy.types, p).bl_category for p in panels if hasattr(getattr(bpy.types, p),
                                                                                     "bl_category")})
    classes = sorted(name for name in dir(bpy.types) if name.startswith("BODYCAL_"))
    return {"operators": ops, "panels": panels, "categories": categories, "classes": classes}


zip_path = sys.argv[1]
report = {"before": registered()}
result = bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default",
                                                  enable_on_install=True)
report["install_result"] = sorted(result)
report["module_enabled"] = "bl_ext.user_default.bodycal" in bpy.context.preferences.addons
report["installed"] = registered()
installed_dir = os.path.join(bpy.utils.user_resource("EXTENSIONS", path="user_default"), "bodycal")
report["installed_files"] = sorted(os.listdir(installed_dir)) if os.path.isdir(installed_dir) else []
# The bundled wheels go to the extensions' own site-packages, which Blender puts on sys.path; the
# installed extension's live receiver runs from there (python-osc may also be in this Python's
# environment: the spec below looks in the extensions' folder only).
site = os.path.join(bpy.utils.user_resource("EXTENSIONS"), ".local", "lib",
                    f"python{sys.version_info.major}.{sys.version_info.minor}", "site-packages")
spec = importlib.machinery.PathFinder.find_spec("pythonosc", [site])
report["wheel"] = {"installed": spec is not None, "on_path": site in sys.path}
receiver = importlib.import_module("bl_ext.user_default.bodycal.bodycal_addon.recording.live.receiver")
live = receiver.VmcReceiver(port=0)
live.start()
report["wheel"]["receiver_ran"] = live.running
live.stop()
# The manifest's wheels, unpacked by Blender into the user extensions' own site-packages.
user_files = os.walk(os.environ["BLENDER_USER_RESOURCES"])
report["wheel_packages"] = sorted({os.path.basename(d) for d, _sub, files in user_files
                                   if "__init__.py" in files and os.path.dirname(d).endswith("site-packages")})
addon_utils.disable("bl_ext.user_default.bodycal", default_set=True)
report["after_disable"] = registered()
report["module_enabled_after"] = "bl_ext.user_default.bodycal" in bpy.context.preferences.addons
print("REPORT " + json.dumps(report))
sys.stdout.flush()
# Blender's session folder, which its exit handlers would remove: this process leaves without them.
shutil.rmtree(bpy.app.tempdir, ignore_errors=True)
os._exit(0)
