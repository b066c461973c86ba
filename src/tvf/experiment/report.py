"""The experiment report: success per task and method in the paper's table shape (Markdown and one
self-contained HTML page), a grouped bar chart, and example episodes.

Input is one summary per method, exactly as :func:`tvf.evaluate.closed_loop.summarise` returns it.
Given the shipped weights' provenance record (:func:`tvf.weights.provenance`), the report also puts
their recorded evaluation beside the run's numbers and the paper's (the quick start's comparison).
"""

from __future__ import annotations

import html
import io
import json
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from tvf import __version__
from tvf.evaluate.closed_loop import wilson
from tvf.io import atomic_write_bytes
from tvf.policies import label, paper_method, variant_order
from tvf.seeds import seed_range
from tvf.tasks import resolve_tasks

PAPER_UNSEEN = {
    1: {"gctn": 0.013, "tvf-small": 0.017, "tvf-large": 0.029},
    10: {"gctn": 0.554, "tvf-small": 0.715, "tvf-large": 0.785},
    100: {"gctn": 0.490, "tvf-small": 0.623, "tvf-large": 0.717},
    1000: {"gctn": 0.542, "tvf-small": 0.725, "tvf-large": 0.856},
}
"""The paper's numbers (Wu et al., IROS 2022; full-size networks), the one copy in the code: average
success on the 8 unseen tasks per number of demonstrations per training task (docs/results.md)."""
PAPER_UNSEEN_10_DEMOS = PAPER_UNSEEN[10]
PAPER_TASKS_10_DEMOS = {"put-plane": {"gctn": 0.867, "tvf-large": 1.0},
                        "stack-building": {"gctn": 0.05, "tvf-large": 0.133}}  # fmt: skip
"""The paper's only per-task cells (10 demos per task)."""
PAPER_LABEL = "paper (10 demos)"


def paper_unseen(demos: int, method: str) -> float | None:
    """The paper's unseen average at ``demos`` per task of the paper's method that ``method`` runs (with our
    rules or the paper's); None where the paper has no such number."""
    return PAPER_UNSEEN.get(demos, {}).get(paper_method(method) or "")


def paper_note() -> str:
    """One sentence naming the paper's numbers, written from :data:`PAPER_UNSEEN_10_DEMOS`."""
    cells = ", ".join(f"{label(m)} {100 * v:.1f}%" for m, v in PAPER_UNSEEN_10_DEMOS.items())
    return (
        "The paper (Wu et al., IROS 2022, full-size networks) reports the average success on the unseen "
        f"tasks at 10 demos per task: {cells}; no per-task or training-task table."
    )


TABLE_NOTE = (
    "Success rate with its Wilson 95% interval in percent; the best method per row (not counting the "
    "oracle) in bold."
)
GIF_CAPTIONS = {
    "tvf": "the real observation (green), the imagined best path of each decision (blue), the goal (grey); "
    "colour over height, every step labelled",
    "other": "the real observation (green) and the goal (grey); colour over height, every step labelled",
}
MISSING = "–"
PARTIAL_NOTE = "\\* averaged over the tasks this method was evaluated on only (fewer than the group)."
GROUPS = (("unseen", "Unseen tasks", "unseen average"), ("train", "Training tasks", "training average"),
          ("other", "Other tasks", "other average"))  # fmt: skip

Row = tuple[str, str, list[str]]
"""A table row: kind ("group", "task", "average", "paper"), first cell, one cell per method."""


def ordered_methods(summaries: dict[str, dict]) -> list[str]:
    """Methods in report order: the known ones first (oracle, gctn, tvf-small, tvf-large, ..., each
    method's foresight variants after it), then the rest in the order given."""
    known = sorted((m for m in summaries if variant_order(m) is not None), key=variant_order)
    return known + [m for m in summaries if variant_order(m) is None]


def evaluated_methods(eval_dir: Path) -> list[str]:
    """The methods with a finished evaluation in ``eval_dir`` (``METHOD/summary.json``), in report order."""
    found = {p.parent.name: {} for p in sorted(Path(eval_dir).glob("*/summary.json"))}
    return ordered_methods(found)


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


