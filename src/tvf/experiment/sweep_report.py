"""The sweep's report: success against demonstrations, over training seeds, next to the paper's numbers.

Input: each cell's summaries, ``OUT/demos-N/seed-S/eval/METHOD/summary.json`` (as
:func:`tvf.evaluate.closed_loop.summarise` writes them). For every (demos, method) and task group a
seed's success is its group average (the mean per-task success, as in the experiment report); the
report gives the mean of the seeds' values, their standard deviation (n - 1 in the denominator; none
for one seed) and range, and the Wilson 95% interval of every episode of the group over all seeds
pooled. Cells not finished are "–", so the report can be re-made at any time. Each cell's
``cost.jsonl`` (:mod:`tvf.experiment.cost`) gives the cost table: CPU hours per stage and cell.
"""

from __future__ import annotations

import io
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from tvf.evaluate.closed_loop import wilson
from tvf.experiment.config import STAGES
from tvf.experiment.cost import hours, stage_costs
from tvf.experiment.report import (
    MISSING,
    PAPER_TASKS_10_DEMOS,
    PAPER_UNSEEN,
    Block,
    Row,
    evaluated_methods,
    html_page,
    markdown_page,
    ordered_methods,
    paper_unseen,
    plural,
    task_groups,
    task_row,
)
from tvf.io import atomic_write_bytes
from tvf.policies import label, paper_method

Cells = dict[tuple[int, int], dict[str, dict]]
"""(demos, seed) -> method -> summary."""
CHART = "success-vs-demos.png"
GROUP_TITLES = {"unseen": "unseen tasks", "train": "training tasks", "other": "other tasks"}
SPREAD_NOTE = (
    "A seed's success is its average over the group's tasks. mean: over the training seeds finished so "
    "far; std: their standard deviation in points (n − 1 in the denominator; – for one seed); min–max: "
    "their range; pooled: every episode of every seed together, with its Wilson 95% interval and the "
    "number of episodes. \\* a seed was evaluated on part of the group only."
)
CELLS_NOTE = "Each cell's unseen-task average per method (its own report.md has the rest)."
COST_NOTE = (
    "CPU hours per stage of each cell (its processes' and their workers' user + system time, summed over "
    "every run of the stage, resumed pieces and interrupted ones included), then the cell's total and its "
    "wall-clock hours; from each cell's cost.jsonl. A run killed without notice (SIGKILL), work on other "
    "machines (--backend ray) and runs from before tvf kept the log are not counted (–: none recorded)."
)
TASK_NOTE = (
    "Mean over seeds, (min–max over seeds) when there are several, [Wilson 95% interval of the pooled "
    "episodes], in percent."
)


@dataclass(frozen=True)
class Aggregate:
    """One (demos, method, tasks) entry over the seeds that have it."""

    seeds: tuple[int, ...]
    values: tuple[float, ...]
    """Each seed's success (mean over the tasks it has)."""
    successes: int
    episodes: int
    partial: bool
    """Some seed has only part of the tasks."""

    @property
    def mean(self) -> float:
        return float(np.mean(self.values))

    @property
    def std(self) -> float | None:
        return float(np.std(self.values, ddof=1)) if len(self.values) > 1 else None

    @property
    def ci95(self) -> tuple[float, float]:
        return wilson(self.successes, self.episodes)

    @property
    def pooled(self) -> float:
        return self.successes / self.episodes


def read_cells(out: Path, demos: list[int], seeds: list[int], methods: list[str]) -> Cells:
    """The summaries on disk of every (demos, seed) of the grid (cells or methods without one are absent)."""
    cells: Cells = {}
    for n in demos:
        for s in seeds:
            found = {}
            for m in methods:
                path = Path(out) / f"demos-{n}" / f"seed-{s}" / "eval" / m / "summary.json"
                if path.is_file():
                    found[m] = json.loads(path.read_text())
            if found:
                cells[(n, s)] = found
    return cells


def aggregate(cells: Cells, demos: int, method: str, tasks: list[str]) -> Aggregate | None:
    """``method`` at ``demos`` over ``tasks``, every seed that has a row of them; None when none has."""
    seeds, values, k, n, partial = [], [], 0, 0, False
    for (d, seed), summaries in sorted(cells.items()):
        if d != demos or method not in summaries:
            continue
        rows = [r for r in (task_row(summaries[method], t) for t in tasks) if r is not None]
        if not rows:
            continue
        seeds.append(seed)
        values.append(float(np.mean([r["success"] for r in rows])))
        k += sum(r["successes"] for r in rows)
        n += sum(r["episodes"] for r in rows)
        partial |= len(rows) < len(tasks)
    return Aggregate(tuple(seeds), tuple(values), k, n, partial) if seeds else None


