"""The avatar body model stored on its armature object (DESIGN.md §4: "saved ... on the armature
object"): a custom property holding the `*.body.json` text, so it survives save and reload of
the .blend, travels with the armature when it is appended or linked, and is covered by undo."""

from __future__ import annotations

import json

from ..bodymodel import BodyModel
from ..errors import BodyCalError

MODEL_PROP = "bodycal_avatar_model"


def store_model(arm, model: BodyModel) -> None:
    if arm is None or getattr(arm, "type", None) != "ARMATURE":
        raise BodyCalError("the avatar model can only be stored on an armature object",
                           source=getattr(arm, "name", "object"))
    arm[MODEL_PROP] = model.to_json()


def has_model(arm) -> bool:
    return arm is not None and bool(arm.get(MODEL_PROP))


def load_model(arm) -> BodyModel:
    raw = arm.get(MODEL_PROP) if arm is not None else None
    if not raw:
        raise BodyCalError("this armature has no avatar body model yet", source=getattr(arm, "name", "armature"),
                           hint="run Calibrate Avatar first")
    try:
        data = json.loads(raw)
    except (TypeError, ValueError):
        raise BodyCalError("the stored avatar body model is damaged", source=arm.name, field=MODEL_PROP,
                           hint="calibrate the avatar again") from None
    return BodyModel.from_dict(data, source=f"{arm.name}[{MODEL_PROP}]")


def clear_model(arm) -> None:
    if arm is not None and MODEL_PROP in arm:
        del arm[MODEL_PROP]
