"""The retargeting methods (DESIGN.md §1), one registry that the command line, batch jobs and the
sidebar all read: the method's name, how the sidebar shows it, and which pose sources it takes.

A pose source is a tracker recording of a calibrated performer ("recording") or another
character's animation ("animation"). Exact Offsets (AvatarGo §3.3) needs the trackers' own poses
and their T-pose offsets, so it takes recordings only.
"""

from __future__ import annotations

from dataclasses import dataclass

from ..core.errors import BodyCalError

SOURCE_KINDS = ("recording", "animation")


@dataclass(frozen=True)
class MethodInfo:
    name: str
    label: str
    description: str
    sources: tuple[str, ...]  # the pose source kinds it takes


REGISTRY: tuple[MethodInfo, ...] = (  # the default first
    MethodInfo("egocentric", "Egocentric",
               "Keep self-contacts: egocentric mapping onto the avatar's surface + IK", SOURCE_KINDS),
    MethodInfo("offsets", "Exact Offsets",
               "AvatarGo: exact tracker-to-joint offsets from the T-pose + IK", ("recording",)),
    MethodInfo("rotations", "Rotation Copy",
               "Copy the performer's bone rotations (the usual retargeting baseline)", SOURCE_KINDS),
)
METHOD_INFO = {m.name: m for m in REGISTRY}


def methods_for(source_kind: str) -> tuple[str, ...]:
    """The methods a pose source of this kind can be retargeted with, the default first."""
    return tuple(m.name for m in REGISTRY if source_kind in m.sources)


def check_method(method: str, source_kind: str = "recording") -> str:
    """`method` when a source of `source_kind` can use it; else one BodyCalError saying which can."""
    allowed = methods_for(source_kind)
    if method not in allowed:
        what = "transfer method" if source_kind == "animation" else "method"
        raise BodyCalError(f"unknown {what} '{method}'", field="method", hint=f"use one of {', '.join(allowed)}")
    return method
