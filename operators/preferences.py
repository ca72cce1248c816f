"""BodyCal's add-on preferences (Edit > Preferences > Add-ons > BodyCal): the folders the file
browsers open in, and the method a scene's Retarget and Bake starts with until one is picked
there. The command line reads none of them: its inputs and outputs are all on the line."""

import os

import bpy

from ..bodycal_addon.blender import session
from .bake_settings import method_items

# Blender keys an add-on's preferences by its root package: "bl_ext.<repository>.bodycal" for an
# extension (this module is <that>.operators.preferences).
PACKAGE = __package__.rpartition(".")[0]
DEFAULT_METHOD = "egocentric"


class BODYCAL_AP_preferences(bpy.types.AddonPreferences):
    """BodyCal's preferences: default folders and method"""

    bl_idname = PACKAGE

    recordings_folder: bpy.props.StringProperty(
        name="Recordings", subtype="DIR_PATH",
        description="Where Import Recording and the user body model's Save and Load open (empty: Blender's "
                    "last folder)")
    avatars_folder: bpy.props.StringProperty(
        name="Avatars", subtype="DIR_PATH",
        description="Where Import Avatar and the avatar model's Export and Import open (empty: Blender's last "
                    "folder)")
    export_folder: bpy.props.StringProperty(
        name="Exports", subtype="DIR_PATH",
        description="Where Export Baked Avatar writes by default (empty: beside the .blend file)")
    default_method: bpy.props.EnumProperty(
        name="Default Method", items=method_items(session.RECORDING), default=DEFAULT_METHOD,
        description="The method Retarget and Bake (and Transfer, when it offers it) starts with in a scene "
                    "where none was picked yet")

    def draw(self, _context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        col = layout.column(heading="Folders")
        col.prop(self, "recordings_folder")
        col.prop(self, "avatars_folder")
        col.prop(self, "export_folder")
        layout.prop(self, "default_method")


def preferences(context=None):
    """BodyCal's add-on preferences; None when it is not enabled as an add-on (a script that
    imports its modules)."""
    addon = (context or bpy.context).preferences.addons.get(PACKAGE)
    return addon.preferences if addon is not None else None


def folder(context, name: str) -> str:
    """The absolute folder the preference `name` names when it is set and exists, else ""."""
    prefs = preferences(context)
    path = bpy.path.abspath(getattr(prefs, name, "")) if prefs is not None else ""
    return path if path and os.path.isdir(path) else ""


def method_property(items: list, label: str, description: str):
    """A method menu for a scene's settings group whose value, until the user picks one in that
    scene, is the preferences' Default Method (when `items` offer it). It is stored under its own
    name, as a plain enum property would be, so a file saved before keeps its pick."""
    names = [item[0] for item in items]

    def get(self):
        stored = self.get("method")
        if stored is not None:
            return stored
        prefs = preferences()
        wanted = prefs.default_method if prefs is not None else DEFAULT_METHOD
        return names.index(wanted) if wanted in names else names.index(DEFAULT_METHOD)

    def set_(self, value):
        self["method"] = value

    return bpy.props.EnumProperty(name=label, items=items, get=get, set=set_, description=description)


class StartsInFolder:
    """Mixin for an import or export operator (before `ImportHelper` / `ExportHelper` in its bases):
    its file browser opens in the folder the preference `_folder` names, when set. An export
    suggests `_suggested_name(context)` there."""

    _folder = ""

    def _suggested_name(self, _context) -> str:
        return ""

    def invoke(self, context, event):
        start = folder(context, self._folder)
        if start and not os.path.dirname(self.filepath):
            self.filepath = os.path.join(start, self.filepath or self._suggested_name(context))
        return super().invoke(context, event)


CLASSES = (BODYCAL_AP_preferences,)