def sweep_groups(cells: Cells) -> dict[str, list[str]]:
    """The task groups (unseen, train, other) of every summary of every cell."""
    flat = {f"{d}/{s}/{m}": summary for (d, s), by in cells.items() for m, summary in by.items()}
    return task_groups(flat)


def pct(value: float) -> str:
    return f"{100 * value:.1f}%"


def spread_cells(entry: Aggregate | None, n_seeds: int) -> list[str]:
    """seeds, mean, std, min–max, pooled [Wilson] of one entry ("–" where it has none)."""
    if entry is None:
        return [f"0 of {n_seeds}", MISSING, MISSING, MISSING, MISSING]
    lo, hi = entry.ci95
    star = " \\*" if entry.partial else ""
    return [
        f"{len(entry.seeds)} of {n_seeds}",
        pct(entry.mean) + star,
        MISSING if entry.std is None else f"{100 * entry.std:.1f}",
        f"{100 * min(entry.values):.1f}–{100 * max(entry.values):.1f}%",
        f"{pct(entry.pooled)} [{100 * lo:.0f}–{100 * hi:.0f}] of {entry.episodes}",
    ]


def group_table(cells: Cells, demos: list[int], seeds: list[int], methods: list[str], tasks: list[str],
                paper: bool) -> tuple[list[str], list[Row]]:  # fmt: skip
    """One row per (demos, method) under a row per demo count; the paper's number last when ``paper``."""
    header = ["demos per task / method", "seeds", "mean", "std", "min–max", "pooled [Wilson 95%]"]
    header += ["paper"] if paper else []
    rows: list[Row] = []
    for n in demos:
        rows.append(("group", plural(n, "demo"), [""] * (len(header) - 1)))
        for m in methods:
            cells_ = spread_cells(aggregate(cells, n, m, tasks), len(seeds))
            if paper:
                value = paper_unseen(n, m)
                cells_.append(MISSING if value is None else pct(value))
            rows.append(("task", label(m), cells_))
    return header, rows


def task_cell(entry: Aggregate | None) -> str:
    """``55.0% (50.0–60.0) [36–73]``: mean over seeds, their range (several seeds), pooled Wilson."""
    if entry is None:
        return MISSING
    lo, hi = entry.ci95
    spread = (
        f" ({100 * min(entry.values):.1f}–{100 * max(entry.values):.1f})" if len(entry.values) > 1 else ""
    )
    return f"{pct(entry.mean)}{spread} [{100 * lo:.0f}–{100 * hi:.0f}]"


def paper_task_cell(demos: int, task: str, methods: list[str]) -> str:
    """The paper's per-task numbers (10 demos only), ``GCTN 86.7%, TVF-L 100.0%``, or "–"."""
    values = PAPER_TASKS_10_DEMOS.get(task, {}) if demos == 10 else {}
    named = dict.fromkeys(p for m in methods if (p := paper_method(m)) in values)  # once per paper method
    return ", ".join(f"{label(p)} {pct(values[p])}" for p in named) or MISSING


def task_table(cells: Cells, demos: int, methods: list[str], groups: dict[str, list[str]]) -> list[Row]:
    """Per task (grouped), one cell per method; the paper's per-task numbers in the last column."""
    rows: list[Row] = []
    for split, tasks in groups.items():
        if tasks:
            rows.append(("group", GROUP_TITLES[split].capitalize(), [""] * (len(methods) + 1)))
        for t in tasks:
            cells_ = [task_cell(aggregate(cells, demos, m, [t])) for m in methods]
            rows.append(("task", t, [*cells_, paper_task_cell(demos, t, methods)]))
    return rows


def cells_table(cells: Cells, demos: list[int], seeds: list[int], methods: list[str], unseen: list[str]
                ) -> list[Row]:  # fmt: skip
    """Every cell of the grid: its folder and each method's unseen average (–: not evaluated yet)."""
    rows: list[Row] = []
    for n in demos:
        for s in seeds:
            found = cells.get((n, s), {})
            values = [task_cell(aggregate({(n, s): found}, n, m, unseen)) for m in methods]
            rows.append(("task", f"demos-{n}/seed-{s}", values))
    return rows


