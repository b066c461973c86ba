"""The experiment report: success per task and method in the paper's table shape (Markdown and one
self-contained HTML page), a grouped bar chart, and example episodes.

Input is one summary per method, exactly as :func:`tvf.evaluate.closed_loop.summarise` returns it.
"""

from __future__ import annotations

import html
import io
import json
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from tvf.evaluate.closed_loop import wilson
from tvf.io import atomic_write_bytes
from tvf.policies import METHODS, label
from tvf.tasks import resolve_tasks

METHOD_ORDER = tuple(METHODS)
"""Column order (the method registry's); other method names follow in the order given."""

PAPER_UNSEEN_10_DEMOS = {"gctn": 0.554, "tvf-large": 0.785}
"""The paper's only published numbers (Wu et al., IROS 2022): average success on the unseen tasks with
10 demonstrations per task; its TVF is the full planner, compared here with ``tvf-large``."""

PAPER_NOTE = (
    "The paper's only published numbers are the average success on the unseen tasks at 10 demos: "
    "GCTN 55.4% and TVF 78.5% (TVF = the full planner, shown under TVF-L)."
)
TABLE_NOTE = (
    "Success rate with its Wilson 95% interval in percent; the best method per row (not counting the "
    "oracle) in bold."
)
GIF_CAPTION = "TVF-L episode (left: real; right: imagined best path)"
MISSING = "–"
PARTIAL_NOTE = "\\* averaged over the tasks this method was evaluated on only (fewer than the group)."
GROUPS = (("unseen", "Unseen tasks", "unseen average"), ("train", "Training tasks", "training average"),
          ("other", "Other tasks", "other average"))  # fmt: skip

Row = tuple[str, str, list[str]]
"""A table row: kind ("group", "task", "average", "paper"), first cell, one cell per method."""


def ordered_methods(summaries: dict[str, dict]) -> list[str]:
    """Methods in report order: the known ones first (oracle, gctn, tvf-small, tvf-large), then the rest."""
    known = [m for m in METHOD_ORDER if m in summaries]
    return known + [m for m in summaries if m not in METHOD_ORDER]


def task_groups(summaries: dict[str, dict]) -> dict[str, list[str]]:
    """Tasks present in any summary, split into "unseen", "train" and "other" (table order inside each)."""
    present = list(dict.fromkeys(r["task"] for s in summaries.values() for r in s.get("tasks", [])))
    groups = {
        split: [t.name for t in resolve_tasks(split) if t.name in present] for split in ("unseen", "train")
    }
    known = set(groups["unseen"]) | set(groups["train"])
    groups["other"] = [t for t in present if t not in known]
    return groups


def task_row(summary: dict, task: str) -> dict | None:
    """The summary's row for ``task``, or None."""
    return next((r for r in summary.get("tasks", []) if r["task"] == task), None)


def group_average(summary: dict, tasks: list[str]) -> dict | None:
    """Average over the ``tasks`` present in ``summary``: mean per-task success, the Wilson 95% interval of
    the pooled successes/episodes, mean progress, episodes and number of tasks; None if none is present."""
    rows = [r for r in (task_row(summary, t) for t in tasks) if r is not None]
    if not rows:
        return None
    k = sum(r["successes"] for r in rows)
    n = sum(r["episodes"] for r in rows)
    return {
        "success": float(np.mean([r["success"] for r in rows])),
        "ci95": list(wilson(k, n)),
        "progress": float(np.mean([r["progress"] for r in rows])),
        "episodes": n,
        "tasks": len(rows),
    }


def success_cell(entry: dict | None) -> str:
    """``"55.0% [36–73]"``: success and Wilson 95% interval in percent, or "–"."""
    if entry is None:
        return MISSING
    lo, hi = entry["ci95"]
    return f"{100 * entry['success']:.1f}% [{100 * lo:.0f}–{100 * hi:.0f}]"


def progress_cell(entry: dict | None) -> str:
    """Mean progress in percent, or "–"."""
    return MISSING if entry is None else f"{100 * entry['progress']:.1f}%"


def best_methods(methods: list[str], entries: list[dict | None], key: str) -> set[str]:
    """The non-oracle methods with the highest ``key`` (all of them on a tie)."""
    values = {m: e[key] for m, e in zip(methods, entries, strict=True) if e is not None and m != "oracle"}
    if not values:
        return set()
    top = max(values.values())
    return {m for m, v in values.items() if v == top}


