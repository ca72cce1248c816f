"""The sidebar and its conventions as animators expect them (docs/SIDEBAR.md): tooltips, add-on
preferences, bake presets, the File > Export entry, the sample buttons, the long-running
operators' progress, Esc and viewport navigation, the panels' order and layout."""

import importlib
import os

import bpy
import pytest
import ui_layout

EXTENSION = "bl_ext.user_default.bodycal"


def _ours(cls) -> bool:
    return cls.__module__.startswith(EXTENSION + ".") or cls.__module__ == EXTENSION


def _subclasses(base) -> list:
    out, todo = [], list(base.__subclasses__())
    while todo:
        cls = todo.pop()
        todo.extend(cls.__subclasses__())
        if _ours(cls) and cls.is_registered:
            out.append(cls)
    return out


def _properties(rna) -> list:
    return [p for p in rna.properties
            if p.identifier != "rna_type" and not p.identifier.startswith("bl_") and not p.is_hidden]


def _described_things():
    """(what, description) of every tooltip the extension shows: each operator, panel and menu,
    each property of theirs and of its property groups, each static enum item, and the
    properties it adds to Blender's own types."""
    for name in dir(bpy.ops.bodycal):
        if name.startswith("_"):
            continue
        rna = getattr(bpy.ops.bodycal, name).get_rna_type()
        yield f"bodycal.{name}", rna.description
        for prop in _properties(rna):
            yield f"bodycal.{name}.{prop.identifier}", prop.description
            for item in getattr(prop, "enum_items", ()):
                yield f"bodycal.{name}.{prop.identifier}:{item.identifier}", item.description
    for base in (bpy.types.Panel, bpy.types.Menu):
        for cls in _subclasses(base):
            yield cls.__name__, cls.bl_description if "bl_description" in cls.__dict__ else (cls.__doc__ or "")
    for base in (bpy.types.PropertyGroup, bpy.types.AddonPreferences):
        for cls in _subclasses(base):
            for prop in _properties(cls.bl_rna):
                if prop.identifier == "name" and base is bpy.types.PropertyGroup:
                    continue  # Blender's own, every property group has it
                yield f"{cls.__name__}.{prop.identifier}", prop.description
                for item in getattr(prop, "enum_items", ()):
                    yield f"{cls.__name__}.{prop.identifier}:{item.identifier}", item.description
    for owner in (bpy.types.Scene, bpy.types.WindowManager, bpy.types.Object):
        for prop in owner.bl_rna.properties:
            if prop.identifier.startswith("bodycal"):
                yield f"{owner.__name__}.{prop.identifier}", prop.description


def test_every_tooltip_is_one_line_and_every_property_is_described():
    """Blender shows an operator's docstring as its tooltip as written: a docstring wrapped over
    lines showed its newline and the next line's indent. And a property without a description
    has a tooltip that only repeats its name."""
    things = list(_described_things())
    assert len(things) > 100  # the operators, panels and settings were all found
    multi = [what for what, text in things if "\n" in text or "  " in text]
    bare = [what for what, text in things if not text.strip()]
    assert not multi and not bare, (len(things), multi, bare)


def _module(name):
    return importlib.import_module(f"{EXTENSION}.{name}")


def _prefs():
    return bpy.context.preferences.addons[EXTENSION].preferences


@pytest.fixture
def prefs():
    """BodyCal's add-on preferences, put back as they were after the test."""
    p = _prefs()
    before = {name: getattr(p, name) for name in ("recordings_folder", "avatars_folder", "export_folder",
                                                   "default_method")}
    yield p
    for name, value in before.items():
        setattr(p, name, value)


def test_preferences_are_the_extensions_own():
    """Blender keys an extension's preferences by its package, bl_ext.<repository>.bodycal."""
    p = _prefs()
    assert type(p).bl_idname == EXTENSION
    for name in ("recordings_folder", "avatars_folder", "export_folder"):
        assert p.bl_rna.properties[name].subtype == "DIR_PATH"
    assert p.default_method == "egocentric"