def _mean_progress(rows: list[dict]) -> float | None:
    """Mean progress of the rows, None when any lacks it (an older recorded evaluation)."""
    values = [r.get("progress") for r in rows]
    return None if None in values else float(np.mean(values))


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
        "progress": _mean_progress(rows),
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
    return MISSING if entry is None or entry.get("progress") is None else f"{100 * entry['progress']:.1f}%"


def best_methods(methods: list[str], entries: list[dict | None], key: str) -> set[str]:
    """The non-oracle methods with the highest ``key`` (all of them on a tie)."""
    values = {m: e[key] for m, e in zip(methods, entries, strict=True)
              if e is not None and e.get(key) is not None and m != "oracle"}  # fmt: skip
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
    cells = [MISSING if (v := paper_unseen(10, m)) is None else f"{100 * v:.1f}%" for m in methods]
    return ("paper", PAPER_LABEL, cells)


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


# ----------------------------------------------------------------------------------------------- shipped


def weights_text(shipped: dict, version: str = __version__) -> str:
    """The shipped weights by name, step and data: ``gctn-lite (step 21000) + vf-lite (step 3000); tvf
    0.1.0; data a346bb23c13c64a6, 10 demos per training task``."""
    models = shipped.get("models", {})
    names = " + ".join(
        f"{Path(m.get('file', kind)).stem} (step {m.get('step', '?')})" for kind, m in models.items()
    )
    prints = sorted({str(m["data_fingerprint"]) for m in models.values() if m.get("data_fingerprint")})
    demos = shipped.get("experiment", {}).get("demos")
    data = f"; data {', '.join(prints)}" if prints else ""
    data += f", {demos} demos per training task" if demos is not None and data else ""
    return f"{names or 'shipped weights'}; tvf {version}{data}"


def shipped_eval_text(shipped: dict) -> str:
    """How the shipped weights were evaluated: ``20 episodes per task, seeds 1, 3, 5, … (validation)``."""
    exp = shipped.get("experiment", {})
    episodes, start = exp.get("episodes"), exp.get("seed_start")
    if episodes is None or start is None:
        return "the evaluation recorded with them"
    seeds = f"{start}, {start + 2}, {start + 4}, …"
    return f"{episodes} episodes per task, seeds {seeds} ({seed_range(start)} range)"


def plural(n: int, word: str) -> str:
    """``1 episode``, ``5 episodes``."""
    return f"{n} {word}{'' if n == 1 else 's'}"


def shipped_label(shipped: dict) -> str:
    """The row label of the shipped weights' numbers."""
    episodes = shipped.get("experiment", {}).get("episodes")
    return f"shipped weights ({plural(episodes, 'episode')} per task)" if episodes else "shipped weights"


def reported_record(record: dict) -> dict:
    """The shipped record the reports show: the test-range evaluations recorded with the weights
    (``evaluations``, one per method: the entry named by the method's label) in place of the experiment's
    own results, when there are any; the record as it is otherwise."""
    chosen = {}
    for entry in record.get("evaluations", []):
        if entry.get("seed_range") == "test" and entry["name"] == label(entry["method"]):
            chosen[entry["method"]] = entry
    if not chosen:
        return record
    first = next(iter(chosen.values()))
    experiment = {**record.get("experiment", {}), "episodes": first["episodes"]}
    experiment["seed_start"] = first["seed_start"]
    per_task = {m: [_task_cell(t, r) for t, r in e["tasks"].items()] for m, e in chosen.items()}
    results = {m: e["results"] for m, e in chosen.items()}
    return {**record, "experiment": experiment, "results": results, "task_results": per_task}


def _task_cell(task: str, recorded: dict) -> dict:
    """A recorded per-task result as a summary row (success, successes, episodes, Wilson interval,
    progress; records written before the full rows were kept lack the progress: None)."""
    n = recorded["episodes"]
    k = recorded.get("successes", round(recorded["success"] * n))
    return {"task": task, "successes": k, "ci95": list(wilson(k, n)), "progress": None, **recorded}


