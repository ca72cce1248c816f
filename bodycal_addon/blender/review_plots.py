"""The review sheet's plots (DESIGN.md §7 "Review"): the rendered frames above, and below them the
figures over the take with their limits: each contact pair's gap (the avatar's, and the source's
dashed), each foot's sole height (the body model's, a line) and skin (the evaluated mesh's, dots),
the feet's slide where the source's foot is down, and the wrists' and ankles' acceleration against
the source's (dashed). The sheet's frames are marked on every plot.

matplotlib (a maintained plotting library; the dev venv and the farm have it, Blender's Python does
not) is imported when a sheet is drawn, never when this module loads: `available()` says whether
it can be (blender/review.py draws the frames alone without it). Only its object-oriented API and
the Agg canvas are used (no pyplot: no global state, no GUI backend, and less to import).
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

from ..output import metrics
from ..output.review import Review

DPI = 100
# Faster drawing, the same picture at this size: paths simplified to the pixels they cover.
STYLE = {"path.simplify": True, "path.simplify_threshold": 0.5, "axes.titlesize": 8, "font.size": 7}
LIMIT = dict(color="#d62728", linewidth=1.0, linestyle=":")
MARK = dict(color="#888888", linewidth=0.6, linestyle="-", alpha=0.5)


def available() -> bool:
    """Whether matplotlib can be imported in this Python."""
    return importlib.util.find_spec("matplotlib") is not None


def compose(review: Review, frames_png: Path, out: Path, plots_px: int) -> None:
    """The sheet: `frames_png` (the rendered frames) over the plots, written to `out` (PNG)."""
    from matplotlib import rc_context
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure
    from matplotlib.image import imread
    from matplotlib.ticker import MaxNLocator

    with rc_context(STYLE):
        _compose(review, imread(str(frames_png)), out, plots_px, Figure, FigureCanvasAgg, MaxNLocator)


def _compose(review, frames, out, plots_px, Figure, FigureCanvasAgg, MaxNLocator) -> None:
    h, w = frames.shape[:2]
    fig = Figure(figsize=(w / DPI, (h + plots_px) / DPI), dpi=DPI)
    FigureCanvasAgg(fig)
    top = fig.add_axes((0.0, plots_px / (h + plots_px), 1.0, h / (h + plots_px)))
    top.imshow(frames, interpolation="nearest")
    top.set_axis_off()
    bottom = plots_px / (h + plots_px)
    grid = fig.add_gridspec(2, 2, left=0.06, right=0.99, bottom=0.09 * bottom, top=0.93 * bottom,
                            hspace=0.45, wspace=0.14)
    axes = [fig.add_subplot(grid[i, j]) for i in range(2) for j in range(2)]
    s = review.series
    marks = [f.frame for f in review.frames]
    _contacts(axes[0], s)
    _feet(axes[1], s)
    _slides(axes[2], s)
    _accelerations(axes[3], s)
    for k, ax in enumerate(axes):
        for m in marks:
            ax.axvline(m, **MARK)
        ax.tick_params(labelsize=7)
        ax.xaxis.set_major_locator(MaxNLocator(6, integer=True))
        ax.yaxis.set_major_locator(MaxNLocator(4))
        if k >= 2:
            ax.set_xlabel("frame", fontsize=7)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=6, loc="upper right", ncol=2, frameon=False, handlelength=1.2)
    # a low PNG compression: a sheet is written once and looked at a few times (level 6 took 3x longer)
    fig.savefig(str(out), format="png", dpi=DPI, pil_kwargs={"compress_level": 2})


def _line(ax, data, **style):
    if data and data[0]:
        ax.plot(data[0], [float("nan") if v is None else v for v in data[1]], **style)


def _contacts(ax, s) -> None:
    ax.set_title("contact gaps (mm): avatar, source dashed", fontsize=8)
    for k, c in enumerate(s.get("contact", [])):
        colour = f"C{k % 10}"
        _line(ax, c["avatar"], color=colour, linewidth=0.8, label=c["pair"])
        _line(ax, c["source"], color=colour, linewidth=0.6, linestyle="--")
    limit = metrics.CONTACT_GAP_P95_MM
    ax.axhline(limit, **LIMIT)
    ax.axhline(-limit, **LIMIT)
    if not s.get("contact"):
        ax.text(0.5, 0.5, "no self-contact in the source", transform=ax.transAxes, ha="center", fontsize=8)


def _feet(ax, s) -> None:
    ax.set_title("feet above the floor (mm): sole model, skin dots", fontsize=8)
    for k, (side, data) in enumerate(sorted(s.get("sole", {}).items())):
        _line(ax, data, color=f"C{k}", linewidth=0.7, label=f"{side} sole")
        skin = s.get("skin", {}).get(side)
        if skin:
            ax.plot(skin[0], skin[1], "o", color=f"C{k}", markersize=3, label=f"{side} skin")
    ax.axhline(metrics.FOOT_SKIN_LOWEST_MM, **LIMIT)


def _slides(ax, s) -> None:
    ax.set_title("foot slide while the source's foot is down (mm per 90 Hz frame)", fontsize=8)
    for k, (name, data) in enumerate(sorted(s.get("slide", {}).items())):
        _line(ax, data, color=f"C{k}", linewidth=0.7, label=name.replace("_", " "))
    ax.axhline(metrics.SLIDE_P95_MM, **LIMIT)
    source = s.get("slide_source_p95")
    if source:
        ax.axhline(source * metrics.SLIDE_RATIO, color="#d62728", linewidth=0.8, linestyle="--", alpha=0.6)


def _accelerations(ax, s) -> None:
    ax.set_title("wrist and ankle acceleration (m/s²): avatar, source scaled dashed", fontsize=8)
    for k, (name, entry) in enumerate(sorted(s.get("accel", {}).items())):
        colour = f"C{k}"
        _line(ax, entry.get("avatar"), color=colour, linewidth=0.6, label=name.replace("_", " "))
        _line(ax, entry.get("source"), color=colour, linewidth=0.5, linestyle="--")
