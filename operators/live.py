"""Live in Blender (docs/LIVE.md): connect to a VMC stream, let avatars follow the performer, record
a take into the scene and bake it. Thin UI over bodycal_addon/blender/live.py; the live view makes
no undo step: only Stop Recording (which imports the take) and Bake Take change the file."""

import bpy

from ..bodycal_addon.blender import calibration_scene, live, recording_scene, session
from .bake_settings import BakeOperator, can_bake_in, method_items, selected_armatures
from .preferences import method_property
from .recording import STEP_MARKER_ITEMS
from .reporting import reports_errors
from .review import BODYCAL_PG_review_flag

USER_ITEMS = [
    ("scene", "Scene's Performer", "The performer calibrated in this scene (User Calibration)"),
    ("file", "Body Model File", "A performer's .body.json file (saved from User Calibration or by bodycal calibrate)"),
]


class BODYCAL_PG_live_settings(bpy.types.PropertyGroup):
    port: bpy.props.IntProperty(
        name="Port", default=live.DEFAULT_PORT, min=0, max=65535,
        description="UDP port the VMC sender sends to (39539 is VMC's; 0 picks a free one)")
    bind: bpy.props.StringProperty(
        name="Listen On", default="127.0.0.1",
        description="Address to listen on: 127.0.0.1 hears this computer only; 0.0.0.0 every network (a headset "
                    "on Wi-Fi: allow the port in the firewall)")
    user: bpy.props.EnumProperty(name="Performer", items=USER_ITEMS, default="scene",
                                 description="Whose body model the followers use")
    user_file: bpy.props.StringProperty(name="Body Model", subtype="FILE_PATH", default="",
                                        description="The performer's .body.json file")
    method: method_property(method_items(session.RECORDING), "Method", "How the performer drives the avatars")
    folder: bpy.props.StringProperty(
        name="Takes Folder", subtype="DIR_PATH", default="",
        description="Where recorded takes are saved (empty: next to the .blend)")
    take_name: bpy.props.StringProperty(name="Take Name", default="take",
                                        description="The take's file name starts with this; the time follows")
    step_markers: bpy.props.EnumProperty(
        name="Step Markers", items=STEP_MARKER_ITEMS, default="starts",
        description="Timeline markers for the calibration steps of the recorded take")
    last_result: bpy.props.StringProperty(name="Last Result", default="", options={"SKIP_SAVE"},
                                          description="The last Bake Take's figures, per avatar")
    review_flags: bpy.props.CollectionProperty(type=BODYCAL_PG_review_flag, name="Review",
                                               description="The last bake\'s review: its figures against their limits")
    use_workers: bpy.props.BoolProperty(
        name="Solve in Worker Processes", default=True,
        description="Solve each avatar in a process of its own: Blender never runs or waits for a solve, and several "
                    "avatars use several cores (off: solved on a thread of Blender's own process)")
    wizard_pause: bpy.props.FloatProperty(
        name="Begin Steps After", default=0.0, min=0.0, soft_max=10.0, unit="TIME_ABSOLUTE",
        description="The calibration wizard begins each step by itself this many seconds after the previous one "
                    "ended (time to read the instruction); 0: each step begins when you press Begin")


def _settings(context):
    return context.scene.bodycal_live


def user_model(context):
    """The performer's model the Live settings name: the scene's or a file's."""
    settings = _settings(context)
    return calibration_scene.performer_model(context.scene, settings.user_file if settings.user == "file" else None)


def _poll_connected(cls) -> bool:
    if not live.connected():
        cls.poll_message_set("Connect to a VMC stream first")
        return False
    return True


class BODYCAL_OT_connect_live(bpy.types.Operator):
    """Listen for a VMC stream (VirtualMotionCapture, bodycal stream, ...): its devices appear as live empties"""

    bl_idname = "bodycal.connect_live"
    bl_label = "Connect"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        if live.connected():
            cls.poll_message_set("Already connected: Disconnect first")
            return False
        return True

    @reports_errors
    def execute(self, context):
        settings = _settings(context)
        live.connect(settings.port, settings.bind)
        self.report({"INFO"}, f"Listening on {settings.bind}:{live.port()} for a VMC stream")
        return {"FINISHED"}