def shipped_entry(shipped: dict, method: str, split: str) -> dict | None:
    """The shipped weights' recorded average of ``method`` over ``split`` (unseen | train | all), or None."""
    return shipped.get("results", {}).get(method, {}).get(split)


def comparison_rows(summaries: dict[str, dict], shipped: dict | None) -> tuple[list[str], list[Row]]:
    """The claim in one table: for each task group the run has, its average success beside the shipped
    weights' and (unseen tasks) the paper's, one column per method of the run."""
    methods = ordered_methods(summaries)
    groups = task_groups(summaries)
    rows: list[Row] = []
    for split, title, _ in GROUPS[:2]:
        if not groups[split]:
            continue
        entries = [group_average(summaries[m], groups[split]) for m in methods]
        per_task = max((e["episodes"] // max(e["tasks"], 1) for e in entries if e), default=0)
        n, of = len(groups[split]), len(resolve_tasks(split))
        ran = f"this run ({plural(per_task, 'episode')} per task" + (
            f", {n} of the {of} tasks)" if n < of else ")"
        )
        rows.append(("group", f"{title}: average success", [""] * len(methods)))
        rows.append(("run", ran, [success_cell(e) for e in entries]))
        if shipped:
            cells = [success_cell(shipped_entry(shipped, m, split)) for m in methods]
            rows.append(("shipped", shipped_label(shipped), cells))
        if split == "unseen":
            rows.append(paper_row(methods))
    return methods, rows


def shipped_rows(shipped: dict) -> tuple[list[str], list[Row]]:
    """Every method of the shipped weights' recorded evaluation: per task when the record has it
    (``task_results``), and the group averages with their intervals, the paper's under the unseen one."""
    results = shipped.get("results", {})
    methods = ordered_methods(results)
    per_task = shipped.get("task_results")
    if per_task:
        return methods, table_rows({m: {"tasks": per_task.get(m, [])} for m in methods}, "success")
    rows: list[Row] = []
    for split, name in (("unseen", "unseen average"), ("train", "training average"), ("all", "all tasks")):
        entries = [shipped_entry(shipped, m, split) for m in methods]
        if any(entries):
            rows.append(metric_row("average", name, methods, entries, "success"))
        if split == "unseen":
            rows.append(paper_row(methods))
    return methods, rows


# ----------------------------------------------------------------------------------------------- blocks

Block = tuple
"""A piece of the report, rendered alike in Markdown and HTML: ("h2", text), ("note", text),
("meta", dict), ("table", header, rows), ("image", path, caption), ("figures", [(path, caption), ...])."""


def gif_caption(task: str, method: str) -> str:
    kind = "tvf" if method.startswith("tvf") else "other"
    return f"{label(method)} on {task}: {GIF_CAPTIONS[kind]}"


def report_blocks(
    summaries: dict[str, dict], meta: dict, gifs: dict[str, dict[str, str]] | None = None,
    chart: str | None = None, shipped: dict | None = None,
) -> list[Block]:  # fmt: skip
    """The report's content in order; ``gifs`` maps task -> method -> path, paths relative to the report."""
    header = ["task", *(label(m) for m in ordered_methods(summaries))]
    blocks: list[Block] = [("meta", meta)]
    if shipped is not None:
        methods, rows = comparison_rows(summaries, shipped)
        blocks += [("h2", "The comparison"), ("table", ["", *(label(m) for m in methods)], rows),
                   ("note", f"Shipped weights: {shipped_eval_text(shipped)}. " + paper_note())]  # fmt: skip
    if chart:
        blocks += [("image", chart, "success per method")]
    if shipped is not None and shipped.get("results"):
        methods, rows = shipped_rows(shipped)
        note = f"{weights_text(shipped)}; {shipped_eval_text(shipped)}. {TABLE_NOTE}"
        blocks += [("h2", "The shipped weights' recorded evaluation"), ("note", note),
                   ("table", ["", *(label(m) for m in methods)], rows)]  # fmt: skip
    success = table_rows(summaries, "success")
    title = "Success per task" + (" (this run)" if shipped is not None else "")
    blocks += [("h2", title), ("note", TABLE_NOTE), ("table", header, success), ("note", paper_note())]
    if any(c.endswith("\\*") for _, _, cells in success for c in cells):
        blocks.append(("note", PARTIAL_NOTE))
    blocks += [("h2", "Mean progress"), ("note", "Fraction of goal blocks placed at the end of an episode."),
               ("table", header, table_rows(summaries, "progress"))]  # fmt: skip
    episodes = [(t, gifs[t]) for t in task_groups(summaries)["unseen"] if gifs and gifs.get(t)]
    if episodes:
        blocks.append(("h2", "Episodes"))
        for task, by_method in episodes:
            figures = [(by_method[m], gif_caption(task, m)) for m in ordered_methods(by_method)]
            blocks += [("h3", task), ("figures", figures)]
    return blocks


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


def md_block(block: Block) -> list[str]:
    """A block as Markdown lines."""
    kind = block[0]
    if kind == "meta":
        return ["| run | |", "|---|---|"] + [
            f"| {md_text(str(k))} | {md_text(meta_value(v))} |" for k, v in block[1].items()
        ]
    if kind in ("h2", "h3"):
        return [f"{'#' * int(kind[1])} {md_text(block[1])}"]
    if kind == "note":
        return [block[1]]
    if kind == "table":
        return md_table(block[1], block[2])
    if kind == "image":
        return [md_image(block[2], block[1])]
    lines = []
    for path, caption in block[1]:
        lines += [md_image(caption, path), "", f"*{md_text(caption)}*", ""]
    return lines[:-1]


def report_markdown(
    summaries: dict[str, dict], meta: dict, gifs: dict[str, dict[str, str]] | None = None,
    chart: str | None = None, title: str = "TVF experiment", shipped: dict | None = None,
) -> str:  # fmt: skip
    """The report as Markdown; ``gifs`` (task -> method -> path) and ``chart`` are paths relative to it."""
    return markdown_page(title, report_blocks(summaries, meta, gifs, chart, shipped))


def markdown_page(title: str, blocks: list[Block]) -> str:
    """A titled Markdown document of blocks."""
    lines = [f"# {md_text(title)}"]
    for block in blocks:
        lines += ["", *md_block(block)]
    return "\n".join(lines) + "\n"


# ----------------------------------------------------------------------------------------------- HTML

CSS = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1400px; color: #222; padding: 0 1em; }
table { border-collapse: collapse; margin: 1em 0; }
th, td { border: 1px solid #ccc; padding: 0.3em 0.7em; text-align: right; white-space: nowrap; }
th:first-child, td:first-child { text-align: left; }
tr.group td { background: #eef; font-weight: bold; text-align: left; }
tr.average td, tr.paper td, tr.shipped td { background: #f7f7f7; font-style: italic; }
tr.run td { font-weight: bold; }
table.meta td { text-align: left; white-space: normal; }
table.meta td:first-child { font-weight: bold; white-space: nowrap; }
figure { margin: 1em 0; } img { max-width: 100%; }
.episodes { display: flex; flex-wrap: wrap; gap: 1em; align-items: flex-start; }
.episodes figure { flex: 0 1 auto; min-width: 0; margin: 0; display: table; }
.episodes figcaption { display: table-caption; caption-side: bottom; }
figcaption, .note { color: #555; font-size: 0.9em; }
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


def html_block(block: Block) -> list[str]:
    """A block as HTML lines."""
    kind = block[0]
    if kind == "meta":
        rows = [
            f"<tr><td>{html.escape(str(k))}</td><td>{html.escape(meta_value(v))}</td></tr>"
            for k, v in block[1].items()
        ]
        return ['<table class="meta">', *rows, "</table>"]
    if kind in ("h2", "h3"):
        return [f"<{kind}>{html.escape(block[1])}</{kind}>"]
    if kind == "note":
        return [f'<p class="note">{html.escape(block[1].replace(chr(92), ""))}</p>']
    if kind == "table":
        return html_table(block[1], block[2])
    if kind == "image":
        return [html_figure(block[1], block[2])]
    return ['<div class="episodes">', *(html_figure(p, c) for p, c in block[1]), "</div>"]


def report_html(
    summaries: dict[str, dict], meta: dict, gifs: dict[str, dict[str, str]] | None = None,
    chart: str | None = None, title: str = "TVF experiment", shipped: dict | None = None,
) -> str:  # fmt: skip
    """The report as one self-contained HTML page (inline CSS, no scripts, images by relative path)."""
    return html_page(title, report_blocks(summaries, meta, gifs, chart, shipped))


def html_page(title: str, blocks: list[Block]) -> str:
    """A titled, self-contained HTML page of blocks (inline CSS, no scripts, images by relative path)."""
    out = ["<!DOCTYPE html>", '<html lang="en">', "<head>", '<meta charset="utf-8">',
           f"<title>{html.escape(title)}</title>", f"<style>{CSS}</style>", "</head>", "<body>",
           f"<h1>{html.escape(title)}</h1>"]  # fmt: skip
    for block in blocks:
        out += html_block(block)
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


def reference_marks(
    ax, methods: list[str], width: float, values: dict[str, float], name: str, style: str
) -> None:
    """Reference numbers (the paper's, the shipped weights') as short lines with a point over each
    method's slot in the "unseen average" group (x = 0), labelled ``name``."""
    for i, m in enumerate(methods):
        if m not in values:
            continue
        x, y = (i - (len(methods) - 1) / 2) * width, values[m]
        first = not any(line.get_label() == name for line in ax.lines)
        ax.hlines(y, x - width / 2, x + width / 2, colors=style[0], lw=1.5)
        ax.plot([x], [y], style, ms=4, label=name if first else None)
        ax.annotate(name, (x, y), xytext=(0, 4), textcoords="offset points", ha="center", fontsize=7)


def success_chart(summaries: dict[str, dict], path: Path, shipped: dict | None = None) -> Path:
    """Grouped bar chart of success per method (Wilson 95% error bars) with the paper's unseen averages
    (and the shipped weights', when given) as labelled markers; written atomically as a PNG at ``path``."""

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
    paper = {m: v for m in methods if (v := paper_unseen(10, m)) is not None}
    reference_marks(ax, methods, width, paper, "paper", "kD")
    if shipped:
        values = {m: e["success"] for m in methods if (e := shipped_entry(shipped, m, "unseen")) is not None}
        reference_marks(ax, methods, width, values, "shipped", "ro")
    ax.set_xticks(range(len(groups)), [name for name, _ in groups], rotation=30, ha="right", fontsize=8)
    ax.set_ylim(0, 1.3)
    ax.set_ylabel("success (Wilson 95% interval)")
    ax.legend(fontsize=8, ncols=len(methods) + 2, loc="upper center", frameon=False)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    atomic_write_bytes(path, buf.getvalue())
    return Path(path)


# ----------------------------------------------------------------------------------------------- files


def write_report(
    out_dir: Path, summaries: dict[str, dict], meta: dict, gifs: dict[str, dict[str, str]] | None = None,
    title: str = "TVF experiment", shipped: dict | None = None,
) -> tuple[Path, Path]:  # fmt: skip
    """Write ``success.png`` (when any summary has tasks), ``report.md`` and ``report.html`` into
    ``out_dir``, each atomically; ``gifs`` maps task -> method -> path relative to ``out_dir``;
    ``shipped`` is a provenance record whose results go beside the run's."""
    out_dir = Path(out_dir)
    chart = None
    if any(s.get("tasks") for s in summaries.values()):
        success_chart(summaries, out_dir / "success.png", shipped)
        chart = "success.png"
    md, page = out_dir / "report.md", out_dir / "report.html"
    atomic_write_bytes(md, report_markdown(summaries, meta, gifs, chart, title, shipped).encode())
    atomic_write_bytes(page, report_html(summaries, meta, gifs, chart, title, shipped).encode())
    return md, page
