"""The sidebar and its conventions as animators expect them (docs/SIDEBAR.md): tooltips, add-on
preferences, bake presets, the File > Export entry, the sample buttons, the long-running
operators' progress, Esc and viewport navigation, the panels' order and layout."""

import importlib

import bpy

EXTENSION = "bl_ext.user_default.bodycal"


def _ours(cls) -> bool:
    return cls.__module__.startswith(EXTENSION + ".") or cls.__module__ == EXTENSION


def _subclasses(base) -> list:
    out, todo = [], list(base.__subclasses__())
    while todo:
        cls = todo.pop()
        todo.extend(cls.__subclasses__())
        if _ours(cls) and cls.is_registered:
            out.append(cls)
    return out


def _properties(rna) -> list:
    return [p for p in rna.properties if p.identifier != "rna_type" and not p.is_hidden]


def _described_things():
    """(what, description) of every tooltip the extension shows: each operator, panel and menu,
    each property of theirs and of its property groups, each static enum item, and the
    properties it adds to Blender's own types."""
    for name in dir(bpy.ops.bodycal):
        if name.startswith("_"):
            continue
        rna = getattr(bpy.ops.bodycal, name).get_rna_type()
        yield f"bodycal.{name}", rna.description
        for prop in _properties(rna):
            yield f"bodycal.{name}.{prop.identifier}", prop.description
            for item in getattr(prop, "enum_items", ()):
                yield f"bodycal.{name}.{prop.identifier}:{item.identifier}", item.description
    for base in (bpy.types.Panel, bpy.types.Menu):
        for cls in _subclasses(base):
            yield cls.__name__, cls.bl_description if "bl_description" in cls.__dict__ else (cls.__doc__ or "")
    for base in (bpy.types.PropertyGroup, bpy.types.AddonPreferences):
        for cls in _subclasses(base):
            for prop in _properties(cls.bl_rna):
                if prop.identifier == "name" and base is bpy.types.PropertyGroup:
                    continue  # Blender's own, every property group has it
                yield f"{cls.__name__}.{prop.identifier}", prop.description
                for item in getattr(prop, "enum_items", ()):
                    yield f"{cls.__name__}.{prop.identifier}:{item.identifier}", item.description
    for owner in (bpy.types.Scene, bpy.types.WindowManager, bpy.types.Object):
        for prop in owner.bl_rna.properties:
            if prop.identifier.startswith("bodycal"):
                yield f"{owner.__name__}.{prop.identifier}", prop.description


def test_every_tooltip_is_one_line_and_every_property_is_described():
    """Blender shows an operator's docstring as its tooltip as written: a docstring wrapped over
    lines showed its newline and the next line's indent. And a property without a description
    has a tooltip that only repeats its name."""
    things = list(_described_things())
    assert len(things) > 100  # the operators, panels and settings were all found
    multi = [what for what, text in things if "\n" in text or "  " in text]
    bare = [what for what, text in things if not text.strip()]
    assert not multi and not bare, (len(things), multi, bare)


def _module(name):
    return importlib.import_module(f"{EXTENSION}.{name}")
