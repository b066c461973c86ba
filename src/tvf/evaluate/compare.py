"""Paired comparison of closed-loop evaluations: several ``tvf eval`` folders (or ``tvf ablate`` cells,
or an experiment's evaluations) read on the episodes they share, matched by task and seed.

A lever is judged on the same episodes as its baseline: the episodes both finish or both lose say
nothing about the difference, so the test is the exact two-sided sign test on the others (McNemar's
exact test), the one docs/results.md quotes as "wins W, loses L, p"."""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import asdict, dataclass
from pathlib import Path

from tvf.errors import TvfError
from tvf.evaluate.closed_loop import wilson
from tvf.io import read_json, read_jsonl

Episode = tuple[str, int]
"""An episode's key: (task, seed)."""


@dataclass(frozen=True)
class Run:
    """One evaluation: its label and each episode's success."""

    label: str
    outcomes: dict[Episode, bool]


@dataclass(frozen=True)
class Pair:
    """``other`` against ``base`` on their shared episodes: episodes only ``other`` finishes (wins),
    only ``base`` finishes (losses), and the sign test's two-sided p-value."""

    base: str
    other: str
    wins: int
    losses: int
    p_value: float


def sign_test(wins: int, losses: int) -> float:
    """Exact two-sided sign test of ``wins`` against ``losses`` (ties left out): the probability, under
    a fair coin over the ``wins + losses`` discordant episodes, of a split at least this uneven."""
    if wins < 0 or losses < 0:
        raise ValueError(f"counts must be non-negative, got {wins} and {losses}")
    n = wins + losses
    if n == 0:
        return 1.0
    tail = sum(math.comb(n, i) for i in range(min(wins, losses) + 1)) / 2**n
    return min(1.0, 2 * tail)


def read_run(folder: Path, label: str | None = None) -> Run:
    """The episode outcomes of an evaluation folder (its ``episodes.jsonl``); the label defaults to the
    method of its ``eval.json`` with the settings it overrode, else the folder's name."""
    folder = Path(folder)
    log = folder / "episodes.jsonl"
    if not log.is_file():
        raise TvfError(f"{folder}: no episodes.jsonl; give a folder written by tvf eval, tvf ablate or "
                       "tvf experiment")  # fmt: skip
    outcomes: dict[Episode, bool] = {}
    for record in read_jsonl(log):
        try:
            outcomes[(str(record["task"]), int(record["seed"]))] = bool(record["success"])
        except (KeyError, TypeError, ValueError):
            raise TvfError(f"{log}: a record without task, seed and success; is it an evaluation's "
                           "episode log?") from None  # fmt: skip
    if not outcomes:
        raise TvfError(f"{log}: no finished episodes yet; run or resume the evaluation first")
    return Run(label or _label(folder), outcomes)


def read_runs(folders: list[Path], labels: list[str] | None = None) -> list[Run]:
    """:func:`read_run` of each folder; where the labels would repeat, each run is named by its folder."""
    if labels is not None and len(labels) != len(folders):
        raise TvfError(f"--labels names {len(labels)} runs for {len(folders)} folders; give one label per "
                       "folder")  # fmt: skip
    runs = [read_run(f, labels[i] if labels else None) for i, f in enumerate(folders)]
    if len({r.label for r in runs}) < len(runs):
        runs = [Run(str(f), r.outcomes) for f, r in zip(folders, runs, strict=True)]
    return runs


def _label(folder: Path) -> str:
    """``method [flag=value ...]`` from the folder's ``eval.json`` (the planner settings it set), or the
    folder's name when it has none."""
    meta = read_json(folder / "eval.json", "pass --labels to name the runs", default=None)
    if not isinstance(meta, dict):
        return folder.name
    skip = {"method", "episodes", "seed_start", "step_slack"}
    set_here = {k: v for k, v in meta.items() if k not in skip and v is not None and not isinstance(v, dict)}
    flags = [f"{k}={v}" for k, v in set_here.items()]
    return " ".join([str(meta.get("method", folder.name)), *flags])


def shared_episodes(runs: list[Run]) -> list[Episode]:
    """The episodes every run has, by task in the first run's order, then by seed; an error when there
    are none."""
    common = set.intersection(*(set(r.outcomes) for r in runs))
    if not common:
        raise TvfError("the evaluations share no episode (task and seed); compare runs of the same tasks "
                       "with the same --seed-start")  # fmt: skip
    order = {task: i for i, task in enumerate(dict.fromkeys(task for task, _ in runs[0].outcomes))}
    return sorted(common, key=lambda e: (order[e[0]], e[1]))


def pair(base: Run, other: Run, episodes: list[Episode]) -> Pair:
    """``other`` against ``base`` on ``episodes``."""
    wins = sum(other.outcomes[e] and not base.outcomes[e] for e in episodes)
    losses = sum(base.outcomes[e] and not other.outcomes[e] for e in episodes)
    return Pair(base.label, other.label, wins, losses, sign_test(wins, losses))


def compare(runs: list[Run]) -> dict:
    """Every run's successes per task and overall on the shared episodes (with Wilson 95% intervals),
    and every later run paired against the first."""
    if len(runs) < 2:
        raise TvfError("give at least two evaluation folders to compare")
    episodes = shared_episodes(runs)
    per_task = Counter(task for task, _ in episodes)  # in the episodes' task order
    table = []
    for run in runs:
        successes = Counter(task for task, seed in episodes if run.outcomes[(task, seed)])
        total = sum(successes.values())
        table.append({"label": run.label, "tasks": {t: successes[t] for t in per_task}, "successes": total,
                      "success": total / len(episodes), "ci95": wilson(total, len(episodes))})  # fmt: skip
    pairs = [pair(runs[0], other, episodes) for other in runs[1:]]
    left_out = {run.label: len(run.outcomes) - len(episodes) for run in runs}
    return {"episodes": len(episodes), "per_task": dict(per_task), "runs": table,
            "pairs": [asdict(p) for p in pairs], "left_out": left_out}  # fmt: skip


def comparison_markdown(result: dict) -> str:
    """The comparison as Markdown: runs as rows, tasks as columns, then the paired tests."""
    tasks = list(result["per_task"])
    columns = [f"{t} (of {n})" for t, n in result["per_task"].items()]
    head = ["run", *columns, f"all (of {result['episodes']})"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in result["runs"]:
        lo, hi = row["ci95"]
        cells = [row["label"], *(str(row["tasks"][t]) for t in tasks),
                 f"**{row['successes']}** ({row['success']:.1%} [{lo:.0%}–{hi:.0%}])"]  # fmt: skip
        lines.append("| " + " | ".join(cells) + " |")
    lines += ["", "| against the first run | wins | losses | sign test, two-sided p |", "|---|---|---|---|"]
    for p in result["pairs"]:
        lines.append(f"| {p['other']} | {p['wins']} | {p['losses']} | {p['p_value']:.3g} |")
    dropped = {label: n for label, n in result["left_out"].items() if n}
    if dropped:
        notes = ", ".join(f"{label}: {n}" for label, n in dropped.items())
        lines += ["", f"Episodes left out because not every run has them: {notes}."]
    return "\n".join(lines) + "\n"