def test_the_default_method_is_the_preferences_until_the_scene_picks_one(prefs):
    retarget, transfer = bpy.context.scene.bodycal_retarget, bpy.context.scene.bodycal_transfer
    assert retarget.method == transfer.method == "egocentric"
    prefs.default_method = "offsets"
    assert retarget.method == "offsets"
    assert transfer.method == "egocentric"  # a transfer has no trackers to take offsets from
    prefs.default_method = "rotations"
    assert retarget.method == transfer.method == "rotations"
    retarget.method = "egocentric"  # picked in this scene: the preference no longer changes it
    prefs.default_method = "offsets"
    assert retarget.method == "egocentric" and transfer.method == "egocentric"
    bpy.ops.wm.read_homefile(use_empty=True)  # a new file starts from the preference again
    assert bpy.context.scene.bodycal_retarget.method == "offsets"


class _WindowManager:
    def __init__(self):
        self.browsers = []

    def fileselect_add(self, op):
        self.browsers.append(op.filepath)


def test_file_browsers_open_in_the_preferences_folders(prefs, tmp_path):
    from bpy_extras.io_utils import ExportHelper, ImportHelper

    preferences = _module("operators.preferences")
    context = type("Context", (), {"preferences": bpy.context.preferences, "window_manager": _WindowManager(),
                                   "blend_data": bpy.data})()
    importer = type("Importer", (preferences.StartsInFolder, ImportHelper),
                    {"filepath": "", "_folder": "recordings_folder"})
    exporter = type("Exporter", (preferences.StartsInFolder, ExportHelper),
                    {"filepath": "", "filename_ext": ".fbx", "_folder": "export_folder",
                     "_suggested_name": lambda self, _context: "ogre.fbx"})
    importer().invoke(context, None)
    exporter().invoke(context, None)
    assert [p.lower() for p in context.window_manager.browsers] == ["", "untitled.fbx"]  # no folder: Blender's choice
    prefs.recordings_folder = str(tmp_path / "takes")
    prefs.export_folder = str(tmp_path / "exports")
    (tmp_path / "exports").mkdir()
    importer().invoke(context, None)
    exporter().invoke(context, None)
    # A folder that does not exist is ignored, rather than opening the browser on nothing.
    assert context.window_manager.browsers[2:] == ["", str(tmp_path / "exports" / "ogre.fbx")]
    (tmp_path / "takes").mkdir()
    importer().invoke(context, None)
    assert context.window_manager.browsers[4] == str(tmp_path / "takes") + "/"
    given = exporter()
    given.filepath = str(tmp_path / "elsewhere.fbx")  # a path the caller gave is kept
    given.invoke(context, None)
    assert context.window_manager.browsers[5] == str(tmp_path / "elsewhere.fbx")
    # The sidebar's file operators use it, each with its folder.
    folders = {"import_recording": "recordings_folder", "save_user_model": "recordings_folder",
               "load_user_model": "recordings_folder", "import_avatar": "avatars_folder",
               "export_avatar_model": "avatars_folder", "import_avatar_model": "avatars_folder",
               "export_animation": "export_folder"}
    for name, pref in folders.items():
        cls = bpy.types.Operator.bl_rna_get_subclass_py(f"BODYCAL_OT_{name}")
        assert issubclass(cls, preferences.StartsInFolder) and cls._folder == pref, name