class BODYCAL_OT_disconnect_live(bpy.types.Operator):
    """Stop listening: every avatar put back as it was, the live empties removed (a take being recorded is saved
and imported first)"""

    bl_idname = "bodycal.disconnect_live"
    bl_label = "Disconnect"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        return _poll_connected(cls)

    @reports_errors
    def execute(self, context):
        if live.recording() is not None:  # saved and imported first; a take that cannot be saved keeps the session
            settings = _settings(context)
            path, coll = live.stop_recording(settings.folder, context.scene, settings.step_markers)
            self.report({"INFO"}, f"Saved {path} and imported it as {coll.name}")
        live.disconnect()
        return {"FINISHED"}


class BODYCAL_OT_follow_live(bpy.types.Operator):
    """The avatar (picked in Retarget and Bake, else the selected armatures) follows the performer"""

    bl_idname = "bodycal.follow_live"
    bl_label = "Follow"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        if not _poll_connected(cls):
            return False
        if context.mode not in {"OBJECT", "POSE"}:
            cls.poll_message_set("Switch to Object or Pose Mode to follow")
            return False
        if not selected_armatures(context):
            cls.poll_message_set("Pick an avatar armature in Retarget and Bake (or select armatures)")
            return False
        return True

    @reports_errors
    def execute(self, context):
        settings, bake = _settings(context), context.scene.bodycal_bake
        user = user_model(context)
        retarget = context.scene.bodycal_retarget
        smooth = retarget.one_euro()
        seat = retarget.seat_height if retarget.seated else None
        arms = selected_armatures(context)
        worker = settings.use_workers
        names = []
        for arm in arms:
            live.follow(arm, user, settings.method, smooth=smooth, plant_feet=bake.plant_feet,
                        placement=bake.placement, root_motion=bake.root_motion, worker=worker, seat_height=seat)
            names.append(arm.name)
        self.report({"INFO"}, f"Following with {', '.join(names)}")
        return {"FINISHED"}


class BODYCAL_OT_stop_following(bpy.types.Operator):
    """Stop every avatar following: each is put back exactly as it was (action, pose, rotation modes)"""

    bl_idname = "bodycal.stop_following"
    bl_label = "Stop Following"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        if not live.following():
            cls.poll_message_set("No avatar is following")
            return False
        return True

    def execute(self, context):
        live.stop_following()
        return {"FINISHED"}


class BODYCAL_OT_record_take(bpy.types.Operator):
    """Record every frame of the stream from now on (Stop Recording saves the take and imports it)"""

    bl_idname = "bodycal.record_take"
    bl_label = "Record"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        if not _poll_connected(cls):
            return False
        if live.recording() is not None:
            cls.poll_message_set("Already recording")
            return False
        return True

    @reports_errors
    def execute(self, context):
        settings = _settings(context)
        live.take_folder(settings.folder)  # said now, not when the take is over
        live.start_recording(settings.take_name or "take")
        return {"FINISHED"}


class BODYCAL_OT_stop_recording(bpy.types.Operator):
    """Stop recording: the take is saved as a recording file (next to the .blend or in the takes folder) and
imported into the scene, ready for Calibrate User and Bake Take"""

    bl_idname = "bodycal.stop_recording"
    bl_label = "Stop Recording"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        if live.recording() is None:
            cls.poll_message_set("Not recording")
            return False
        if context.mode != "OBJECT":
            cls.poll_message_set("Switch to Object Mode to import the take")
            return False
        return True

    @reports_errors
    def execute(self, context):
        settings = _settings(context)
        path, coll = live.stop_recording(settings.folder, context.scene, settings.step_markers)
        self.report({"INFO"}, f"Saved {path} and imported it as {coll.name}")
        return {"FINISHED"}


class BODYCAL_OT_start_wizard(bpy.types.Operator):
    """Record a calibration take with the performer: the protocol's steps the connected devices allow, each with
its instruction and progress, each ending by itself when enough data is in"""

    bl_idname = "bodycal.start_wizard"
    bl_label = "Calibration Wizard"
    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        if not _poll_connected(cls):
            return False
        if live.wizard() is not None:
            cls.poll_message_set("The calibration wizard is running")
            return False
        return True

    @reports_errors
    def execute(self, context):
        settings = _settings(context)
        live.take_folder(settings.folder)  # said now, not when the take is over
        w = live.start_wizard(settings.take_name or "calibration", settings.wizard_pause or None)
        self.report({"INFO"}, f"Calibration wizard: {len(w.steps)} steps")
        return {"FINISHED"}


