"""A batch's review page (FORMATS.md §4.5): `<output_dir>/review.html`, one row per job with its
sheet's thumbnail, its flags (red past their limits) and links to its outputs, the worst first (a
job that failed its verification on the evaluated rig first of all, then the other failures, then
the most flags past their limits). One static file beside the outputs, every link relative: it
opens from the disk in any browser, no server, no script but the one that marks a thumbnail whose
sheet is missing.

The rows come from `summary.json` (the local batch's and `--cluster`'s: every job, how it ended)
and the jobs' review records (`<job>.review.json`, written by `retarget --review` /
`transfer --review` beside the job's output, also when the bake failed): a farm's run, which
writes no summary, is listed from its records.
"""

from __future__ import annotations

import html
import json
import os
from pathlib import Path
from urllib.parse import quote

from ..core import outputs
from .review import Review

PAGE_NAME = "review.html"
RECORD_SUFFIX = ".review.json"
THUMB_WIDTH = 480  # CSS pixels: the sheet is 1500 wide, so a thumbnail shows its frames readably enough

STYLE = """
body { font: 14px/1.4 system-ui, sans-serif; margin: 1.5em; color: #222; }
h1 { font-size: 1.3em; margin: 0 0 .2em; }
p.counts { margin: 0 0 1em; color: #555; }
table { border-collapse: collapse; width: 100%; }
th, td { border-bottom: 1px solid #ddd; padding: .5em; text-align: left; vertical-align: top; }
th { background: #f4f4f4; }
tr.failed td.status, .over { color: #b00; font-weight: 600; }
ul.flags { margin: 0; padding-left: 1.1em; }
img.sheet { width: THUMBpx; max-width: 40vw; border: 1px solid #ccc; }
img.missing { display: none; }
span.missing { color: #b00; }
.error { color: #b00; }
""".replace("THUMB", str(THUMB_WIDTH))

# A thumbnail whose sheet cannot be read is hidden and said (data-loaded: its width, or "missing").
ON_LOAD = "this.dataset.loaded=this.naturalWidth"
ON_ERROR = ("this.dataset.loaded='missing';this.className='missing';"
            "this.insertAdjacentHTML('afterend','<span class=missing>sheet missing</span>')")


def rows(folder: Path, summary: dict | None = None) -> list[dict]:
    """One row per job: {job, status, error, outputs, sheet, review (Review or None), verified}."""
    folder = Path(folder)
    if summary is None and (folder / "summary.json").is_file():
        try:
            summary = json.loads((folder / "summary.json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            summary = None
    found: dict[str, dict] = {}
    for result in (summary or {}).get("results", []):
        found[result["job"]] = {"job": result["job"], "status": result["status"], "error": result.get("error"),
                                "outputs": result.get("outputs") or [], "seconds": result.get("seconds")}
    for path in sorted(folder.glob(f"*{RECORD_SUFFIX}")):
        name = path.name[:-len(RECORD_SUFFIX)]
        try:
            record = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        row = found.setdefault(name, {"job": name, "status": record.get("status", "ok"), "error": record.get("error"),
                                      "outputs": record.get("outputs") or [], "seconds": None})
        row["record"] = record
        if row["status"] == "ok" and record.get("status") == "failed":
            row["status"], row["error"] = "failed", record.get("error")
    out = []
    for row in found.values():
        record = row.pop("record", None)
        review = Review.from_dict(record) if record and record.get("status") == "ok" else None
        if record and record.get("status") == "failed":
            review = Review.from_dict(record)
        sheet = record.get("sheet") if record else None
        out.append({**row, "review": review, "sheet": sheet if sheet and (folder / sheet).is_file() else sheet,
                    "verified": record.get("verified") if record else None})
    out.sort(key=_order)
    return out


def _order(row: dict) -> tuple:
    """Worst first: a failed verification, other failures, cancelled jobs, then the reviews by
    `Review.severity`, then by name."""
    review = row["review"]
    failed_check = review is not None and any(f.name == "verification" and f.over for f in review.flags)
    rank = 0 if failed_check else {"failed": 1, "cancelled": 2}.get(row["status"], 3)
    severity = review.severity()[1:] if review is not None else (0, 0.0)
    return (rank, *severity, row["job"])


def page(folder: Path, summary: dict | None = None) -> str:
    """The page's HTML."""
    folder = Path(folder)
    items = rows(folder, summary)
    flagged = sum(1 for r in items if r["status"] != "ok" or (r["review"] and r["review"].over))
    body = [f"<h1>BodyCal review: {html.escape(folder.name or str(folder))}</h1>",
            f'<p class="counts">{len(items)} job{"" if len(items) == 1 else "s"}; {flagged} flagged (red), '
            "worst first. "
            "Each figure against its limit: docs/FORMATS.md §4.5.</p>",
            "<table><thead><tr><th>job</th><th>status</th><th>flags</th><th>sheet</th><th>outputs</th></tr></thead>",
            "<tbody>"]
    for row in items:
        body.append(_row(folder, row))
    body.append("</tbody></table>")
    return ("<!doctype html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            f"<title>BodyCal review: {html.escape(folder.name)}</title><style>{STYLE}</style></head>\n"
            "<body>\n" + "\n".join(body) + "\n</body></html>\n")


def _link(folder: Path, path: str) -> str:
    """A link to an output, relative to the page's folder (the page and the outputs move together)."""
    p = Path(path)
    rel = Path(os.path.relpath(p.resolve(), folder.resolve())).as_posix()
    return f'<a href="{html.escape(quote(rel))}">{html.escape(p.name)}</a>'


def _row(folder: Path, row: dict) -> str:
    review: Review | None = row["review"]
    failed = row["status"] != "ok"
    status = html.escape(row["status"])
    if row["error"]:
        status += f'<div class="error">{html.escape(row["error"])}</div>'
    flags = []
    for flag in review.flags if review is not None else ():
        cls = ' class="over"' if flag.over else ""
        at = f" (frame {flag.frame:g})" if flag.frame is not None else ""
        flags.append(f"<li{cls}>{html.escape(flag.text)}{html.escape(at)}</li>")
    flag_cell = f'<ul class="flags">{"".join(flags)}</ul>' if flags else ""
    sheet = ""
    if row["sheet"]:
        src = html.escape(quote(row["sheet"]))
        sheet = (f'<a href="{src}"><img class="sheet" src="{src}" alt="review sheet of {html.escape(row["job"])}" '
                 f'onload="{ON_LOAD}" onerror="{html.escape(ON_ERROR)}"></a>')
    links = " ".join(_link(folder, o) for o in row["outputs"])
    cls = ' class="failed"' if failed else ' class="flagged"' if review is not None and review.over else ""
    return (f"<tr{cls}><td>{html.escape(row['job'])}</td><td class=\"status\">{status}</td><td>{flag_cell}</td>"
            f"<td>{sheet}</td><td>{links}</td></tr>")


def write_page(folder, summary: dict | None = None) -> Path:
    """`<folder>/review.html` (replaced whole); its path."""
    folder = Path(folder)
    return outputs.write_text(folder / PAGE_NAME, page(folder, summary), overwrite=True, field="review page")
