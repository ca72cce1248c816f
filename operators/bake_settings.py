"""The bake settings Retarget and Bake and Transfer Animation share (issue 15's key reduction and
frame rate, issue 14's root motion and Rigify target): one set of sidebar properties, mixed into
each panel's settings group, and the BakeOptions they make."""

import math

import bpy

from ..bodycal_addon.blender.bake import BakeOptions
from ..bodycal_addon.output.keyreduce import DEFAULT_LOCATION_TOLERANCE_MM, DEFAULT_TOLERANCE_DEG

ROOT_MOTION_ITEMS = [  # retarget/root_motion.py
    ("root", "Root Bone", "The travel and heading on the rig's root bone when it has one above the pelvis "
     "(game engines' root motion); else on the pelvis"),
    ("pelvis", "Pelvis", "The travel on the pelvis; the root bone stays at rest"),
    ("in-place", "In Place", "No horizontal travel: the character stays on its spot"),
]
RIGIFY_TARGET_ITEMS = [  # retarget/rigify.py
    ("fk", "FK Controls", "A generated Rigify rig is keyed on its FK controls (IK switched to FK): ready to edit"),
    ("def", "DEF Bones", "A generated Rigify rig is keyed on its deforming DEF- bones: for export"),
]


class BakeSettings:
    """Mixed into a PropertyGroup (Blender registers annotations a base class declares: checked on
    4.2, 4.5 and 5.0). The group adds its own `output_fps`, whose 0 means the source's rate for a
    transfer and the scene's for a retarget."""

    root_motion: bpy.props.EnumProperty(name="Root Motion", items=ROOT_MOTION_ITEMS, default="root")
    rigify_target: bpy.props.EnumProperty(name="Rigify Target", items=RIGIFY_TARGET_ITEMS, default="fk")
    replace: bpy.props.BoolProperty(
        name="Replace Action", default=False,
        description="Overwrite an existing action of the same name instead of creating a new one")
    push_to_nla: bpy.props.BoolProperty(name="Push to NLA", default=False,
                                        description="Put the baked action on a new NLA track")
    tolerance: bpy.props.FloatProperty(
        name="Key Tolerance", default=math.radians(DEFAULT_TOLERANCE_DEG), min=0.0, soft_max=math.radians(2.0),
        precision=3, subtype="ANGLE",
        description="Key reduction: every bone's rotation stays within this angle of the every-frame bake "
                    "(linear keys); 0 keys every frame")
    location_tolerance: bpy.props.FloatProperty(
        name="Location Tolerance", default=DEFAULT_LOCATION_TOLERANCE_MM / 1000.0, min=0.0, soft_max=0.01,
        precision=4, subtype="DISTANCE", unit="LENGTH",
        description="Key reduction of the root bone's location: stays within this distance of the every-frame bake")
    last_result: bpy.props.StringProperty(name="Last Result", default="", options={"SKIP_SAVE"})

    def bake_options(self, context, fps: float | None) -> BakeOptions:
        """The settings as the bake takes them: degrees, and world millimetres whatever the
        scene's unit scale."""
        return BakeOptions(math.degrees(self.tolerance),
                           self.location_tolerance * 1000.0 * context.scene.unit_settings.scale_length, fps,
                           self.root_motion, self.rigify_target)


def can_bake_in(cls, context) -> bool:
    """A bake operator's first poll check: the mode the bake writes in (its poll message says so)."""
    if context.mode not in {"OBJECT", "POSE"}:
        cls.poll_message_set("Switch to Object or Pose Mode to bake")
        return False
    return True
