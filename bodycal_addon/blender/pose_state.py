"""An armature as it was, to put back exactly: every pose bone's rotation mode and values (all three
rotation kinds, location, scale) and its numeric custom properties (a Rigify rig's IK/FK
switches), and what animates it (the action, its slot on Blender 4.4+, and
whether the NLA is evaluated). Used by the live follow (live.py), which sets pose values the
action would otherwise overwrite on the next frame change (DESIGN.md "Live session in Blender"),
and by the timeline preview (preview.py), which puts back the pose only.

Modes are put back before the values: setting `rotation_mode` converts the current rotation into
the new kind, so the saved values of every kind are written once the mode is back."""

from __future__ import annotations

import contextlib
from dataclasses import dataclass

import bpy
import numpy as np

_CHANNELS = (("rotation_quaternion", 4), ("rotation_euler", 3), ("rotation_axis_angle", 4), ("location", 3),
             ("scale", 3))


@dataclass
class PoseState:
    bones: list[str]
    modes: list[str]
    values: dict[str, np.ndarray]  # channel -> (n * width,) float32, the pose bones' order
    had_animation_data: bool
    action: str | None  # the action's name: an undo replaces every datablock, a name finds it again
    slot: str | None  # its slot's identifier (Blender 4.4+)
    use_nla: bool
    props: dict  # (pose bone, custom property) -> its number (a Rigify rig's IK_FK switches, ...)

    @classmethod
    def capture(cls, arm) -> PoseState:
        bones = arm.pose.bones
        values = {}
        for name, width in _CHANNELS:
            buf = np.empty(len(bones) * width, np.float32)
            bones.foreach_get(name, buf)
            values[name] = buf
        ad = arm.animation_data
        props = {(pb.name, key): pb[key] for pb in bones for key in pb.keys()
                 if isinstance(pb[key], (int, float)) and not isinstance(pb[key], bool)}
        action = ad.action if ad else None
        slot = getattr(ad, "action_slot", None) if ad else None
        return cls([pb.name for pb in bones], [pb.rotation_mode for pb in bones], values, ad is not None,
                   action.name if action else None, slot.identifier if slot else None,
                   bool(ad.use_nla) if ad else True, props)

    def detach(self, arm) -> None:
        """Nothing animates the armature while its pose is set from outside: no action, no NLA."""
        ad = arm.animation_data
        if ad is not None:
            ad.action = None
            ad.use_nla = False

    def restore(self, arm) -> None:
        """The armature exactly as captured: what animates it and its pose."""
        self.restore_animation(arm)
        self.restore_pose(arm)

    def restore_animation(self, arm) -> None:
        ad = arm.animation_data
        if ad is None and self.had_animation_data:
            ad = arm.animation_data_create()
        if ad is not None:
            action = bpy.data.actions.get(self.action) if self.action else None
            if ad.action != action:
                ad.action = action
            slot = getattr(ad, "action_slot", None)
            if action is not None and self.slot is not None and (slot is None or slot.identifier != self.slot):
                with contextlib.suppress(AttributeError, TypeError, RuntimeError, KeyError):
                    ad.action_slot = action.slots[self.slot]
            ad.use_nla = self.use_nla
            if not self.had_animation_data:
                arm.animation_data_clear()

    def restore_pose(self, arm) -> None:
        """The pose bones' modes and values as captured (bones added since are left alone)."""
        bones = arm.pose.bones
        if [pb.name for pb in bones] == self.bones:
            for pb, mode in zip(bones, self.modes, strict=True):
                if pb.rotation_mode != mode:
                    pb.rotation_mode = mode
            for name, _width in _CHANNELS:
                bones.foreach_set(name, self.values[name])
        else:  # bones renamed, added or removed meanwhile: by name, what is still there
            index = {n: i for i, n in enumerate(self.bones)}
            for pb in bones:
                i = index.get(pb.name)
                if i is None:
                    continue
                pb.rotation_mode = self.modes[i]
                for name, width in _CHANNELS:
                    setattr(pb, name, self.values[name][i * width:(i + 1) * width].tolist())
        for (bone, key), value in self.props.items():
            pb = bones.get(bone)
            if pb is not None and pb.get(key) != value:
                pb[key] = value
        arm.update_tag(refresh={"DATA"})
