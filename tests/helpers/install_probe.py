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


def worker_probe(installed_dir):
    import time

    sys.path.append(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))  # bodycal_dev
    from bodycal_dev import synthetic
    from bodycal_dev.retarget_fixtures import procedural_avatar

    worker = importlib.import_module("bl_ext.user_default.bodycal.bodycal_addon.live.worker")
    model = importlib.import_module("bl_ext.user_default.bodycal.bodycal_addon.recording.model")
    rec, truth = synthetic.record_session(synthetic.make_performer(seed=1), motions=("clap",),
                                          calibration=["tpose"], motion_seconds=0.5)
    process = worker.SolverProcess("probe")
    deadline = time.monotonic() + 120.0
    while process.starting and time.monotonic() < deadline:
        time.sleep(0.01)
    out = {"engine_dir": str(worker.ENGINE_DIR) == os.path.realpath(installed_dir), "error": process.error,
           "poses": 0}
    if process.connection is not None:
        used = [i for i, d in enumerate(rec.devices) if d.role]
        devices = [model.Device(rec.devices[i].name, rec.devices[i].kind, rec.devices[i].role) for i in used]
        process.connection.send(worker.prepare_message(truth.body_model(), procedural_avatar(), "egocentric",
                                                       devices, [], None, True, "object"))
        out["prepared"] = process.connection.recv()[0]
        for k in range(3):
            process.connection.send(worker.frame_message(rec.time[k], rec.positions[k, used],
                                                         rec.rotations[k, used], rec.valid[k, used], None, None))
            out["poses"] += process.connection.recv()[0] == "pose"
    pid = process.pid
    process.close()
    out["ended"] = pid is not None and process.exit_code() is not None
    return out


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
# A live follower's worker process from the installed files: the child imports the engine from the
# installed extension's folder as a top-level package (no bl_ext there) and solves a frame.
report["worker"] = worker_probe(installed_dir)
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
