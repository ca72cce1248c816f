"""Edits to a sample rig that tests of the Blender lane share."""

from __future__ import annotations

import bpy


def constrain_forearm_to_an_unkeyed_control(arm) -> None:
    """The right forearm, which the mesh follows, copies an unkeyed control bone (a control rig the
    bake does not know): a bake's keys do not move it, and the bake's check on the evaluated rig
    refuses it (blender/bake_check.py)."""
    bpy.context.view_layer.objects.active = arm
    bpy.ops.object.mode_set(mode="EDIT")
    src = arm.data.edit_bones["lowerarm_r"]
    ctrl = arm.data.edit_bones.new("ctrl_lowerarm_r")
    ctrl.head, ctrl.tail, ctrl.roll, ctrl.parent = src.head, src.tail, src.roll, src.parent
    bpy.ops.object.mode_set(mode="OBJECT")
    arm.data.bones["ctrl_lowerarm_r"].use_deform = False
    c = arm.pose.bones["lowerarm_r"].constraints.new("COPY_TRANSFORMS")
    c.target, c.subtarget = arm, "ctrl_lowerarm_r"