def metric_row(kind: str, name: str, methods: list[str], entries: list[dict | None], key: str) -> Row:
    """One row of cells for ``key`` ("success" or "progress"); the best non-oracle method marked ``**``."""
    fmt = success_cell if key == "success" else progress_cell
    best = best_methods(methods, entries, key)
    cells = []
    for m, e in zip(methods, entries, strict=True):
        cell = fmt(e)
        cell = f"**{cell}**" if m in best else cell
        cells.append(cell)
    return (kind, name, cells)


def average_row(summaries: dict[str, dict], methods: list[str], name: str, tasks: list[str], key: str) -> Row:
    """A group-average row; a method evaluated on only part of the group gets a ``*``."""
    entries = [group_average(summaries[m], tasks) for m in methods]
    kind, name, cells = metric_row("average", name, methods, entries, key)
    cells = [
        c + " \\*" if e is not None and e["tasks"] < len(tasks) else c
        for c, e in zip(cells, entries, strict=True)
    ]
    return (kind, name, cells)


def paper_row(methods: list[str]) -> Row:
    """The paper's unseen averages (10 demos) under their methods, "–" elsewhere."""
    cells = [
        f"{100 * PAPER_UNSEEN_10_DEMOS[m]:.1f}%" if m in PAPER_UNSEEN_10_DEMOS else MISSING for m in methods
    ]
    return ("paper", "paper (10 demos)", cells)


def table_rows(summaries: dict[str, dict], key: str) -> list[Row]:
    """The paper-style table for ``key``: tasks by group, then the group averages (and, for success, the
    paper's numbers under the unseen average)."""
    methods = ordered_methods(summaries)
    groups = task_groups(summaries)
    rows: list[Row] = []
    for split, title, _ in GROUPS:
        if groups[split]:
            rows.append(("group", title, [""] * len(methods)))
        for t in groups[split]:
            rows.append(metric_row("task", t, methods, [task_row(summaries[m], t) for m in methods], key))
    for split, _, avg_name in GROUPS:
        if groups[split]:
            rows.append(average_row(summaries, methods, avg_name, groups[split], key))
        if split == "unseen" and key == "success":
            rows.append(paper_row(methods))
    return rows


def meta_value(value: object) -> str:
    """A meta value as one line of text: lists joined by "; ", dicts as JSON."""
    if isinstance(value, list | tuple):
        return "; ".join(meta_value(v) for v in value)
    if isinstance(value, dict):
        return json.dumps(value, sort_keys=True, default=str)
    return str(value)


# ----------------------------------------------------------------------------------------------- Markdown


def md_text(text: str) -> str:
    """Text safe inside a Markdown table cell (HTML-escaped, pipes escaped)."""
    return html.escape(text, quote=False).replace("|", "\\|")


def md_table(header: list[str], rows: list[Row]) -> list[str]:
    """Markdown lines of a table; group rows are bold, averages and the paper row are italic in column 1."""
    lines = ["| " + " | ".join(md_text(h) for h in header) + " |", "|---" * len(header) + "|"]
    for kind, name, cells in rows:
        first = {"group": f"**{md_text(name)}**", "task": md_text(name)}.get(kind, f"*{md_text(name)}*")
        lines.append("| " + " | ".join([first, *cells]) + " |")
    return lines


def md_image(alt: str, path: str) -> str:
    """A Markdown image; the path goes in angle brackets so spaces are allowed."""
    return f"![{md_text(alt)}](<{path}>)"


