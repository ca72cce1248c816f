"""The one place where an operator's failure becomes a line in the status bar."""

from __future__ import annotations

import functools

from ..bodycal_addon.blender import BodyCalError, describe_os_error


def error_line(exc: BaseException) -> str:
    """One line for the user: a BodyCalError's own, or the file and reason of an OSError."""
    if isinstance(exc, BodyCalError):
        return exc.line()
    if isinstance(exc, OSError):
        return " ".join(describe_os_error(exc, advice=False).split())
    return " ".join(str(exc).split())


def reports_errors(method):
    """Wrap an operator's execute / invoke / modal: bad input (BodyCalError) or a file that cannot
    be read or written (OSError) is reported as one ERROR line and the operator is CANCELLED, so
    nothing half-done is kept; anything else is a bug and propagates with its traceback.
    The wrapper keeps the method's arity: Blender checks it when it registers the class."""

    def run(self, context, *event):
        try:
            return method(self, context, *event)
        except (BodyCalError, OSError) as exc:
            self.report({"ERROR"}, error_line(exc))
            return {"CANCELLED"}

    if method.__code__.co_argcount == 3:  # invoke / modal (self, context, event)
        def wrapper(self, context, event):
            return run(self, context, event)
    else:  # execute (self, context)
        def wrapper(self, context):
            return run(self, context)
    return functools.wraps(method)(wrapper)