class _WizardStepOperator:
    """What Begin, End, Skip and Redo share: they act on the running wizard."""

    bl_options = {"REGISTER"}

    @classmethod
    def poll(cls, context):
        if live.wizard() is None:
            cls.poll_message_set("Start the calibration wizard first")
            return False
        return cls._can(live.wizard())

    @classmethod
    def _can(cls, wizard) -> bool:
        return True

    @reports_errors
    def execute(self, context):
        self._act(live.wizard())
        return {"FINISHED"}


class BODYCAL_OT_begin_step(_WizardStepOperator, bpy.types.Operator):
    """Begin recording the current calibration step (read its instruction to the performer first)"""

    bl_idname = "bodycal.begin_step"
    bl_label = "Begin"

    @classmethod
    def _can(cls, wizard):
        if wizard.finished or wizard.active:
            cls.poll_message_set("No step is waiting to begin")
            return False
        return True

    def _act(self, wizard):
        wizard.begin()


class BODYCAL_OT_end_step(_WizardStepOperator, bpy.types.Operator):
    """End the current step now and keep what was recorded of it"""

    bl_idname = "bodycal.end_step"
    bl_label = "End"

    @classmethod
    def _can(cls, wizard):
        if not wizard.active:
            cls.poll_message_set("No step is being recorded")
            return False
        return True

    def _act(self, wizard):
        wizard.end_step()


class BODYCAL_OT_skip_step(_WizardStepOperator, bpy.types.Operator):
    """Leave the current step out and go to the next"""

    bl_idname = "bodycal.skip_step"
    bl_label = "Skip"

    @classmethod
    def _can(cls, wizard):
        if wizard.finished:
            cls.poll_message_set("Every step is done")
            return False
        return True

    def _act(self, wizard):
        wizard.skip_step()


class BODYCAL_OT_redo_step(_WizardStepOperator, bpy.types.Operator):
    """Record the current step again (or, between steps, the previous one)"""

    bl_idname = "bodycal.redo_step"
    bl_label = "Redo"

    @classmethod
    def _can(cls, wizard):
        if not wizard.active and wizard.index == 0:
            cls.poll_message_set("No step to redo yet")
            return False
        return True

    def _act(self, wizard):
        wizard.redo_step()


class BODYCAL_OT_bake_take(BakeOperator, bpy.types.Operator):
    """Retarget the recorded take (the scene's recording) onto the avatars that followed it, with the whole
offline pipeline, and bake a new action on each"""

    _doing, _cancelled = "baking the take", "Bake Take cancelled"
    bl_idname = "bodycal.bake_take"
    bl_label = "Bake Take"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        if not can_bake_in(cls, context):
            return False
        if live.recording() is not None:
            cls.poll_message_set("Stop Recording first")
            return False
        if not cls._avatars(context):
            cls.poll_message_set("Follow with an avatar while recording, or select armatures")
            return False
        if recording_scene.scene_recording_collection(context.scene) is None:
            cls.poll_message_set("Record a take first")
            return False
        return True

    @staticmethod
    def _avatars(context) -> list:
        names = list(live.following()) or live.recorded_for()
        return [bpy.data.objects[n] for n in names if n in bpy.data.objects] or selected_armatures(context)

    def _read_take(self, context) -> session.RecordingTake:
        return session.scene_take(context.scene, context.scene.bodycal_retarget.one_euro(), user=user_model(context))

    def _armatures(self, context) -> list:
        armatures = self._avatars(context)
        for arm in armatures:  # the bake starts from each armature as it was, and keeps its new action
            live.stop_following(arm.name)
        return armatures

    def _method(self, context) -> str:
        return _settings(context).method

    def _own_settings(self, context):
        return _settings(context)


CLASSES = (BODYCAL_PG_live_settings, BODYCAL_OT_connect_live, BODYCAL_OT_disconnect_live, BODYCAL_OT_follow_live,
           BODYCAL_OT_stop_following, BODYCAL_OT_record_take, BODYCAL_OT_stop_recording, BODYCAL_OT_start_wizard,
           BODYCAL_OT_begin_step, BODYCAL_OT_end_step, BODYCAL_OT_skip_step, BODYCAL_OT_redo_step, BODYCAL_OT_bake_take)


def register_properties():
    bpy.types.Scene.bodycal_live = bpy.props.PointerProperty(
        type=BODYCAL_PG_live_settings, description="BodyCal: the Live panel's settings")


def unregister_properties():
    del bpy.types.Scene.bodycal_live


def register_handlers():
    live.register_handlers()


def unregister_handlers():
    live.unregister_handlers()
