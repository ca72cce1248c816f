"""The engine's layout (DESIGN.md "Modules"): packages stacked in layers, each importing only its
own layer and those below; no import cycle; no import inside a function but the few LAZY_IMPORTS
name, each for its reason; no module loose at the top of `bodycal_addon/`; the numpy engine never
imports Blender (but `core/one_frame.py`, Blender's mathutils for one frame); the sidebar
(`operators/`, `panels/`) reaches the engine through `blender/` only; no private name crosses a
module."""

import ast
import pathlib
import re
import sys
import tomllib

import pytest

ADDON = pathlib.Path(__file__).resolve().parents[2] / "bodycal_addon"

# Lowest first. Packages on one line are siblings: neither imports the other.
LAYERS = (
    ("core",),
    ("body",),
    ("recording",),
    ("calibration", "avatar"),
    ("retarget",),
    ("output",),
    ("live",),  # the live layer: threads, worker processes, the clock; the math is retarget's
    ("blender",),
    ("app",),
)
RANK = {pkg: rank for rank, names in enumerate(LAYERS) for pkg in names}
# The only imports a function may hold (a module, or what starts with it), where, and why; everything
# else is imported at the top of its module.
LAZY_IMPORTS = {
    "bodycal_addon.blender": ("app", "the command line loads Blender's glue only in the commands that need it: "
                                     "`--help`, calibrate-user, live, record and stream run without Blender"),
    "bodycal_addon.recording.live.receiver": ("app", "python-osc's: `live` imports without python-osc"),
    "bodycal_addon.recording.live.sender": ("app", "python-osc's: `live` imports without python-osc"),
    "bodycal_addon.output.vmc_bones": ("app", "python-osc's: `live` imports without python-osc"),
    "bodycal_addon.app.cluster": ("app", "dask and distributed, installed for `batch --cluster` only"),
    "tqdm": ("app", "an optional progress bar"),
    "matplotlib": ("blender", "the review sheet's plots: an optional package"),
    "addon_utils": ("blender", "Blender's, on sys.path only once bpy is imported"),
    "_bpy": ("blender", "Blender's, on sys.path only once bpy is imported"),
}
BLENDER_MODULES = ("bpy", "mathutils", "bmesh", "addon_utils")


def _module_name(path: pathlib.Path) -> str:
    parts = list(path.relative_to(ADDON.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


MODULES = {_module_name(p): p for p in sorted(ADDON.rglob("*.py"))}


def _imports(path: pathlib.Path):
    """(imported module, line, inside a function?) for every import of the file, named from the
    extension's root (`..bodycal_addon.blender` in operators/x.py is `bodycal_addon.blender`)."""
    name = _module_name(path)
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    tree = ast.parse(path.read_text())
    nested = {id(n) for f in ast.walk(tree) if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef))
              for n in ast.walk(f) if n is not f}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, node.lineno, id(node) in nested
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = ".".join(package[: len(package) - node.level + 1] + ([node.module] if node.module else []))
            else:
                base = node.module or ""
            for alias in node.names:
                full = f"{base}.{alias.name}" if base else alias.name  # `from .. import sample_rigs`
                yield (full if full in MODULES or not base else base), node.lineno, id(node) in nested


def _package(module: str) -> str | None:
    """The layer package a module belongs to (`python -m bodycal_addon` is the command line's)."""
    parts = module.split(".")
    if len(parts) < 2 or parts[0] != "bodycal_addon":
        return None
    return "app" if parts[1] == "__main__" else parts[1]


def test_no_module_loose_at_the_top():
    loose = sorted(p.name for p in ADDON.glob("*.py"))
    assert loose == ["__init__.py", "__main__.py"]
    assert {p.name for p in ADDON.iterdir() if p.is_dir() and p.name != "__pycache__"} == set(RANK)


@pytest.mark.parametrize("module", sorted(MODULES))
def test_imports_stay_in_their_layer(module):
    own = _package(module)
    for target, line, _ in _imports(MODULES[module]):
        other = _package(target)
        if own is None or other is None:
            continue
        where = f"{module}:{line} imports {target}"
        assert RANK[other] <= RANK[own], f"{where}: up a layer"
        if RANK[other] == RANK[own]:
            assert other == own, f"{where}: a sibling package"


# The sidebar (operators/, panels/) is thin UI: it reaches the engine through `bodycal_addon.blender`
# only, whose modules own each job the UI asks for (calibrate the scene's performer, read a take,
# import a recording...) and re-export the few engine names it shows (errors, defaults, the segment
# names). Besides blender/ and each other it imports the standard library and these:
UI_PACKAGES = ("operators", "panels")
UI_MAY_IMPORT = {
    "bpy", "bpy_extras", "bl_operators", "bl_ui",  # Blender's own Python API and its UI helpers
    "numpy",  # as Blender ships it: the live panel's timing figures
    "sample_rigs",  # the extension's sample avatars (it ships them; numpy and bpy only, no engine)
}
UI_FILES = sorted(p for tree in UI_PACKAGES for p in (ADDON.parent / tree).rglob("*.py"))