def test_bake_presets_save_and_apply_the_bake_settings():
    scene = bpy.context.scene
    bake, retarget = scene.bodycal_bake, scene.bodycal_retarget
    arm = bpy.data.objects.new("avatar", bpy.data.armatures.new("avatar"))
    scene.collection.objects.link(arm)
    bake.armature = arm
    bake.root_motion, bake.rigify_target, bake.plant_feet, bake.output_fps = "in-place", "def", False, 60
    bake.tolerance, bake.frame_range = 0.01, "take"
    retarget.use_filter, retarget.filter_beta = True, 2.5
    retarget.method = "offsets"
    assert bpy.ops.bodycal.add_bake_preset(name="Game Export") == {"FINISHED"}
    preset = os.path.join(bpy.utils.user_resource("SCRIPTS", path="presets/bodycal/bake"), "Game_Export.py")
    assert os.path.isfile(preset)  # the user's presets: kept across files and sessions
    try:
        bake.root_motion, bake.rigify_target, bake.plant_feet, bake.output_fps = "root", "fk", True, 0
        bake.tolerance, bake.frame_range = 0.002, "scene"
        retarget.use_filter, retarget.filter_beta = False, 5.0
        bake.armature, retarget.method = None, "rotations"
        assert bpy.ops.script.execute_preset(filepath=preset, menu_idname="BODYCAL_PT_bake_presets") == {"FINISHED"}
        applied = (bake.root_motion, bake.rigify_target, bake.plant_feet, bake.output_fps)
        assert applied == ("in-place", "def", False, 60)
        assert bake.tolerance == pytest.approx(0.01) and bake.frame_range == "take"
        assert retarget.use_filter and retarget.filter_beta == pytest.approx(2.5)
        # How to bake, not what: the avatar and the method are the scene's own.
        assert bake.armature is None and retarget.method == "rotations"
        # Both bake panels offer the presets in their header.
        for panel in ("BODYCAL_PT_retarget", "BODYCAL_PT_transfer"):
            log = ui_layout.draw(getattr(bpy.types, panel), bpy.context, "draw_header_preset")
            assert ("popover", "BODYCAL_PT_bake_presets") in log, panel
        assert bpy.ops.bodycal.add_bake_preset(remove_active=True) == {"FINISHED"}  # the one applied last
        assert not os.path.exists(preset)
    finally:
        if os.path.exists(preset):
            os.remove(preset)


def _baked_avatar():
    """The procedural avatar with a short action on its upper arm, as a bake leaves it (active)."""
    from bodycal_addon.core import paths

    arm, _mesh, _spec = paths.sample_rigs().build_procedural_avatar()
    bpy.context.view_layer.objects.active = arm
    arm.animation_data_create().action = bpy.data.actions.new("take__procedural")
    bone = arm.pose.bones["upperarm_l"]
    bone.rotation_mode = "QUATERNION"
    for frame, w in ((1, 1.0), (10, 0.8)):
        bone.rotation_quaternion = (w, (1 - w * w) ** 0.5, 0.0, 0.0)
        bone.keyframe_insert("rotation_quaternion", frame=frame)
    bpy.context.scene.frame_start, bpy.context.scene.frame_end = 1, 10
    return arm


def test_file_export_offers_the_baked_avatar(tmp_path):
    entries = []
    for draw in bpy.types.TOPBAR_MT_file_export._dyn_ui_initialize():
        log = []
        draw(type("Menu", (), {"layout": ui_layout.RecordingLayout(log)})(), bpy.context)
        entries += [e[1] for e in log if e[0] == "operator"]
    assert "bodycal.export_animation" in entries
    assert not bpy.ops.bodycal.export_animation.poll()  # nothing baked is active: greyed out, says why
    arm = _baked_avatar()
    assert bpy.ops.bodycal.export_animation.poll()
    for suffix in (".fbx", ".glb"):
        out = tmp_path / f"ogre{suffix}"
        assert bpy.ops.bodycal.export_animation(filepath=str(out), file_format=suffix) == {"FINISHED"}
        assert out.stat().st_size > 1000
    assert bpy.context.active_object == arm


def test_sample_avatars_are_offered_only_where_they_are(monkeypatch):
    """An installed extension has no sample_data/: its Load Sample Avatars button was there for
    good, greyed out."""
    paths = _module("bodycal_addon.core.paths")
    drawn = {e[1] for e in ui_layout.draw(bpy.types.BODYCAL_PT_avatar, bpy.context) if e[0] == "operator"}
    assert {"bodycal.load_sample_avatars", "bodycal.add_procedural_avatar"} <= drawn
    monkeypatch.setattr(paths, "data_dir", lambda: None)
    drawn = {e[1] for e in ui_layout.draw(bpy.types.BODYCAL_PT_avatar, bpy.context) if e[0] == "operator"}
    assert "bodycal.load_sample_avatars" not in drawn
    assert "bodycal.add_procedural_avatar" in drawn  # built from code: always there


