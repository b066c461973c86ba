"""The K x depth ablation of the TVF planner (the paper's Table: K in {2, 3} x d in {1, 2, 3, 4}).

Every cell is one closed-loop evaluation (:func:`tvf.evaluate.closed_loop.evaluate`, resumable) of the
same models on the same episodes with another branching K and depth, in ``OUT/k{K}-d{D}``. The grid is
summarised as ``OUT/ablation.json``, ``OUT/ablation.md`` (success per group with Wilson 95% intervals)
and a heat map per task group, ``OUT/ablation.png``.
"""

from __future__ import annotations

import io
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from tvf.errors import TvfError
from tvf.evaluate.closed_loop import evaluate
from tvf.experiment.report import group_average, plural, success_cell, task_groups
from tvf.io import atomic_write_bytes, atomic_write_json
from tvf.policies import PLANNER_METHODS, PolicySpec, foresight_of, planner_of
from tvf.tasks import Task

PAPER_CELLS = {(3, 3): 0.785, (2, 1): 0.715}
"""The paper's unseen-task averages at 10 demos for its two named planners (TVF-L, TVF-S); it reports
the rest of its grid only as a figure (tvf-facts §8)."""


def parse_grid(text: str, name: str) -> tuple[int, ...]:
    """``"2,3"`` -> (2, 3): distinct positive integers in the order given; a one-line error otherwise."""
    try:
        values = tuple(dict.fromkeys(int(v) for v in text.split(",") if v.strip()))
    except ValueError:
        raise TvfError(f"--{name} takes comma-separated whole numbers such as 1,2,3, got {text!r}") from None
    if not values or min(values) < 1:
        raise TvfError(f"--{name} needs at least one value, each at least 1, got {text!r}")
    return values


def cell_dir(out: Path, k: int, depth: int) -> Path:
    return Path(out) / f"k{k}-d{depth}"


def ablation_cells(spec: PolicySpec, ks: Sequence[int], depths: Sequence[int]) -> list[PolicySpec]:
    """The spec of every (K, depth) cell, K-major; a method that does not search or a bad cell is refused."""
    if spec.method not in PLANNER_METHODS:
        choices = ", ".join(PLANNER_METHODS)
        raise TvfError(f"the ablation varies the search: --method must be one of {choices}")
    cells = [replace(spec, k=k, depth=d) for k in ks for d in depths]
    for cell in cells:
        planner_of(cell)
    return cells


def run_ablation(
    spec: PolicySpec, ks: Sequence[int], depths: Sequence[int], tasks: Sequence[Task], episodes: int,
    seed_start: int, workers: int, out: Path, step_slack: int = 0,
    say: Callable[[str], None] = print,
) -> dict:  # fmt: skip
    """Evaluate ``spec`` at every (K, depth) of the grid (each cell resumes) and write the summary files."""
    cells = ablation_cells(spec, ks, depths)
    summaries = {}
    for i, cell in enumerate(cells, 1):
        say(f"ablation cell {i} of {len(cells)}: K={cell.k}, depth={cell.depth}")
        summaries[(cell.k, cell.depth)] = evaluate(
            cell, tasks, episodes, seed_start, workers, cell_dir(out, cell.k, cell.depth), step_slack
        )
    seen = foresight_of(spec)
    return write_ablation(out, summaries, spec.method if seen == "vf" else f"{spec.method}, {seen} foresight")


def grid_entries(summaries: dict[tuple[int, int], dict]) -> dict[str, dict[tuple[int, int], dict | None]]:
    """Per task group present (unseen, train, other, all), the group average of every cell."""
    groups = task_groups({f"k{k}-d{d}": s for (k, d), s in summaries.items()})
    if sum(1 for names in groups.values() if names) > 1:
        groups["all"] = [t for names in groups.values() for t in names]
    return {
        name: {cell: group_average(s, tasks) for cell, s in summaries.items()}
        for name, tasks in groups.items()
        if tasks
    }


