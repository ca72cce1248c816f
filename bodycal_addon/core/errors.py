"""The one error type users see: a clear line naming what is wrong and what to do."""

from __future__ import annotations


class BodyCalError(Exception):
    """Bad input or an impossible request. Its message is shown to the user as one line.

    `source` is the file (or object) at fault, `field` the field or column, `where` the frame or
    line; each is optional and, when given, prefixed to the message in that order.
    """

    def __init__(self, message: str, *, source: str | None = None, field: str | None = None,
                 where: str | None = None, hint: str | None = None):
        self.message = message
        self.source = source
        self.field = field
        self.where = where
        self.hint = hint
        super().__init__(self.line())

    def line(self) -> str:
        parts = [p for p in (self.source, self.field, self.where) if p]
        prefix = ": ".join(parts)
        text = f"{prefix}: {self.message}" if prefix else self.message
        if self.hint:
            text += f" ({self.hint})"
        return " ".join(text.split())  # always one line


def short_repr(v) -> str:
    """`repr(v)`, cut to 40 characters: a damaged value quoted in a one-line message."""
    s = repr(v)
    return s if len(s) <= 40 else s[:37] + "..."


class Cancelled(Exception):
    """The user pressed Esc during long work; nothing was written."""