class _Event:
    def __init__(self, kind, alt=False):
        self.type, self.value, self.alt = kind, "PRESS", alt


class _JobContext:
    """What a running job touches of its context: the progress, the status text, the timer."""

    def __init__(self, emulate_3_button=False):
        self.progress, self.status = [], []
        wm = type("WM", (), {})()
        wm.progress_update = self.progress.append
        wm.progress_begin = wm.progress_end = lambda *a: None
        wm.event_timer_add = lambda *a, **k: "timer"
        wm.event_timer_remove = wm.modal_handler_add = lambda *a: None
        self.window_manager, self.window = wm, None
        self.workspace = type("WS", (), {"status_text_set": lambda _s, text: self.status.append(text)})()
        inputs = type("Inputs", (), {"use_mouse_emulate_3_button": emulate_3_button})()
        self.preferences = type("Prefs", (), {"inputs": inputs})()


def _job(work, doing="retargeting"):
    """A BackgroundWork operator stand-in (the mixin Retarget and Bake and Transfer use) that
    started `work(progress, cancel)` in its worker thread."""
    background_work = _module("operators.background_work")

    class Job(background_work.BackgroundWork):
        _doing = doing

        def __init__(self):
            self.reports = []

        def report(self, kind, text):
            self.reports.append((kind, text))

        def _done(self, _context, result):
            self.result = result
            return {"FINISHED"}

    job, context = Job(), _JobContext()
    assert job._start(context, work) == {"RUNNING_MODAL"}
    return job, context


def _until_finished(job, context):
    while True:
        result = job.modal(context, _Event("TIMER"))
        if result != {"PASS_THROUGH"}:
            return result
        job._thread.join(0.05)


def test_a_running_bake_lets_the_viewport_be_navigated_and_nothing_else():
    import threading

    release = threading.Event()

    def work(progress, cancel):
        progress(0.25)
        release.wait(30)
        progress(1.0)
        return "baked"

    job, context = _job(work)
    for kind in ("MIDDLEMOUSE", "WHEELUPMOUSE", "WHEELDOWNMOUSE", "MOUSEMOVE", "TRACKPADPAN", "TRACKPADZOOM",
                 "NDOF_MOTION", "NUMPAD_1", "NUMPAD_PERIOD", "HOME", "TIMER_REPORT"):
        assert job.modal(context, _Event(kind)) == {"PASS_THROUGH"}, kind
    for kind in ("LEFTMOUSE", "RIGHTMOUSE", "A", "G", "X", "DEL", "Z", "SPACE", "RET"):
        assert job.modal(context, _Event(kind)) == {"RUNNING_MODAL"}, kind  # no edits under a bake
    assert job.modal(context, _Event("LEFTMOUSE", alt=True)) == {"RUNNING_MODAL"}
    context.preferences.inputs.use_mouse_emulate_3_button = True  # Alt + left button orbits
    assert job.modal(context, _Event("LEFTMOUSE", alt=True)) == {"PASS_THROUGH"}
    job._thread.join(0.2)
    assert job.modal(context, _Event("TIMER")) == {"PASS_THROUGH"}  # still working
    assert context.progress[-1] == 25 and context.status[-1] == "BodyCal: retargeting... 25% (Esc to cancel)"
    release.set()
    assert _until_finished(job, context) == {"FINISHED"} and job.result == "baked"
    assert context.progress[-1] == 100 and context.status[-1] is None


def test_esc_stops_a_running_bake_before_anything_is_written():
    errors = _module("bodycal_addon.core.errors")

    def work(progress, cancel):
        k = 0
        while not cancel():
            progress(min(k / 1000, 0.5))
            k += 1
        raise errors.Cancelled()

    job, context = _job(work)
    assert job.modal(context, _Event("ESC")) == {"RUNNING_MODAL"}  # Esc is the job's: nothing else sees it
    job._thread.join(5)
    assert job.modal(context, _Event("TIMER")) == {"CANCELLED"}
    assert "BodyCal: cancelling retargeting..." in context.status and context.status[-1] is None
    assert not hasattr(job, "result")
    assert job.reports == [({"WARNING"}, "Cancelled: nothing was written")]


