"""How the extension's classes are registered: every tooltip on one line."""

import bpy


def one_line(text: str) -> str:
    return " ".join(text.split())


def one_line_tooltips(classes) -> None:
    """Blender shows an operator's, panel's or menu's docstring as its tooltip as written: a
    docstring wrapped over lines showed its newline and the next line's indent. Each class without
    a `bl_description` of its own gets its docstring on one line as one."""
    for cls in classes:
        if "bl_description" not in cls.__dict__ and cls.__doc__ and "bl_description" in cls.bl_rna.properties:
            cls.bl_description = one_line(cls.__doc__)


def register_classes_factory(classes):
    """`bpy.utils.register_classes_factory`, with one-line tooltips."""
    register, unregister = bpy.utils.register_classes_factory(classes)

    def register_one_line():
        one_line_tooltips(classes)
        register()

    return register_one_line, unregister
