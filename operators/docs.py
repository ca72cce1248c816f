"""The panels' help buttons: BodyCal's documentation, the docs/ folder the extension carries (the
manifest names no website)."""

from pathlib import Path

import bpy

DOCS_DIR = Path(__file__).resolve().parents[1] / "docs"  # beside operators/, in the repository and the extension


def docs_path(page: str) -> Path:
    return DOCS_DIR / Path(page).name  # a page of docs/, never a path elsewhere


def open_url(url: str) -> None:
    bpy.ops.wm.url_open(url=url)


class BODYCAL_OT_open_docs(bpy.types.Operator):
    """Open BodyCal's documentation"""

    bl_idname = "bodycal.open_docs"
    bl_label = "BodyCal Help"
    bl_options = {"INTERNAL"}  # opens a file outside Blender: nothing to undo, nothing to redo

    page: bpy.props.StringProperty(name="Page", default="SIDEBAR.md", description="The page of docs/ to open")
    section: bpy.props.StringProperty(name="Section", default="",
                                      description="The part of the page this help button is about")

    @classmethod
    def description(cls, _context, properties):
        about = f": {properties.section}" if properties.section else ""
        return f"Open BodyCal's documentation{about} (docs/{docs_path(properties.page).name})"

    @classmethod
    def poll(cls, context):
        if not DOCS_DIR.is_dir():
            cls.poll_message_set(f"The documentation is not in this installation ({DOCS_DIR})")
            return False
        return True

    def execute(self, _context):
        path = docs_path(self.page)
        if not path.is_file():
            self.report({"ERROR"}, f"{path}: no such documentation page")
            return {"CANCELLED"}
        # A file URL without the section's anchor: opening "file:...#anchor" fails on some systems.
        open_url(path.as_uri())
        if self.section:
            self.report({"INFO"}, f"Opened {path.name}: see '{self.section}'")
        return {"FINISHED"}


CLASSES = (BODYCAL_OT_open_docs,)
