"""A UI layout stand-in for background mode (no window draws panels there): a panel's `draw`
given it records what it draws, as ("prop", data, name), ("prop_search", data, name, search_data,
search_name), ("template_list", listtype, data, propname), ("operator", idname) and ("label", text);
every sub-layout (column, row, box...) records into the same log."""


class RecordingLayout:
    def __init__(self, log: list):
        self.log = log

    def operator(self, idname, **_kw):
        self.log.append(("operator", idname))
        return type("Props", (), {})()

    def prop(self, data, name, **_kw):
        self.log.append(("prop", data, name))

    def prop_search(self, data, name, search_data, search_name, **_kw):
        self.log.append(("prop_search", data, name, search_data, search_name))

    def template_list(self, listtype, _list_id, data, propname, *_a, **_kw):
        self.log.append(("template_list", listtype, data, propname))

    def label(self, text="", **_kw):
        self.log.append(("label", text))

    def panel(self, idname, **_kw):
        """A collapsible sub-panel (Blender 4.1+), open: its header and body layouts."""
        self.log.append(("panel", idname))
        return RecordingLayout(self.log), RecordingLayout(self.log)

    def __getattr__(self, name):
        return lambda *a, **k: type(self)(self.log)


def draw(panel_type, context) -> list:
    """What `panel_type.draw` draws in `context`, as the log above."""
    log = []
    panel_type.draw(type("P", (), {"layout": RecordingLayout(log)})(), context)
    return log