def report_markdown(
    summaries: dict[str, dict], meta: dict, gifs: dict[str, str] | None = None, chart: str | None = None
) -> str:
    """The report as Markdown; ``gifs`` (task -> path) and ``chart`` are paths relative to the report."""
    header = ["task", *(label(m) for m in ordered_methods(summaries))]
    lines = ["# TVF experiment", "", "| run | |", "|---|---|"]
    lines += [f"| {md_text(str(k))} | {md_text(meta_value(v))} |" for k, v in meta.items()]
    lines += ["", "## Success", "", TABLE_NOTE, ""]
    success = table_rows(summaries, "success")
    lines += md_table(header, success)
    lines += ["", PAPER_NOTE]
    if any(c.endswith("\\*") for _, _, cells in success for c in cells):
        lines += ["", PARTIAL_NOTE]
    lines += ["", "## Mean progress", "", "Fraction of goal blocks placed at the end of an episode.", ""]
    lines += md_table(header, table_rows(summaries, "progress"))
    if chart:
        lines += ["", "## Chart", "", md_image("success per method", chart)]
    episodes = [(t, gifs[t]) for t in task_groups(summaries)["unseen"] if gifs and t in gifs]
    if episodes:
        lines += ["", "## Episodes"]
        for task, path in episodes:
            lines += ["", f"### {md_text(task)}", "", md_image(f"{task}: {GIF_CAPTION}", path), "",
                      f"*{GIF_CAPTION}*"]  # fmt: skip
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------------------------- HTML

