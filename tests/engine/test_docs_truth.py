"""The docs tell the truth about the tree: DESIGN.md's module table ("| layer | package | does |")
names every module under `bodycal_addon/` in its package's row, and the docs' links to sections of
DESIGN.md and PERFORMANCE.md resolve to a heading that exists.

A module counts as named when its file stem appears in backticks in its package's row (`solver`,
`user.py`, `recording/live/buffer.LiveRecording` all name theirs); a subpackage when its directory
does (`io/`). A new module, or a new package without a row, fails here until the table says what
it does."""

import pathlib
import re

ROOT = pathlib.Path(__file__).resolve().parents[2]
ADDON = ROOT / "bodycal_addon"
DOCS = ROOT / "docs"


def _table_rows() -> dict[str, str]:
    """{package: the text of its row} from DESIGN.md's module table."""
    lines = (DOCS / "DESIGN.md").read_text().splitlines()
    start = next(i for i, line in enumerate(lines) if re.match(r"\|\s*layer\s*\|\s*package\s*\|", line))
    rows = {}
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        package = re.fullmatch(r"`([a-z_]+)/`", cells[1])
        assert package, f"module table: a row's package cell is not `name/`: {line!r}"
        rows[package.group(1)] = " ".join(cells[2:])
    return rows


def _named_words(row: str) -> set[str]:
    """Every identifier inside the row's backtick spans."""
    return {w for span in re.findall(r"`([^`]+)`", row) for w in re.findall(r"[A-Za-z_][A-Za-z0-9_]*", span)}


def _unnamed() -> list[str]:
    rows = _table_rows()
    missing = []
    for path in sorted(ADDON.rglob("*.py")):
        rel = path.relative_to(ADDON)
        if len(rel.parts) == 1:  # the add-on's own __init__ and __main__: they only register and start
            continue
        package = rel.parts[0]
        if package not in rows:
            missing.append(f"{package}/ (no row)")
            continue
        words = _named_words(rows[package])
        for sub in rel.parts[1:-1]:  # subpackages on the way: io/, live/, egocentric/, ...
            if sub not in words:
                missing.append(f"{package}/ row: {sub}/")
        if path.stem != "__init__" and path.stem not in words:
            missing.append(f"{package}/ row: {rel}")
    return sorted(set(missing))


def test_module_table_names_every_module():
    missing = _unnamed()
    assert not missing, "DESIGN.md's module table does not name:\n" + "\n".join(missing)


def test_module_table_has_no_stale_package():
    rows = _table_rows()
    stale = [p for p in rows if not (ADDON / p).is_dir()]
    assert not stale, f"DESIGN.md's module table names packages that do not exist: {stale}"


def _anchors(doc: pathlib.Path) -> set[str]:
    """GitHub's anchors for a Markdown file's headings, and the headings' own text."""
    found = set()
    for line in doc.read_text().splitlines():
        m = re.match(r"#+\s+(.*)", line)
        if m:
            title = m.group(1).strip()
            found.add(title)
            slug = re.sub(r"[^\w\- ]", "", title.lower()).replace(" ", "-")
            found.add(slug)
    return found


def test_links_to_doc_sections_resolve():
    """Every `X.md#anchor` link in the docs and README names a heading of X.md."""
    sources = sorted(DOCS.glob("*.md")) + [ROOT / "README.md"]
    broken = []
    for src in sources:
        for target, anchor in re.findall(r"\]\(([A-Z_]+\.md)#([^)\s]+)\)", src.read_text()):
            doc = DOCS / target if (DOCS / target).exists() else ROOT / target
            if not doc.exists() or anchor not in _anchors(doc):
                broken.append(f"{src.name}: {target}#{anchor}")
    assert not broken, "links to sections that do not exist:\n" + "\n".join(broken)


def _section_names(doc: pathlib.Path) -> set[str]:
    """What a citation may name in a doc: its headings, the bold or italic lead-ins of its paragraphs
    and list items (`**Placement**`, `*A foot turning in place*`) and a list item's first words
    (`- Lost devices (...)`). A citation names one by its beginning ("One session path")."""
    names = set()
    for line in doc.read_text().splitlines():
        m = re.match(r"#+\s+(?:[0-9]+b?\.\s+)?(.*)", line)
        if m:
            names.add(m.group(1).strip())
        names.update(s.strip() for s in re.findall(r"\*\*([^*]+)\*\*", line))
        names.update(s.strip() for s in re.findall(r"(?<!\*)\*([^*\s][^*]*)\*(?!\*)", line))
        item = re.match(r"\s*- ([A-Z][^(:.]+)", line)
        if item:
            names.add(item.group(1).strip())
    return names


def _resolves(quoted: str, names: set[str]) -> bool:
    quoted = quoted.strip().rstrip(".")
    return any(n == quoted or n.startswith(quoted + " ") or n.startswith(quoted + ",")
               or n.startswith(quoted + ":") or n.startswith(quoted + ".") for n in names)


CITING = [ROOT / "README.md", *sorted(DOCS.glob("*.md"))] + [
    p for d in ("bodycal_addon", "benchmarks", "tests", "bodycal_dev", "evaluation")
    for p in sorted((ROOT / d).rglob("*.py")) if p.name != "test_docs_truth.py"]


CITATION = re.compile(r"\b(DESIGN\.md|PERFORMANCE\.md)((?:[ ,;]*(?:§\s?[0-9]+b?,?|\"[^\"]{2,60}\",?))+)")


def test_quoted_section_citations_resolve():
    """`DESIGN.md §6 "Planted feet"`, `PERFORMANCE.md "Bake"`: the quoted names exist in that doc."""
    names = {doc: _section_names(DOCS / doc) for doc in ("DESIGN.md", "PERFORMANCE.md")}
    broken = []
    for src in CITING:
        text = re.sub(r"\s*\n\s*(#\s*)?", " ", src.read_text())  # citations run over wrapped lines
        for doc, rest in CITATION.findall(text):
            for quoted in re.findall(r"\"([^\"]+)\"", rest):
                if re.fullmatch(r"[a-z0-9_]+", quoted):  # a dict key on the next line of code, not a name
                    continue
                if not _resolves(quoted, names[doc]):
                    broken.append(f"{src.relative_to(ROOT)}: {doc} \"{quoted}\"")
    assert not broken, "citations of sections that do not exist:\n" + "\n".join(sorted(set(broken)))


DIARY = re.compile(r"\bissues? #?\d+|\bbranch wt-|\bwt-[a-z]+\b|\bstop \d+\b|\b(?:main|commit) at [0-9a-f]{7}\b",
                   re.IGNORECASE)


def test_docs_read_for_a_newcomer():
    """The docs say what is and why, not which issue, branch, work session or commit brought it
    (git keeps that): no issue numbers, branch names, session stops or `main at <commit>`."""
    found = [f"{src.name}:{n}: {line.strip()[:100]}"
             for src in [ROOT / "README.md", *sorted(DOCS.glob("*.md"))]
             for n, line in enumerate(src.read_text().splitlines(), 1) if DIARY.search(line)]
    assert not found, "\n".join(found)
