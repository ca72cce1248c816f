"""Avatar operators (DESIGN.md §4): bone map, surface calibration, authoring, import/export."""

import bpy
from bpy_extras.io_utils import ExportHelper, ImportHelper

from ..bodycal_addon.blender import (
    avatar_calibration,
    avatar_rig,
    avatar_storage,
    blendfile,
    surface_helpers,
)
from .background_work import BackgroundWork
from .preferences import StartsInFolder
from .reporting import reports_errors


def context_armature(context):
    """The armature the avatar operators act on: the active armature, the armature deforming the
    active mesh, or the armature whose surface helper is active."""
    obj = context.active_object
    if obj is None:
        return None
    if obj.type == "ARMATURE":
        return obj
    if obj.type == "MESH":
        for m in obj.modifiers:
            if m.type == "ARMATURE" and m.object is not None:
                return m.object
        if obj.parent is not None and obj.parent.type == "ARMATURE":
            return obj.parent
    name = obj.get(surface_helpers.ARMATURE_PROP)
    if name:
        arm = bpy.data.objects.get(name)
        if arm is not None and arm.type == "ARMATURE":
            return arm
    return None


def poll_armature(cls, context, need_model=False, object_mode=True):
    arm = context_armature(context)
    if arm is None:
        cls.poll_message_set("Select the avatar's armature (or its mesh)")
        return False
    if object_mode and context.mode != "OBJECT":
        cls.poll_message_set("Switch to Object Mode first")
        return False
    if need_model and not avatar_storage.has_model(arm):
        cls.poll_message_set(f"{arm.name} has no avatar model yet: run Calibrate Avatar")
        return False
    return True


class BODYCAL_OT_detect_bone_map(bpy.types.Operator):
    """Map the armature's bones to the canonical skeleton from their names (Unreal, Rigify,
    Mixamo, VRM / Unity, VRoid, MakeHuman, Daz, Character Creator); your manual assignments and
    applied presets are kept unless Reset is on"""

    bl_idname = "bodycal.detect_bone_map"
    bl_label = "Detect Bone Map"
    bl_options = {"REGISTER", "UNDO"}

    reset: bpy.props.BoolProperty(name="Reset", default=False, description="Forget manual assignments")

    @classmethod
    def poll(cls, context):
        return poll_armature(cls, context, object_mode=False)

    @reports_errors
    def execute(self, context):
        arm = context_armature(context)
        dropped = False
        if self.reset:
            bm, dropped = avatar_rig.reset_to_detected(arm)
        else:
            bm = avatar_rig.bone_map_for(arm)
        missing = bm.missing()
        mapped = len(bm.bones) + sum(1 for c in bm.chains.values() if c)
        if dropped:
            self.report({"WARNING"}, f"{arm.name}: {avatar_rig.MODEL_DROPPED}")
        if missing:
            self.report({"WARNING"}, f"{arm.name}: {bm.scheme} names, {mapped} segments mapped; "
                        f"missing {', '.join(missing)}: assign them in the Avatar panel")
        else:
            self.report({"INFO"}, f"{arm.name}: {bm.scheme} names, {mapped} segments mapped, nothing missing")
        return {"FINISHED"}


class BODYCAL_OT_assign_bone(bpy.types.Operator):
    """Map a body segment to a bone of the armature (the active bone unless a name is given);
    saved with the armature"""

    bl_idname = "bodycal.assign_bone"
    bl_label = "Assign Bone"
    bl_options = {"REGISTER", "UNDO"}

    segment: bpy.props.StringProperty(name="Segment",
                                      description="The canonical body segment to map (upperarm_l, spine...)")
    bone: bpy.props.StringProperty(name="Bone", description="Bone name (spine/neck: comma-separated, bottom-up); "
                                   "empty = the active bone")

    @classmethod
    def poll(cls, context):
        return poll_armature(cls, context, object_mode=False)

    @reports_errors
    def execute(self, context):
        arm = context_armature(context)
        bone = self.bone or (arm.data.bones.active.name if arm.data.bones.active else "")
        if not bone:
            self.report({"ERROR"}, "No bone given and no active bone: select a bone in Pose Mode")
            return {"CANCELLED"}
        _bm, dropped = avatar_rig.edit_segment(arm, self.segment, bone)
        self.report({"WARNING"} if dropped else {"INFO"},
                    f"{self.segment} -> {bone}" + (f"; {avatar_rig.MODEL_DROPPED}" if dropped else ""))
        return {"FINISHED"}


