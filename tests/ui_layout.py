"""A UI layout stand-in for background mode (no window draws panels there): a panel's `draw`
given it records what it draws, as ("prop", data, name), ("prop_search", data, name, search_data,
search_name), ("template_list", listtype, data, propname), ("operator", idname), ("label", text),
("popover", panel) and ("panel", idname) (a layout panel, drawn open); every sub-layout (column,
row, box...) records into the same log."""


class OperatorEntry(tuple):
    """("operator", idname), and `.props`: the operator's properties as the panel set them."""

    def __init__(self, _items):
        self.props = type("Props", (), {})()


class RecordingLayout:
    def __init__(self, log: list):
        self.log = log

    def operator(self, idname, **_kw):
        entry = OperatorEntry(("operator", idname))
        self.log.append(entry)
        return entry.props

    def prop(self, data, name, **_kw):
        self.log.append(("prop", data, name))

    def prop_search(self, data, name, search_data, search_name, **_kw):
        self.log.append(("prop_search", data, name, search_data, search_name))

    def template_list(self, listtype, _list_id, data, propname, *_a, **_kw):
        self.log.append(("template_list", listtype, data, propname))

    def label(self, text="", **_kw):
        self.log.append(("label", text))

    def popover(self, panel, **_kw):
        self.log.append(("popover", panel))

    def panel(self, idname, **_kw):
        """A layout panel (Blender 4.1+): its header and its body, drawn open."""
        self.log.append(("panel", idname))
        return type(self)(self.log), type(self)(self.log)

    def __getattr__(self, name):
        return lambda *a, **k: type(self)(self.log)


def draw(panel_type, context, method="draw") -> list:
    """What `panel_type.draw` (or another of its draw methods: "draw_header", "draw_header_preset")
    draws in `context`, as the log above."""
    log = []
    getattr(panel_type, method)(type("P", (), {"layout": RecordingLayout(log)})(), context)
    return log