@pytest.mark.parametrize("path", UI_FILES, ids=lambda p: str(p.relative_to(ADDON.parent)))
def test_the_sidebar_goes_through_blender_only(path):
    for target, line, in_function in _imports(path):
        top = target.split(".")[0]
        where = f"{path.relative_to(ADDON.parent)}:{line} imports {target}"
        assert not in_function, f"{where} inside a function"
        if top == "bodycal_addon":
            assert target == "bodycal_addon.blender" or target.startswith("bodycal_addon.blender."), \
                f"{where}: the engine, not through bodycal_addon/blender/"
        else:
            assert top in UI_PACKAGES or top in UI_MAY_IMPORT or top in sys.stdlib_module_names, where


def _lazy_reason(module: str, target: str) -> str | None:
    for name, (package, reason) in LAZY_IMPORTS.items():
        if (target == name or target.startswith(name + ".")) and _package(module) == package:
            return reason
    return None


@pytest.mark.parametrize("module", sorted(MODULES))
def test_no_import_inside_a_function_without_its_reason(module):
    for target, line, in_function in _imports(MODULES[module]):
        if in_function:
            assert _lazy_reason(module, target), f"{module}:{line} imports {target} inside a function"


def _private(name: str) -> bool:
    return name.startswith("_") and not name.startswith("__")


@pytest.mark.parametrize("path", sorted(ADDON.rglob("*.py")) + UI_FILES, ids=lambda p: str(p.relative_to(ADDON.parent)))
def test_no_private_name_crosses_a_module(path):
    """A name with a leading underscore is its module's own: another module neither imports it nor
    reaches it through the module (`from .solver import _check`, `solver._check`); what two modules
    share is public, or lives where it is used."""
    package = path.relative_to(ADDON.parent).with_suffix("").parts[:-1] if path.name != "__init__.py" else \
        path.relative_to(ADDON.parent).parts[:-1]
    tree = ast.parse(path.read_text())
    ours = {}  # a name bound to one of BodyCal's modules -> that module
    crossing = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            base = list(package[: len(package) - node.level + 1]) if node.level else []
            module = ".".join(base + ([node.module] if node.module else []))
            if module.split(".")[0] not in ("bodycal_addon", *UI_PACKAGES):
                continue
            for alias in node.names:
                if _private(alias.name):
                    crossing.append(f"{node.lineno}: from {module} import {alias.name}")
                ours[alias.asname or alias.name] = f"{module}.{alias.name}"
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name.split(".")[0] == "bodycal_addon":
                    ours[(alias.asname or alias.name).split(".")[0]] = alias.name
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and _private(node.attr) and isinstance(node.value, ast.Name) \
                and node.value.id in ours:
            crossing.append(f"{node.lineno}: {node.value.id}.{node.attr} ({ours[node.value.id]})")
    assert not crossing, f"{path.relative_to(ADDON.parent)}: " + "; ".join(crossing)


def _shipped_and_left_out() -> tuple[list[pathlib.Path], set[str]]:
    """(the Python files the extension zip carries, the top-level folders its manifest leaves out)."""
    root = ADDON.parent
    patterns = tomllib.loads((root / "blender_manifest.toml").read_text())["build"]["paths_exclude_pattern"]
    left_out = {p.strip("/") for p in patterns if p.startswith("/") and p.endswith("/")}
    shipped = [path for top in sorted(root.iterdir()) if not top.name.startswith(".") and top.name not in left_out
               for path in ([top] if top.suffix == ".py" else sorted(top.rglob("*.py")) if top.is_dir() else [])]
    return shipped, left_out


def test_what_the_extension_ships_never_imports_what_it_leaves_out():
    """The zip leaves out the development tools (`bodycal_dev`), the tests and benchmarks: nothing it
    carries may import them (`sample_rigs` ships; `bodycal_dev` may import it, not the other way)."""
    shipped, left_out = _shipped_and_left_out()
    assert {"bodycal_dev", "tests", "benchmarks"} <= left_out and "sample_rigs" not in left_out
    assert ADDON.parent / "sample_rigs" / "__init__.py" in shipped
    found = []
    for path in shipped:
        package = list(path.relative_to(ADDON.parent).parts[:-1])
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):  # `from .. import bodycal_dev` named from the root
                base = ".".join(package[: len(package) - node.level + 1] + [node.module or ""]).strip(".")
                names = [base] if base else [a.name for a in node.names]
            else:
                continue
            found += [f"{path.relative_to(ADDON.parent)}:{node.lineno} imports {n}" for n in names
                      if n.split(".")[0] in left_out]
    assert not found, "; ".join(found)