def ablation_markdown(summaries: dict[tuple[int, int], dict], method: str) -> str:
    """One table per task group: rows K, columns depth, cells success [Wilson 95%]."""
    ks = sorted({k for k, _ in summaries})
    depths = sorted({d for _, d in summaries})
    lines = [f"# K x depth ablation ({method})", ""]
    for group, entries in grid_entries(summaries).items():
        n = next(e["episodes"] for e in entries.values() if e is not None)
        lines += [f"## {group} tasks ({plural(n, 'episode')} per cell)", "",
                  "| K \\ depth | " + " | ".join(str(d) for d in depths) + " |",
                  "|---" * (len(depths) + 1) + "|"]  # fmt: skip
        for k in ks:
            lines.append(f"| {k} | " + " | ".join(success_cell(entries.get((k, d))) for d in depths) + " |")
        if group == "unseen":
            paper = ", ".join(f"K={k}, d={d}: {v:.1%}" for (k, d), v in PAPER_CELLS.items())
            lines += ["", f"The paper (10 demos, unseen tasks): {paper}."]
        lines.append("")
    return "\n".join(lines)


def _rate(entry: dict | None) -> float:
    return entry["success"] if entry is not None else float("nan")


def heat_map(summaries: dict[tuple[int, int], dict], path: Path, method: str) -> Path:
    """One panel per task group: success per (K, depth) as colour, with the rate and interval written in."""
    ks = sorted({k for k, _ in summaries})
    depths = sorted({d for _, d in summaries})
    groups = [(g, e) for g, e in grid_entries(summaries).items() if g in ("unseen", "train")] or list(
        grid_entries(summaries).items()
    )[:1]
    fig = Figure(figsize=(1.3 + 1.6 * len(depths) * len(groups), 1.2 + 0.8 * len(ks)), dpi=110)
    FigureCanvasAgg(fig)
    for i, (group, entries) in enumerate(groups):
        ax = fig.add_subplot(1, len(groups), i + 1)
        values = np.array([[_rate(entries.get((k, d))) for d in depths] for k in ks])
        image = ax.imshow(values, vmin=0, vmax=1, cmap="viridis", aspect="auto")
        for r, k in enumerate(ks):
            for c, d in enumerate(depths):
                entry = entries.get((k, d))
                if entry is not None:
                    lo, hi = entry["ci95"]
                    text = f"{entry['success']:.0%}\n[{lo:.0%}–{hi:.0%}]"
                    ax.text(c, r, text, ha="center", va="center", fontsize=7,
                            color="black" if entry["success"] > 0.6 else "white")  # fmt: skip
        ax.set_xticks(range(len(depths)), [str(d) for d in depths])
        ax.set_yticks(range(len(ks)), [str(k) for k in ks])
        ax.set_xlabel("depth d")
        ax.set_ylabel("proposals K")
        ax.set_title(f"{method}: {group} tasks", fontsize=9)
        fig.colorbar(image, ax=ax, fraction=0.05, label="success")
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png")
    atomic_write_bytes(path, buf.getvalue())
    return Path(path)


def write_ablation(out: Path, summaries: dict[tuple[int, int], dict], method: str) -> dict:
    """``ablation.json`` (every cell's group averages and task rows), ``ablation.md``, ``ablation.png``."""
    out = Path(out)
    record = {
        "method": method,
        "cells": [
            {
                "k": k,
                "depth": d,
                "groups": {g: e[(k, d)] for g, e in grid_entries(summaries).items()},
                "tasks": s["tasks"],
            }  # fmt: skip
            for (k, d), s in summaries.items()
        ],
        "paper_unseen": [{"k": k, "depth": d, "success": v} for (k, d), v in PAPER_CELLS.items()],
    }
    atomic_write_json(out / "ablation.json", record)
    atomic_write_bytes(out / "ablation.md", ablation_markdown(summaries, method).encode())
    heat_map(summaries, out / "ablation.png", method)
    return record