def cost_table(out: Path, demos: list[int], seeds: list[int]) -> list[Row]:
    """CPU hours per stage of every cell that has a cost log, its total and wall hours, and a total row
    over those cells ([] when none has one)."""
    rows: list[Row] = []
    total = dict.fromkeys((*STAGES, "cpu", "wall"), 0.0)
    for n in demos:
        for s in seeds:
            costs = stage_costs(Path(out) / f"demos-{n}" / f"seed-{s}")
            if not costs:
                continue
            cpu = sum(c["cpu_s"] for c in costs.values())
            wall = sum(c["wall_s"] for c in costs.values())
            for stage, c in costs.items():
                total[stage] = total.get(stage, 0.0) + c["cpu_s"]
            total["cpu"] += cpu
            total["wall"] += wall
            cells = [hours(costs[st]["cpu_s"]) if st in costs else "–" for st in STAGES]
            rows.append(("task", f"demos-{n}/seed-{s}", [*cells, hours(cpu), hours(wall)]))
    if rows:
        cells = [hours(total[st]) for st in STAGES]
        rows.append(("average", "all cells", [*cells, hours(total["cpu"]), hours(total["wall"])]))
    return rows


def named_methods(settings: dict) -> list[str]:
    """The methods the sweep's commands named (``settings["methods"]``), in report order."""
    return ordered_methods(dict.fromkeys(m for m in settings.get("methods", "").split(",") if m))


def sweep_methods(out: Path, demos: list[int], seeds: list[int], settings: dict) -> list[str]:
    """The methods named, then every other method evaluated in some cell (a command with other --methods
    adds rows to the report, it does not take any away)."""
    found = [m for n in demos for s in seeds for m in evaluated_methods(out / f"demos-{n}/seed-{s}/eval")]
    return ordered_methods(dict.fromkeys([*named_methods(settings), *found]))


def sweep_blocks(cells: Cells, demos: list[int], seeds: list[int], settings: dict, commands: list[str],
                 chart: str | None, methods: list[str] | None = None, out: Path | None = None
                 ) -> list[Block]:  # fmt: skip
    """The report's content in order (rendered alike as Markdown and HTML by tvf.experiment.report), one
    row per method of ``methods`` (default: those named in ``settings``); with the sweep's folder
    ``out``, also what each cell cost."""
    named = named_methods(settings)
    methods = methods or named
    groups = sweep_groups(cells)
    done = sum(1 for n in demos for s in seeds if set(named) <= set(cells.get((n, s), {})))
    meta = {"preset": settings.get("preset"), "demos per training task": ", ".join(map(str, demos)),
            "training seeds": ", ".join(map(str, seeds)),
            "episodes per task and method": settings.get("episodes"),
            "cells finished": f"{done} of {len(demos) * len(seeds)}"}  # fmt: skip
    if commands:
        meta["commands"] = "; ".join(commands)
    blocks: list[Block] = [("meta", meta)]
    if chart:
        blocks.append(("image", chart, "success against demonstrations per task, with the paper's curves"))
    for split in ("unseen", "train", "other"):
        if groups[split] or split == "unseen":
            header, rows = group_table(cells, demos, seeds, methods, groups[split], split == "unseen")
            title = f"Success on the {GROUP_TITLES[split]}"
            note = SPREAD_NOTE + (
                " The paper: full-size networks, one number per cell." if split == "unseen" else ""
            )
            blocks += [("h2", title), ("note", note), ("table", header, rows)]
    rows = cells_table(cells, demos, seeds, methods, groups["unseen"])
    blocks += [("h2", "Cells"), ("note", CELLS_NOTE), ("table", ["cell", *(label(m) for m in methods)], rows)]
    costs = cost_table(out, demos, seeds) if out is not None else []
    if costs:
        header = ["cell", *(f"{st} (CPU h)" for st in STAGES), "total CPU h", "wall h"]
        blocks += [("h2", "Cost"), ("note", COST_NOTE), ("table", header, costs)]
    for n in demos:
        if any(d == n for d, _ in cells):
            header = ["task", *(label(m) for m in methods), "paper"]
            blocks += [("h2", f"Per task, {plural(n, 'demo')}"), ("note", TASK_NOTE),
                       ("table", header, task_table(cells, n, methods, groups))]  # fmt: skip
    return blocks