# The one engine module that imports Blender's mathutils (one frame's kernels; PyPI's build outside
# Blender), and imports nothing else of Blender's.
ONE_FRAME = "bodycal_addon.core.one_frame"


@pytest.mark.parametrize("module", sorted(m for m in MODULES if _package(m) not in ("blender", "app", None)))
def test_engine_never_imports_blender(module):
    for target, line, _ in _imports(MODULES[module]):
        if module == ONE_FRAME and target.split(".")[0] == "mathutils":
            continue
        assert target.split(".")[0] not in BLENDER_MODULES, f"{module}:{line} imports {target}"
        assert _package(target) not in ("blender", "app"), f"{module}:{line} imports {target}"


def test_no_import_cycle():
    graph = {m: {t for t, _, _ in _imports(p) if t in MODULES and t != m} for m, p in MODULES.items()}
    # a package's __init__ importing its own modules is its face, not a cycle through them
    state: dict[str, int] = {}
    path: list[str] = []

    def visit(m):
        state[m] = 1
        path.append(m)
        for t in sorted(graph[m]):
            if state.get(t) == 1:
                if not m.startswith(t + ".") and not t.startswith(m + "."):
                    raise AssertionError("import cycle: " + " -> ".join(path[path.index(t):] + [t]))
            elif t not in state:
                visit(t)
        path.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)


@pytest.mark.parametrize("path", sorted(ADDON.rglob("__init__.py")), ids=lambda p: _module_name(p) or "bodycal_addon")
def test_package_init_only_re_exports(path):
    """A package's __init__ is its face: a docstring, imports and `__all__` (the top package also
    its version); the code lives in modules."""
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            continue
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant) and isinstance(node.value.value, str):
            continue
        if isinstance(node, ast.Assign) and [t.id for t in node.targets if isinstance(t, ast.Name)] in (
                ["__all__"], ["__version__"]):
            continue
        raise AssertionError(f"{_module_name(path)}: line {node.lineno} is code, not a re-export")


def test_recording_readers_leaves_do_not_import_the_readers_package():
    """coords, segments, gaps and the LED gloves are shared by every reader; the readers' package
    imports them, never the other way."""
    for leaf in ("coords", "segments", "gaps", "led_gloves", "model"):
        for target, line, _ in _imports(MODULES[f"bodycal_addon.recording.{leaf}"]):
            assert not target.startswith("bodycal_addon.recording.io"), f"{leaf}:{line} imports {target}"


# An issue number of a tracker that is not in the repository, or a paper by a number rather than its
# short name in docs/REFERENCES.md.
UNRESOLVABLE_CITATION = re.compile(r"\bissues? #?\d+|\bpapers? 0\d\d\b", re.IGNORECASE)


def test_the_code_cites_what_a_reader_can_open():
    """The code says what it means: a section of docs/FORMATS.md or docs/DESIGN.md, a paper by its
    short name, or the feature's name; never an issue number no reader of the repository can look
    up."""
    found = [f"{path.relative_to(ADDON.parent)}:{n}: {line.strip()}"
             for tree in ("bodycal_addon", "operators", "panels")
             for path in sorted((ADDON.parent / tree).rglob("*.py"))
             for n, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
             if UNRESOLVABLE_CITATION.search(line)]
    assert not found, "\n".join(found)


MAX_FUNCTION_LINES = 80


def _functions(tree: ast.AST, outer: str = ""):
    """(qualified name, node) of every function and method, nested ones included."""
    for node in ast.iter_child_nodes(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            name = f"{outer}{node.name}"
            if not isinstance(node, ast.ClassDef):
                yield name, node
            yield from _functions(node, name + ".")
        else:
            yield from _functions(node, outer)


def test_no_engine_function_is_longer_than_80_lines():
    """A long engine function becomes a short sequence of named passes, each stating what it reads
    and what it sets (as glTF-Blender-IO's vnode.py and Rigify's rig stages do), so each step can
    be read and checked on its own. The Blender glue (`blender/`) is not the engine."""
    too_long = []
    for path in sorted(ADDON.rglob("*.py")):
        if path.relative_to(ADDON).parts[0] == "blender":
            continue
        for name, node in _functions(ast.parse(path.read_text())):
            lines = node.end_lineno - node.lineno + 1
            if lines > MAX_FUNCTION_LINES:
                too_long.append(f"{_module_name(path)}.{name} (line {node.lineno}): {lines} lines")
    assert not too_long, f"longer than {MAX_FUNCTION_LINES} lines; split into passes: " + "; ".join(too_long)