def test_calibrate_avatar_shows_its_progress_and_esc_stops_it():
    """Calibrate Avatar casts its rays in the sidebar's worker (the bake's BackgroundWork): its
    progress runs from 0 to 100 % as the rays are cast, and Esc stops it with nothing stored."""
    from bodycal_addon.core import paths

    # The extension's own modules: its worker knows its own Cancelled.
    avatar_calibration = _module("bodycal_addon.blender.avatar_calibration")
    avatar_storage = _module("bodycal_addon.blender.avatar_storage")
    background_work = _module("operators.background_work")
    assert issubclass(bpy.types.BODYCAL_OT_calibrate_avatar, background_work.BackgroundWork)
    arm, _mesh, _spec = paths.sample_rigs().build_procedural_avatar()
    rig, caster = avatar_calibration.prepare_survey(arm)
    seen = []

    def work(progress, cancel):
        return avatar_calibration.measure(rig, caster, arm.name, progress=lambda f: (seen.append(f), progress(f)),
                                          cancel=cancel)

    job, context = _job(work, "calibrating the avatar")
    assert _until_finished(job, context) == {"FINISHED"}
    assert len(set(seen)) > 1000 and seen == sorted(seen) and seen[-1] == 1.0
    assert job.result.extra["rays_cast"] == len(seen)
    assert context.progress[-1] == 100
    reference = avatar_calibration.calibrate_avatar(arm)  # the same numbers as the one-call path
    assert [e.id for e in job.result.surface] == [e.id for e in reference.surface]
    assert job.result.bones["forearm_l"].radius_head == reference.bones["forearm_l"].radius_head

    rig, caster = avatar_calibration.prepare_survey(arm)
    job, context = _job(lambda progress, cancel: avatar_calibration.measure(
        rig, caster, arm.name, progress=progress, cancel=cancel), "calibrating the avatar")
    job.modal(context, _Event("ESC"))
    assert _until_finished(job, context) == {"CANCELLED"}
    assert caster.rays < caster.planned and not avatar_storage.has_model(arm)



def _sub_panels_of_main() -> list:
    return [cls for cls in _subclasses(bpy.types.Panel) if getattr(cls, "bl_parent_id", "") == "BODYCAL_PT_main"]


def test_the_panels_follow_the_work_and_a_new_one_takes_its_slot():
    """Recording, User Calibration, Avatar, Retarget and Bake, Transfer Animation, then Live: the
    order of panels/conventions.ORDER, whichever module a panel comes from and whenever it is
    registered (Blender sorts a parent's sub-panels by bl_order)."""
    conventions = _module("panels.conventions")
    order = conventions.ORDER
    assert order[0] == "BODYCAL_PT_recording" and order[-1] == "BODYCAL_PT_live"
    assert order.index("BODYCAL_PT_calibration") < order.index("BODYCAL_PT_avatar") < order.index(
        "BODYCAL_PT_retarget") < order.index("BODYCAL_PT_transfer") < order.index("BODYCAL_PT_live")
    panels = _sub_panels_of_main()
    assert {"BODYCAL_PT_calibration", "BODYCAL_PT_avatar", "BODYCAL_PT_retarget",
            "BODYCAL_PT_transfer"} <= {cls.bl_idname for cls in panels}
    for cls in panels:  # every stage has its place: a new panel is added to ORDER
        assert cls.bl_idname in order, cls.bl_idname
        assert cls.bl_order == order.index(cls.bl_idname), cls.bl_idname
    # The Recording panel, merged later from its own module, slots first.
    recording = type("BODYCAL_PT_recording", (bpy.types.Panel,), {
        "bl_idname": "BODYCAL_PT_recording", "bl_label": "Recording", "bl_space_type": "VIEW_3D",
        "bl_region_type": "UI", "bl_category": "BodyCal", "bl_parent_id": "BODYCAL_PT_main",
        "draw": lambda self, context: None})
    if not hasattr(bpy.types, "BODYCAL_PT_recording"):
        conventions.apply_order([recording])
        assert recording.bl_order < min(cls.bl_order for cls in panels)


