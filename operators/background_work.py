"""Long work in a modal operator: computed in a worker thread with a progress bar and Esc to
cancel, then finished (the bake: writing to the scene) on the main thread."""

from __future__ import annotations

import threading

from ..bodycal_addon.blender import Cancelled
from .reporting import reports_errors

# What a running job lets through: looking around the viewport (orbit, pan, zoom, the view keys,
# trackpad and NDOF) and Blender's own timers. Anything else (selecting, editing, undo, another
# bake) waits until the job has finished: it writes onto the objects it read when it started.
NAVIGATION_EVENTS = frozenset({
    "MOUSEMOVE", "INBETWEEN_MOUSEMOVE", "MIDDLEMOUSE", "WHEELUPMOUSE", "WHEELDOWNMOUSE", "WHEELINMOUSE",
    "WHEELOUTMOUSE", "TRACKPADPAN", "TRACKPADZOOM", "MOUSEROTATE", "MOUSESMARTZOOM", "HOME",
    *(f"NUMPAD_{k}" for k in (*"0123456789", "PERIOD", "SLASH", "ASTERIX", "PLUS", "MINUS")),
})


def passes_through(context, event) -> bool:
    kind = event.type
    if kind in NAVIGATION_EVENTS or kind.startswith(("NDOF_", "TIMER")):
        return True
    # Alt + left button orbits with Emulate 3 Button Mouse (Preferences > Input).
    return kind == "LEFTMOUSE" and event.alt and context.preferences.inputs.use_mouse_emulate_3_button


class BackgroundWork:
    """Mixin for an operator whose `invoke` calls `self._start(context, work)`. `work(progress,
    cancel)` runs in the worker (progress(f) with f in [0, 1]; it raises Cancelled when cancel()
    turns true); `self._done(context, result)` then runs on the main thread and returns the
    operator's result. `_doing` names the work in the status bar ("retargeting"), `_cancelled` the
    warning when Esc stopped it."""

    _doing = "working"
    _cancelled = "Cancelled"

    def _start(self, context, work):
        self._progress = 0.0
        self._cancel = threading.Event()
        self._result = {}

        def run():
            try:
                self._result["value"] = work(lambda f: setattr(self, "_progress", f), self._cancel.is_set)
            except BaseException as exc:  # reported on the main thread
                self._result["error"] = exc

        self._thread = threading.Thread(target=run, name=f"bodycal-{self._doing}", daemon=True)
        self._thread.start()
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.1, window=context.window)
        wm.progress_begin(0, 100)
        wm.modal_handler_add(self)
        self._show_progress(context)
        return {"RUNNING_MODAL"}

    def _show_progress(self, context):
        percent = int(100 * self._progress)
        context.window_manager.progress_update(percent)
        context.workspace.status_text_set(f"BodyCal: {self._doing}... {percent}% (Esc to cancel)"
                                          if not self._cancel.is_set() else f"BodyCal: cancelling {self._doing}...")

    def _cleanup(self, context):
        wm = context.window_manager
        wm.event_timer_remove(self._timer)
        wm.progress_end()
        context.workspace.status_text_set(None)

    @reports_errors
    def modal(self, context, event):
        if event.type == "ESC":
            self._cancel.set()
            return {"RUNNING_MODAL"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"} if passes_through(context, event) else {"RUNNING_MODAL"}
        self._show_progress(context)
        if self._thread.is_alive():
            return {"PASS_THROUGH"}  # another handler's timer may be the one that fired
        self._cleanup(context)
        error = self._result.get("error")
        if isinstance(error, Cancelled):
            self.report({"WARNING"}, f"{self._cancelled}: nothing was written")
            return {"CANCELLED"}
        if error is not None:
            raise error  # bad input becomes one line (reports_errors); anything else is a bug
        return self._done(context, self._result["value"])