VARIANT_STYLES = (("-", "o"), (":", "s"), ("-.", "^"))
"""Line and marker of the first, second, ... method that runs one paper method (ours, the paper's rules)."""


def method_styles(methods: list[str]) -> dict[str, tuple[str, str, str]]:
    """Colour, line style and marker per method: one colour per paper method (its paper curve shares it),
    a line style per variant of it."""
    families = list(dict.fromkeys(paper_method(m) or m for m in methods))
    styles, seen = {}, {}
    for m in methods:
        family = paper_method(m) or m
        k = seen[family] = seen.get(family, -1) + 1
        styles[m] = (f"C{families.index(family)}", *VARIANT_STYLES[k % len(VARIANT_STYLES)])
    return styles


def success_vs_demos(cells: Cells, demos: list[int], methods: list[str], path: Path) -> Path:
    """Success against demos per task (log scale) for each task group with results: ours as the mean
    over seeds with the pooled Wilson interval and each seed as a dot, the paper's as dashed curves."""
    groups = sweep_groups(cells)
    panels = [s for s in ("unseen", "train") if groups[s]] or ["unseen"]
    fig = Figure(figsize=(5.6 * len(panels), 5.0), dpi=110)
    FigureCanvasAgg(fig)
    shown = [m for m in methods if m != "oracle"] or methods
    styles = method_styles(shown)
    for i, split in enumerate(panels):
        ax = fig.add_subplot(1, len(panels), i + 1)
        drawn: set[str] = set()  # the paper's curves, once per paper method
        for m in shown:
            colour, line, marker = styles[m]
            entries = [(n, e) for n in demos if (e := aggregate(cells, n, m, groups[split])) is not None]
            if entries:
                xs = [n for n, _ in entries]
                ys = [e.mean for _, e in entries]
                err = [[max(0.0, e.mean - e.ci95[0]) for _, e in entries],
                       [max(0.0, e.ci95[1] - e.mean) for _, e in entries]]  # fmt: skip
                ax.errorbar(xs, ys, yerr=err, color=colour, ls=line, marker=marker, capsize=3, label=label(m))
                dots = [(n, v) for n, e in entries for v in e.values]
                ax.plot([n for n, _ in dots], [v for _, v in dots], ".", color=colour, alpha=0.5, ms=4)
            paper = sorted((n, v) for n in PAPER_UNSEEN if (v := paper_unseen(n, m)) is not None)
            if split == "unseen" and paper and paper_method(m) not in drawn:
                drawn.add(paper_method(m))
                ax.plot([n for n, _ in paper], [v for _, v in paper], "--", marker="D", mfc="none",
                        color=colour, alpha=0.8, label=f"{label(paper_method(m))}, paper")  # fmt: skip
        ticks = sorted({*demos, *(PAPER_UNSEEN if split == "unseen" else ())})
        ax.set_xscale("log")
        ax.set_xticks(ticks, [str(t) for t in ticks])
        ax.set_ylim(0, 1.05)
        ax.set_xlabel("demonstrations per training task")
        ax.set_ylabel("success (mean over seeds, Wilson 95%)")
        ax.set_title(GROUP_TITLES[split], fontsize=9)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncols=3, frameon=False)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    atomic_write_bytes(path, buf.getvalue())
    return Path(path)


def sweep_title(settings: dict, demos: list[int], seeds: list[int]) -> str:
    counts, runs = "/".join(map(str, demos)), ", ".join(map(str, seeds))
    return f"tvf sweep: {settings.get('preset')} models, {counts} demos per training task, seeds {runs}"


def write_sweep_report(out: Path, demos: list[int], seeds: list[int], settings: dict, commands: list[str]
                       ) -> tuple[Path, Path]:  # fmt: skip
    """Write OUT/success-vs-demos.png (when a cell has results), OUT/sweep.md and OUT/sweep.html."""
    out = Path(out)
    methods = sweep_methods(out, demos, seeds, settings)
    cells = read_cells(out, demos, seeds, methods)
    chart = None
    if cells:
        success_vs_demos(cells, demos, methods, out / CHART)
        chart = CHART
    blocks = sweep_blocks(cells, demos, seeds, settings, commands, chart, methods, out)
    title = sweep_title(settings, demos, seeds)
    md, page = out / "sweep.md", out / "sweep.html"
    atomic_write_bytes(md, markdown_page(title, blocks).encode())
    atomic_write_bytes(page, html_page(title, blocks).encode())
    return md, page
