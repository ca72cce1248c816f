"""The avatar body model stored on its armature object (DESIGN.md §4: "saved ... on the armature
object"): a custom property holding the `*.body.json` text, so it survives save and reload of
the .blend, travels with the armature when it is appended or linked, and is covered by undo."""

from __future__ import annotations

import json

from ..body.bodymodel import BodyModel
from ..core.errors import BodyCalError

MODEL_PROP = "bodycal_avatar_model"


def store_json_model(owner, key: str, model: BodyModel) -> None:
    """Keep `model` as `*.body.json` text in a custom property of `owner` (an object or a scene):
    saved with the .blend and covered by undo."""
    owner[key] = model.to_json()


def has_json_model(owner, key: str) -> bool:
    return owner is not None and bool(owner.get(key))


def load_json_model(owner, key: str, *, what: str, redo: str) -> BodyModel:
    """The model stored by `store_json_model`; `what` names it and `redo` says how to make it."""
    raw = owner.get(key) if owner is not None else None
    name = getattr(owner, "name", "?")
    if not raw:
        raise BodyCalError(f"no {what} yet", source=name, hint=redo)
    try:
        data = json.loads(raw)
    except (TypeError, ValueError):
        raise BodyCalError(f"the stored {what} is damaged", source=name, field=key, hint=redo) from None
    return BodyModel.from_dict(data, source=f"{name}[{key}]")


def load_model_file(arm, path) -> BodyModel:
    """Read an avatar body model file (`*.body.json`) and store it on the armature `arm`."""
    model = BodyModel.load(path)
    if model.kind != "avatar":
        raise BodyCalError(f"a '{model.kind}' body model, not an avatar model", source=path, field="kind")
    store_model(arm, model)
    return model


def store_model(arm, model: BodyModel) -> None:
    if arm is None or getattr(arm, "type", None) != "ARMATURE":
        raise BodyCalError("the avatar model can only be stored on an armature object",
                           source=getattr(arm, "name", "object"))
    store_json_model(arm, MODEL_PROP, model)


def has_model(arm) -> bool:
    return has_json_model(arm, MODEL_PROP)


def load_model(arm) -> BodyModel:
    return load_json_model(arm, MODEL_PROP, what="avatar body model",
                           redo="run Calibrate Avatar first")


def clear_model(arm) -> None:
    if arm is not None and MODEL_PROP in arm:
        del arm[MODEL_PROP]