_HINGE_ITEMS = [(b, b, f"Flexion axis of {b}") for b in avatar_rig.HINGE_BONES]
_AXES = {"X": (1.0, 0.0, 0.0), "-X": (-1.0, 0.0, 0.0), "Z": (0.0, 0.0, 1.0), "-Z": (0.0, 0.0, -1.0)}


class BODYCAL_OT_set_hinge_axis(bpy.types.Operator):
    """Choose which local axis of the avatar's bone its hinge flexes about (default +X, Blender's
    convention); saved with the armature, used at the next calibration"""

    bl_idname = "bodycal.set_hinge_axis"
    bl_label = "Set Hinge Axis"
    bl_options = {"REGISTER", "UNDO"}

    bone: bpy.props.EnumProperty(name="Hinge", items=_HINGE_ITEMS,
                                 description="The hinge joint's bone (elbow: forearm, knee: shin)")
    axis: bpy.props.EnumProperty(name="Axis", items=[(k, k, f"The bone's local {k}") for k in _AXES], default="X",
                                description="The local axis of the avatar's bone the hinge flexes about")

    @classmethod
    def poll(cls, context):
        return poll_armature(cls, context, object_mode=False)

    @reports_errors
    def invoke(self, context, event):
        return context.window_manager.invoke_props_dialog(self)

    @reports_errors
    def execute(self, context):
        arm = context_armature(context)
        avatar_rig.set_hinge_axis(arm, self.bone, _AXES[self.axis])
        self.report({"INFO"}, f"{self.bone} flexes about its bone's local {self.axis}: calibrate again to apply")
        return {"FINISHED"}


class BODYCAL_OT_calibrate_avatar(BackgroundWork, bpy.types.Operator):
    """Measure the avatar's surface by raycasting onto its mesh (capsules, torso, jaw, skull,
    palms, soles) and store the body model on the armature"""

    _doing, _cancelled = "calibrating the avatar", "Avatar calibration cancelled"
    bl_idname = "bodycal.calibrate_avatar"
    bl_label = "Calibrate Avatar"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return poll_armature(cls, context)

    def _survey(self, context):
        """The armature, its rig and its meshes' BVH trees, read on the main thread."""
        arm = context_armature(context)
        return arm, *avatar_calibration.prepare_survey(arm, depsgraph=context.evaluated_depsgraph_get())

    @reports_errors
    def execute(self, context):
        arm, rig, caster = self._survey(context)
        return self._store(arm, avatar_calibration.measure(rig, caster, arm.name))

    @reports_errors
    def invoke(self, context, _event):
        """The rays in a worker thread: the progress in the status bar, Esc cancels."""
        arm, rig, caster = self._survey(context)
        self._arm = arm
        return self._start(context, lambda progress, cancel: avatar_calibration.measure(
            rig, caster, arm.name, progress=progress, cancel=cancel))

    def _done(self, _context, model):
        return self._store(self._arm, model)

    def _store(self, arm, model):
        avatar_storage.store_model(arm, model)
        summary, warnings = avatar_calibration.calibration_report(arm.name, model)
        self.report({"INFO"}, summary)
        for line in warnings:
            self.report({"WARNING"}, line)
        return {"FINISHED"}


class BODYCAL_OT_edit_surface(bpy.types.Operator):
    """Show every surface point and element of the stored avatar model as helper empties you
    can move (points, skull) and scale (capsule ends, skull)"""

    bl_idname = "bodycal.edit_surface"
    bl_label = "Edit Surface"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        return poll_armature(cls, context, need_model=True)

    @reports_errors
    def execute(self, context):
        arm = context_armature(context)
        coll = surface_helpers.edit_surface(arm, context)
        self.report({"INFO"}, f"{len(coll.objects)} helpers in '{coll.name}': move or scale them, then Apply Edits")
        return {"FINISHED"}


class BODYCAL_OT_apply_surface_edits(bpy.types.Operator):
    """Read the surface helpers back into the avatar model stored on the armature"""

    bl_idname = "bodycal.apply_surface_edits"
    bl_label = "Apply Surface Edits"
    bl_options = {"REGISTER", "UNDO"}

    remove_helpers: bpy.props.BoolProperty(name="Remove Helpers", default=False,
                                           description="Delete the helper empties once read")

    @classmethod
    def poll(cls, context):
        if not poll_armature(cls, context, need_model=True):
            return False
        if surface_helpers.helper_collection(context_armature(context)) is None:
            cls.poll_message_set("No surface helpers: press Edit Surface first")
            return False
        return True

    @reports_errors
    def execute(self, context):
        arm = context_armature(context)
        changed = surface_helpers.apply_surface_edits(arm, remove=self.remove_helpers)
        self.report({"INFO"}, f"{arm.name}: {len(changed)} elements changed"
                    + (f" ({', '.join(changed[:6])}{', ...' if len(changed) > 6 else ''})" if changed else ""))
        return {"FINISHED"}


