"""Rigify's generated rig (issue 14): placeholder, filled in below."""

RIGIFY_TARGETS = ("fk", "def")  # the default first


def check_rigify_target(target: str) -> str:
    from ..errors import BodyCalError

    if target not in RIGIFY_TARGETS:
        raise BodyCalError(f"unknown Rigify target '{target}'", field="rigify_target",
                           hint=f"use one of {', '.join(RIGIFY_TARGETS)}")
    return target
