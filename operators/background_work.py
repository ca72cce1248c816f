"""Long work in a modal operator: computed in a worker thread with a progress bar and Esc to
cancel, then finished (the bake: writing to the scene) on the main thread."""

from __future__ import annotations

import threading

from ..bodycal_addon.core.errors import Cancelled
from .reporting import reports_errors


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
        context.workspace.status_text_set(f"BodyCal: {self._doing}... (Esc to cancel)")
        return {"RUNNING_MODAL"}

    def _cleanup(self, context):
        wm = context.window_manager
        wm.event_timer_remove(self._timer)
        wm.progress_end()
        context.workspace.status_text_set(None)

    @reports_errors
    def modal(self, context, event):
        if event.type == "ESC":
            self._cancel.set()
        if event.type != "TIMER":
            return {"RUNNING_MODAL"}
        context.window_manager.progress_update(int(100 * self._progress))
        if self._thread.is_alive():
            return {"RUNNING_MODAL"}
        self._cleanup(context)
        error = self._result.get("error")
        if isinstance(error, Cancelled):
            self.report({"WARNING"}, f"{self._cancelled}: nothing was written")
            return {"CANCELLED"}
        if error is not None:
            raise error  # bad input becomes one line (reports_errors); anything else is a bug
        return self._done(context, self._result["value"])