CSS = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1100px; color: #222; }
table { border-collapse: collapse; margin: 1em 0; }
th, td { border: 1px solid #ccc; padding: 0.3em 0.7em; text-align: right; white-space: nowrap; }
th:first-child, td:first-child { text-align: left; }
tr.group td { background: #eef; font-weight: bold; text-align: left; }
tr.average td, tr.paper td { background: #f7f7f7; font-style: italic; }
table.meta td { text-align: left; white-space: normal; }
figure { margin: 1em 0; } img { max-width: 100%; }
.note { color: #555; font-size: 0.9em; }
"""


def html_cell(cell: str) -> str:
    """A table cell's text as HTML: ``**x**`` becomes <strong>, ``\\*`` a plain star."""
    text = cell.replace("\\*", "*")
    if text.startswith("**") and "**" in text[2:]:
        inner, rest = text[2:].split("**", 1)
        return f"<strong>{html.escape(inner)}</strong>{html.escape(rest)}"
    return html.escape(text)


def html_table(header: list[str], rows: list[Row]) -> list[str]:
    """HTML lines of a table; group rows span the whole width."""
    out = ["<table>", "<tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in header) + "</tr>"]
    for kind, name, cells in rows:
        if kind == "group":
            out.append(f'<tr class="group"><td colspan="{len(header)}">{html.escape(name)}</td></tr>')
            continue
        tds = "".join(f"<td>{html_cell(c)}</td>" for c in cells)
        out.append(f'<tr class="{kind}"><td>{html.escape(name)}</td>{tds}</tr>')
    return out + ["</table>"]


def html_figure(path: str, caption: str) -> str:
    """An image with a caption, by relative path."""
    src, cap = html.escape(path, quote=True), html.escape(caption)
    return f'<figure><img src="{src}" alt="{cap}"><figcaption>{cap}</figcaption></figure>'


def report_html(
    summaries: dict[str, dict], meta: dict, gifs: dict[str, str] | None = None, chart: str | None = None
) -> str:
    """The report as one self-contained HTML page (inline CSS, no scripts, images by relative path)."""
    header = ["task", *(label(m) for m in ordered_methods(summaries))]
    out = ["<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
           "<title>TVF experiment</title>", f"<style>{CSS}</style>", "</head>", "<body>",
           "<h1>TVF experiment</h1>", '<table class="meta">']  # fmt: skip
    out += [
        f"<tr><td>{html.escape(str(k))}</td><td>{html.escape(meta_value(v))}</td></tr>"
        for k, v in meta.items()
    ]
    out += ["</table>", "<h2>Success</h2>", f'<p class="note">{html.escape(TABLE_NOTE)}</p>']
    success = table_rows(summaries, "success")
    out += html_table(header, success)
    out.append(f'<p class="note">{html.escape(PAPER_NOTE)}</p>')
    if any(c.endswith("\\*") for _, _, cells in success for c in cells):
        out.append(f'<p class="note">{html.escape(PARTIAL_NOTE.replace(chr(92), ""))}</p>')
    out += [
        "<h2>Mean progress</h2>",
        '<p class="note">Fraction of goal blocks placed at the end of an episode.</p>',
    ]
    out += html_table(header, table_rows(summaries, "progress"))
    if chart:
        out += ["<h2>Chart</h2>", html_figure(chart, "success per method")]
    episodes = [(t, gifs[t]) for t in task_groups(summaries)["unseen"] if gifs and t in gifs]
    if episodes:
        out.append("<h2>Episodes</h2>")
        out += [f"<h3>{html.escape(t)}</h3>\n{html_figure(p, GIF_CAPTION)}" for t, p in episodes]
    return "\n".join(out + ["</body>", "</html>"]) + "\n"


# ----------------------------------------------------------------------------------------------- chart


def chart_groups(summaries: dict[str, dict]) -> list[tuple[str, dict[str, dict | None]]]:
    """Bar groups: unseen average, train average, then each unseen task; each maps method -> entry (groups
    with no data are left out, except the unseen average, where the paper's numbers go)."""
    groups = task_groups(summaries)
    methods = ordered_methods(summaries)
    out = [
        ("unseen average", {m: group_average(summaries[m], groups["unseen"]) for m in methods}),
        ("train average", {m: group_average(summaries[m], groups["train"]) for m in methods}),
    ]
    out += [(t, {m: task_row(summaries[m], t) for m in methods}) for t in groups["unseen"]]
    return [g for g in out if g[0] == "unseen average" or any(e is not None for e in g[1].values())]


def paper_marks(ax, methods: list[str], width: float) -> None:
    """The paper's unseen averages as short black lines with a point, over each method's slot in the
    "unseen average" group (x = 0), labelled "paper"."""
    for i, m in enumerate(methods):
        if m not in PAPER_UNSEEN_10_DEMOS:
            continue
        x, y = (i - (len(methods) - 1) / 2) * width, PAPER_UNSEEN_10_DEMOS[m]
        first = not any(line.get_label() == "paper" for line in ax.lines)
        ax.hlines(y, x - width / 2, x + width / 2, colors="black", lw=1.5)
        ax.plot([x], [y], "kD", ms=4, label="paper" if first else None)
        ax.annotate("paper", (x, y), xytext=(0, 4), textcoords="offset points", ha="center", fontsize=7)


def success_chart(summaries: dict[str, dict], path: Path) -> Path:
    """Grouped bar chart of success per method (Wilson 95% error bars) with the paper's unseen averages
    as labelled markers; written atomically as a PNG at ``path``."""

    methods = ordered_methods(summaries)
    groups = chart_groups(summaries)
    width = 0.8 / max(len(methods), 1)
    fig = Figure(figsize=(max(6.0, 1.1 * len(groups) + 2), 4.2), dpi=110)
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    for i, m in enumerate(methods):
        xs = [g + (i - (len(methods) - 1) / 2) * width for g in range(len(groups))]
        pts = [(x, e) for x, (_, entries) in zip(xs, groups, strict=True) if (e := entries[m]) is not None]
        if not pts:
            continue
        ys = [e["success"] for _, e in pts]
        err = [[max(0.0, e["success"] - e["ci95"][0]) for _, e in pts],
               [max(0.0, e["ci95"][1] - e["success"]) for _, e in pts]]  # fmt: skip
        ax.bar([x for x, _ in pts], ys, width, yerr=err, capsize=2, ecolor="0.4", label=label(m))
    paper_marks(ax, methods, width)
    ax.set_xticks(range(len(groups)), [name for name, _ in groups], rotation=30, ha="right", fontsize=8)
    ax.set_ylim(0, 1.3)
    ax.set_ylabel("success (Wilson 95% interval)")
    ax.legend(fontsize=8, ncols=len(methods) + 1, loc="upper center", frameon=False)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    atomic_write_bytes(path, buf.getvalue())
    return Path(path)


# ----------------------------------------------------------------------------------------------- files


def write_report(
    out_dir: Path, summaries: dict[str, dict], meta: dict, gifs: dict[str, str] | None = None
) -> tuple[Path, Path]:
    """Write ``success.png`` (when any summary has tasks), ``report.md`` and ``report.html`` into
    ``out_dir``, each atomically; ``gifs`` maps task -> path relative to ``out_dir``."""
    out_dir = Path(out_dir)
    chart = None
    if any(s.get("tasks") for s in summaries.values()):
        success_chart(summaries, out_dir / "success.png")
        chart = "success.png"
    md, page = out_dir / "report.md", out_dir / "report.html"
    atomic_write_bytes(md, report_markdown(summaries, meta, gifs, chart).encode())
    atomic_write_bytes(page, report_html(summaries, meta, gifs, chart).encode())
    return md, page