def _drawn_layout(panel, context):
    log = []
    layout = ui_layout.RecordingLayout(log)
    panel.draw(type("P", (), {"layout": layout})(), context)
    return layout, log


def test_settings_are_laid_out_as_blenders_own_panels():
    """Properties in two columns (label, value) without animation dots, as Blender's own editors
    show them (`use_property_split`), in every panel that shows settings and in the preferences."""
    for panel in (bpy.types.BODYCAL_PT_retarget, bpy.types.BODYCAL_PT_transfer, type(_prefs())):
        layout, log = _drawn_layout(panel, bpy.context)
        assert any(e[0] == "prop" for e in log), panel
        assert layout.use_property_split is True and layout.use_property_decorate is False, panel


def test_smooth_devices_is_an_optional_block_with_its_checkbox_in_its_header():
    settings = bpy.context.scene.bodycal_retarget
    filters = ["filter_min_cutoff", "filter_beta", "filter_rot_min_cutoff", "filter_rot_beta"]
    for on in (False, True):
        settings.use_filter = on
        log = ui_layout.draw(bpy.types.BODYCAL_PT_retarget, bpy.context)
        at = log.index(("panel", "BODYCAL_retarget_smoothing"))
        assert log[at + 1] == ("prop", settings, "use_filter")  # the block's header
        # Its values stay in view, greyed out while it is off, rather than appearing and vanishing.
        assert [e[2] for e in log[at + 2:at + 6]] == filters
    settings.use_filter = False


class _Region:
    def __init__(self, width):
        self.width = width


def _in_region(width):
    """The context a sidebar of `width` pixels draws its panels in."""
    return type("Context", (), {"scene": bpy.context.scene, "region": _Region(width),
                                "preferences": bpy.context.preferences, "active_object": None})()


def test_long_result_lines_are_wrapped_to_the_sidebar_not_cut():
    settings = bpy.context.scene.bodycal_retarget
    first = ("adult_male: 2304 keys on 53 bones over 240 frames (0.1 degree tolerance), root motion on root, "
             "feet planted 61% of the frames, 3 contacts kept")
    settings.last_result = f"{first}; child: 1880 keys"
    try:
        for width, most in ((300, 40), (600, 80)):
            log = ui_layout.draw(bpy.types.BODYCAL_PT_retarget, _in_region(width))
            labels = [e[1] for e in log if e[0] == "label"]
            assert " ".join(labels) == f"{first} child: 1880 keys"  # nothing cut
            assert all(len(line) <= most for line in labels), (width, labels)
            assert labels[-1] == "child: 1880 keys"  # each avatar's line starts a line
        assert len([e for e in ui_layout.draw(bpy.types.BODYCAL_PT_retarget, _in_region(300))
                    if e[0] == "label"]) > 3
    finally:
        settings.last_result = ""


def test_every_panel_has_a_help_button_to_its_part_of_the_docs(monkeypatch):
    from repo_paths import REPO

    sidebar = (REPO / "docs" / "SIDEBAR.md").read_text()
    headings = {line.lstrip("#").strip() for line in sidebar.splitlines() if line.startswith("#")}
    for cls in [bpy.types.BODYCAL_PT_main, *_sub_panels_of_main()]:
        log = ui_layout.draw(cls, bpy.context, "draw_header_preset")
        (help_button,) = [e for e in log if e[0] == "operator" and e[1] == "bodycal.open_docs"]
        assert help_button.props.page == "SIDEBAR.md"
        assert help_button.props.section in headings, (cls.bl_idname, help_button.props.section)
    docs = _module("operators.docs")
    opened = []
    monkeypatch.setattr(docs, "open_url", opened.append)
    assert bpy.ops.bodycal.open_docs(page="SIDEBAR.md", section="Avatar") == {"FINISHED"}
    assert opened == [(REPO / "docs" / "SIDEBAR.md").resolve().as_uri()]
    # A page is a file of docs/, never a path elsewhere.
    assert docs.docs_path("../README.md") == docs.DOCS_DIR / "README.md"