class BODYCAL_OT_export_avatar_model(StartsInFolder, bpy.types.Operator, ExportHelper):
    """Write the avatar body model stored on the armature as a *.body.json file"""

    bl_idname = "bodycal.export_avatar_model"
    bl_label = "Export Avatar Model"
    bl_options = {"REGISTER"}
    _folder = "avatars_folder"

    filename_ext = ".json"
    filter_glob: bpy.props.StringProperty(default="*.json", options={"HIDDEN"})

    @classmethod
    def poll(cls, context):
        return poll_armature(cls, context, need_model=True, object_mode=False)

    @reports_errors
    def invoke(self, context, event):
        self.filepath = bpy.path.clean_name(context_armature(context).name) + ".body.json"
        return super().invoke(context, event)

    @reports_errors
    def execute(self, context):
        arm = context_armature(context)
        path = avatar_storage.load_model(arm).save(self.filepath)
        self.report({"INFO"}, f"Wrote {path}")
        return {"FINISHED"}


class BODYCAL_OT_import_avatar_model(StartsInFolder, bpy.types.Operator, ImportHelper):
    """Read a *.body.json avatar model (an authored configuration) onto the active armature"""

    bl_idname = "bodycal.import_avatar_model"
    bl_label = "Import Avatar Model"
    bl_options = {"REGISTER", "UNDO"}
    _folder = "avatars_folder"

    filename_ext = ".json"
    filter_glob: bpy.props.StringProperty(default="*.json", options={"HIDDEN"})

    @classmethod
    def poll(cls, context):
        return poll_armature(cls, context, object_mode=False)

    @reports_errors
    def execute(self, context):
        arm = context_armature(context)
        model = avatar_storage.load_model_file(arm, self.filepath)
        rig_name = model.extra.get("rig", {}).get("armature")
        if rig_name and rig_name != arm.name:
            self.report({"WARNING"}, f"Stored on {arm.name}; the model was calibrated on '{rig_name}'")
        else:
            self.report({"INFO"}, f"Stored the avatar model on {arm.name}")
        return {"FINISHED"}


class BODYCAL_OT_import_avatar(StartsInFolder, bpy.types.Operator, ImportHelper):
    """Import an avatar (.fbx, .glb, .gltf, or .vrm with a VRM importer add-on) with Blender's own
    importer and make its armature the active object; a .blend avatar is opened or appended as
    usual (File > Open, File > Append)"""

    bl_idname = "bodycal.import_avatar"
    bl_label = "Import Avatar"
    bl_options = {"REGISTER", "UNDO"}
    _folder = "avatars_folder"

    filter_glob: bpy.props.StringProperty(default="*.fbx;*.glb;*.gltf;*.vrm", options={"HIDDEN"})

    @classmethod
    def poll(cls, context):
        if context.mode != "OBJECT":
            cls.poll_message_set("Switch to Object Mode to import an avatar")
            return False
        return True

    @reports_errors
    def execute(self, context):
        notes = []
        try:
            new, avatars = blendfile.import_avatars(self.filepath, notes)
        finally:
            for note in notes:
                self.report({"WARNING"}, note)
        for obj in context.selected_objects:
            obj.select_set(False)
        for arm in avatars:
            arm.select_set(True)
        context.view_layer.objects.active = avatars[0]
        others = f"; also {', '.join(a.name for a in avatars[1:])}" if len(avatars) > 1 else ""
        self.report({"INFO"}, f"Imported {avatars[0].name} ({len(new)} objects){others}: "
                    f"check its bone map, then Calibrate Avatar")
        return {"FINISHED"}


CLASSES = (BODYCAL_OT_import_avatar, BODYCAL_OT_detect_bone_map, BODYCAL_OT_assign_bone, BODYCAL_OT_set_hinge_axis,
           BODYCAL_OT_calibrate_avatar, BODYCAL_OT_edit_surface, BODYCAL_OT_apply_surface_edits,
           BODYCAL_OT_export_avatar_model, BODYCAL_OT_import_avatar_model)
