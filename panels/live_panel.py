"""Sidebar > BodyCal > Live: connect to a VMC stream, the devices seen, avatars following the
performer with their latency, record a take and bake it (docs/LIVE.md)."""

import bpy
import numpy as np

from ..bodycal_addon.blender import live
from .bake_rows import draw_last_result
from .conventions import draw_help, wrapped_label

STEPS_BEFORE, STEPS_AFTER = 2, 5  # the wizard's steps shown around the current one (a glove kit has ~70)


class BODYCAL_PT_live(bpy.types.Panel):
    """Live capture: the performer's VMC stream in the viewport, avatars following, takes recorded"""

    bl_idname = "BODYCAL_PT_live"
    bl_label = "Live"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "BodyCal"
    bl_parent_id = "BODYCAL_PT_main"
    bl_options = {"DEFAULT_CLOSED"}

    def draw_header_preset(self, _context):
        draw_help(self.layout, "Live")

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        settings, bake = context.scene.bodycal_live, context.scene.bodycal_bake
        session = live.session()
        col = layout.column()
        if session is None:
            col.prop(settings, "port")
            col.prop(settings, "bind")
            col.operator("bodycal.connect_live", icon="LINKED")
            return
        col.label(text=f"Listening on {settings.bind}:{live.port()}", icon="LINKED")
        wrapped_label(col, context, session.stats.line())
        if live.last_error():
            wrapped_label(col, context, live.last_error(), icon="ERROR")
        col.operator("bodycal.disconnect_live", icon="UNLINKED")
        draw_devices(layout, session)

        draw_wizard(layout, context, settings)

        col = layout.column()
        col.prop(settings, "user")
        if settings.user == "file":
            col.prop(settings, "user_file")
        col.prop(bake, "armature")
        col.prop(settings, "method")
        col.prop(bake, "plant_feet")
        col.prop(bake, "root_motion")
        col.prop(settings, "use_workers")
        draw_followers(layout, context, session)

        col = layout.column()
        col.prop(settings, "folder")
        col.prop(settings, "take_name")
        col.prop(settings, "step_markers")
        recorder = live.recording()
        if recorder is None:
            col.operator("bodycal.record_take", icon="REC")
        else:
            col.label(text=f"Recording: {recorder.frames} frames, {recorder.duration:.1f} s", icon="REC")
            col.operator("bodycal.stop_recording", icon="SNAP_FACE")
        col.operator("bodycal.bake_take", icon="ACTION")
        draw_last_result(layout, settings, context)


def draw_wizard(layout, context, settings) -> None:
    """The calibration wizard: its steps with the current one, the instruction to read aloud, the
    step's progress, Begin / End / Skip / Redo."""
    header, body = layout.panel("BODYCAL_live_wizard", default_closed=False)
    header.label(text="Calibration Wizard")
    if body is None:
        return
    wizard = live.wizard()
    if wizard is None:
        body.prop(settings, "wizard_pause")
        body.operator("bodycal.start_wizard", icon="OUTLINER_OB_ARMATURE")
        return
    steps = body.column(align=True)
    first, last = max(0, wizard.index - STEPS_BEFORE), min(len(wizard.steps), wizard.index + STEPS_AFTER + 1)
    if first:
        steps.label(text=f"{first} steps before", icon="BLANK1")
    for k, step in zip(range(first, last), wizard.steps[first:last], strict=True):
        done = wizard.completed.get(k)
        icon = ("CHECKMARK" if done in {"auto", "ended"} else "FORWARD" if done == "skipped"
                else "REC" if k == wizard.index and wizard.active else "RIGHTARROW" if k == wizard.index
                else "BLANK1")
        row = steps.row()
        row.active = k >= wizard.index
        row.label(text=f"{k + 1}. {step.title}", icon=icon)
    if last < len(wizard.steps):
        steps.label(text=f"{len(wizard.steps) - last} steps after", icon="BLANK1")
    step = wizard.current
    if step is None:
        wrapped_label(body, context, wizard.status_line(), icon="CHECKMARK")
        return
    box = body.box()
    wrapped_label(box, context, step.instruction, icon="INFO")
    progress = wizard.progress
    if wizard.active:
        box.progress(factor=progress.fraction if progress else 0.0,
                     text=progress.figure if progress else "recording")
    row = body.row(align=True)
    row.operator("bodycal.begin_step", icon="PLAY")
    row.operator("bodycal.end_step", icon="CHECKMARK")
    row.operator("bodycal.skip_step", icon="FORWARD")
    row.operator("bodycal.redo_step", icon="LOOP_BACK")


def draw_devices(layout, session) -> None:
    """One row per device: name, kind, role, rate, frames missed since it was first seen."""
    devices = session.devices()
    box = layout.box()
    if not devices:
        box.label(text="No device yet: is the sender sending to this port?", icon="INFO")
        return
    for d in devices:
        row = box.row(align=True)
        row.label(text=d.name, icon="OBJECT_DATA" if d.role else "QUESTION")
        row.label(text=f"{d.kind}, {d.role or 'no role'}")
        row.label(text=f"{d.rate_hz:.0f} Hz, {d.missed} missed")


def draw_followers(layout, context, session) -> None:
    following = live.following()
    col = layout.column()
    if not following:
        col.operator("bodycal.follow_live", icon="ARMATURE_DATA")
        return
    box = col.box()
    for name, f in following.items():
        follower = session.followers.get(name)
        if follower is None:
            continue
        if follower.note:  # a worker process that ended: it solves here now
            wrapped_label(box, context, follower.note, icon="ERROR")
        state = follower.state
        if state == "starting":
            wrapped_label(box, context, f"{name}: starting its worker process", icon="TIME")
            continue
        if state == "waiting":
            wrapped_label(box, context, f"{name}: waiting for devices with the roles "
                                        f"{', '.join(follower.waiting_for)}", icon="TIME")
            continue
        if state == "preparing":
            wrapped_label(box, context, f"{name}: preparing its solver in its worker process", icon="TIME")
            continue
        write = f" write {np.median(f.write_ms):.2f} ms," if f.write_ms else ""
        where = " (worker process)" if follower.in_worker else ""
        if getattr(follower, "kernels", "") == "numpy":  # a worker without mathutils: several times slower
            where = " (worker process, numpy kernels: no mathutils there)"
        wrapped_label(box, context, f"{name}{where}:{write} {follower.stats.line()}", icon="ARMATURE_DATA")
    row = col.row(align=True)
    row.operator("bodycal.follow_live", text="Follow Again", icon="FILE_REFRESH")
    row.operator("bodycal.stop_following", icon="PAUSE")


CLASSES = (BODYCAL_PT_live,)
