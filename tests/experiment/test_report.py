"""The experiment report: tables, averages by split, the paper row, HTML escaping, written files."""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
import pytest

from tvf.evaluate.closed_loop import summarise, wilson
from tvf.experiment.report import (
    PAPER_UNSEEN_10_DEMOS,
    group_average,
    ordered_methods,
    report_html,
    report_markdown,
    write_report,
)
from tvf.tasks import resolve_tasks

UNSEEN = [t.name for t in resolve_tasks("unseen")]
TRAIN = [t.name for t in resolve_tasks("train")]
ODD = "odd<task>&"
META = {"demos": 10, "preset": "lite", "episodes": 4, "commands": ["tvf eval --method gctn"]}


def episodes(task: str, successes: int, n: int = 4, progress: float = 0.5) -> list[dict]:
    """``n`` synthetic episode records on ``task``, the first ``successes`` of them successful."""
    return [
        {"task": task, "seed": 2 * i + 1, "success": i < successes, "progress": progress} for i in range(n)
    ]


def fake_summaries() -> dict[str, dict]:
    """oracle solves everything; gctn 3/4 on unseen[0]; tvf-large 4/4 there; tvf-large misses unseen[1]."""
    oracle = [r for t in UNSEEN + TRAIN for r in episodes(t, 4, progress=1.0)]
    gctn = episodes(UNSEEN[0], 3) + episodes(UNSEEN[1], 1) + episodes(TRAIN[0], 2) + episodes(ODD, 1)
    tvf = episodes(UNSEEN[0], 4, progress=0.9) + episodes(TRAIN[0], 0, progress=0.1)
    # given out of order, with an unknown method name: it goes last
    return {
        "mine": summarise(episodes(UNSEEN[0], 0), "mine"),
        "tvf-large": summarise(tvf, "tvf-large"),
        "oracle": summarise(oracle, "oracle"),
        "gctn": summarise(gctn, "gctn"),
    }


def md_row(md: str, first_cell: str) -> list[str]:
    """The cells of the first Markdown table row starting with ``first_cell``."""
    for line in md.splitlines():
        cells = [c.strip() for c in line.strip("|").split(" | ")]
        if cells[0] == first_cell:
            return cells[1:]
    raise AssertionError(f"no row {first_cell!r}")


def test_method_order():
    assert ordered_methods(fake_summaries()) == ["oracle", "gctn", "tvf-large", "mine"]
    names = ("tvf-large-paper+rigid", "mine", "tvf-large-paper", "tvf-small+rigid", "gctn")
    ordered = ["gctn", "tvf-small+rigid", "tvf-large-paper", "tvf-large-paper+rigid", "mine"]
    assert ordered_methods({m: {} for m in names}) == ordered  # each method's variants after it


def test_markdown_rows_cells_and_bold():
    md = report_markdown(fake_summaries(), META)
    assert md.startswith("# TVF experiment")
    assert "| preset | lite |" in md and "| demos | 10 |" in md
    for task in UNSEEN + TRAIN:
        assert f"| {task} |" in md
    lo, hi = wilson(3, 4)
    assert f"75.0% [{100 * lo:.0f}–{100 * hi:.0f}]" == "75.0% [30–95]"
    oracle, gctn, tvf, mine = md_row(md, UNSEEN[0])
    assert oracle == "100.0% [51–100]"  # the oracle is never bold
    assert gctn == "75.0% [30–95]" and tvf == "**100.0% [51–100]**" and mine == "0.0% [0–49]"
    assert md_row(md, UNSEEN[1]) == ["100.0% [51–100]", "**25.0% [5–70]**", "–", "–"]
    assert md.index("**Unseen tasks**") < md.index(f"| {UNSEEN[0]} |") < md.index("**Training tasks**")
    assert md.index("**Training tasks**") < md.index(f"| {TRAIN[0]} |") < md.index("**Other tasks**")


def test_group_average_uses_only_the_groups_tasks():
    s = fake_summaries()["gctn"]
    avg = group_average(s, UNSEEN)
    assert avg["success"] == pytest.approx((0.75 + 0.25) / 2)
    assert avg["ci95"] == pytest.approx(list(wilson(4, 8)))
    assert avg["episodes"] == 8 and avg["tasks"] == 2 and avg["progress"] == pytest.approx(0.5)
    assert group_average(s, TRAIN)["success"] == pytest.approx(0.5)
    assert group_average(s, ["nope"]) is None
    md = report_markdown(fake_summaries(), META)
    assert md_row(md, "*unseen average*")[1] == "50.0% [22–78] \\*"  # gctn has 2 of the 8 unseen tasks
    assert md_row(md, "*training average*")[1] == "**50.0% [15–85]** \\*"
    assert md_row(md, "*other average*")[1] == "**25.0% [5–70]**"


def test_paper_row_under_the_unseen_average():
    md = report_markdown(fake_summaries(), META)
    assert md_row(md, "*paper (10 demos)*") == ["–", "55.4%", "78.5%", "–"]
    assert md.index("*unseen average*") < md.index("*paper (10 demos)*") < md.index("*training average*")
    assert PAPER_UNSEEN_10_DEMOS == {"gctn": 0.554, "tvf-small": 0.715, "tvf-large": 0.785}
    assert "GCTN 55.4%, TVF-S 71.5%, TVF-L 78.5%" in md  # the note is written from the same numbers


def test_progress_table_and_images():
    gifs = {
        UNSEEN[0]: {"tvf-large": "gifs/a b.gif", "gctn": "gifs/g.gif"},
        TRAIN[0]: {"gctn": "gifs/train.gif"},
    }
    md = report_markdown(fake_summaries(), META, gifs=gifs, chart="success.png")
    progress = md[md.index("## Mean progress") :]
    assert md_row(progress, UNSEEN[0]) == ["100.0%", "50.0%", "**90.0%**", "50.0%"]
    assert "](<success.png>)" in md and "](<gifs/a b.gif>)" in md
    assert "gifs/train.gif" not in md  # only unseen tasks get an episode
    assert md.index("gifs/g.gif") < md.index("gifs/a b.gif")  # in method order: GCTN, then TVF-L
    assert f"*TVF-L on {UNSEEN[0]}: the real observation (green), the imagined best path" in md
    assert f"*GCTN on {UNSEEN[0]}: the real observation (green) and the goal (grey)" in md


def test_html_is_self_contained_and_escaped():
    page = report_html(fake_summaries(), META, gifs={UNSEEN[0]: {"tvf-large": "x.gif"}}, chart="success.png")
    assert page.startswith("<!DOCTYPE html>") and page.rstrip().endswith("</html>")
    assert "<table" in page and "<style>" in page and "<script" not in page and "http" not in page
    assert "odd&lt;task&gt;&amp;" in page and ODD not in page
    assert "<strong>100.0% [51–100]</strong>" in page
    assert page.count("<tr") == page.count("</tr>") and page.count("<table") == page.count("</table>")
    assert 'src="success.png"' in page and 'src="x.gif"' in page
    assert "odd&lt;task&gt;&amp;" in report_markdown(fake_summaries(), META)


def test_write_report_files(tmp_path):
    md, page = write_report(tmp_path / "rep", fake_summaries(), META, gifs={UNSEEN[0]: {"gctn": "g.gif"}})
    out = tmp_path / "rep"
    assert md == out / "report.md" and page == out / "report.html"
    assert md.read_text().startswith("# TVF experiment") and page.read_text().startswith("<!DOCTYPE html>")
    png = (out / "success.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 1000
    assert "success.png" in md.read_text()
    assert sorted(p.name for p in out.iterdir()) == ["report.html", "report.md", "success.png"]  # no temps


def test_write_report_without_tasks_has_no_chart(tmp_path):
    md, _ = write_report(tmp_path, {"gctn": summarise([], "gctn")}, {})
    assert not (tmp_path / "success.png").exists()
    assert "success.png" not in md.read_text()


# ------------------------------------------------- report numbers recomputed from the episodes they summarise
class CoinEnv:
    """A scripted world: an episode succeeds after one step unless (seed + name length) % modulus == 0;
    a failed episode's progress is (seed % 4) / 4."""

    def __init__(self, task, modulus: int) -> None:
        self.task, self.modulus, self.seed = task, modulus, 0
        self.obs = {"color": np.zeros((4, 4, 3), np.uint8), "height": np.zeros((4, 4), np.float32)}

    def reset(self, *, seed=None, options=None):
        self.seed = seed
        return self.obs, {"goal": self.obs, "progress": 0.0}

    def step(self, action):
        success = (self.seed + len(self.task.name)) % self.modulus != 0
        progress = 1.0 if success else (self.seed % 4) / 4
        info = {"success": success, "progress": progress, "steps": 1, "primitive": "ok"}
        return self.obs, progress, success, not success, info

    def oracle_action(self):
        return np.zeros((2, 4))


@dataclass(frozen=True)
class CoinEnvs:
    modulus: int = 3

    def __call__(self, task):
        return CoinEnv(task, self.modulus)


def _table_cells(md: str, first_cell: str) -> list[list[str]]:
    """The cells (bold marks removed) of every Markdown table row whose first cell is ``first_cell``."""
    rows = []
    for line in md.splitlines():
        cells = [
            c.strip().replace("**", "").removesuffix(" \\*") for c in line.strip().strip("|").split(" | ")
        ]
        if cells[0] == first_cell:
            rows.append(cells[1:])
    return rows


def _expected_cells(records: list[dict]) -> tuple[str, str]:
    k, n = sum(r["success"] for r in records), len(records)
    lo, hi = wilson(k, n)
    progress = np.mean([r["progress"] for r in records])
    return f"{100 * k / n:.1f}% [{100 * lo:.0f}–{100 * hi:.0f}]", f"{100 * progress:.1f}%"


def test_report_numbers_equal_the_episodes_they_summarise(tmp_path):
    """Two evaluations (the scripted world with two failure rules, reported as two methods) through the real
    evaluation and report: every task cell and the unseen average recomputed from episodes.jsonl."""
    from tvf.evaluate.closed_loop import evaluate
    from tvf.policies import PolicySpec

    tasks = [*UNSEEN[:2], TRAIN[0]]
    summaries, logs = {}, {}
    for method, modulus in (("gctn", 3), ("tvf-large", 4)):
        out = tmp_path / method
        summaries[method] = evaluate(PolicySpec("oracle"), tasks, 6, 1, 1, out, envs=CoinEnvs(modulus))
        logs[method] = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
    md_path, _ = write_report(tmp_path / "report", summaries, META)
    md = md_path.read_text()
    methods = list(summaries)
    for task in tasks:
        success_cells, progress_cells = _table_cells(md, task)
        for i, m in enumerate(methods):
            records = [r for r in logs[m] if r["task"] == task]
            assert len(records) == 6
            assert (success_cells[i], progress_cells[i]) == _expected_cells(records), (task, m)
    success_cells, _ = _table_cells(md, "*unseen average*")
    for i, m in enumerate(methods):
        unseen = [r for r in logs[m] if r["task"] in UNSEEN]
        per_task = [np.mean([r["success"] for r in unseen if r["task"] == t]) for t in UNSEEN[:2]]
        lo, hi = wilson(sum(r["success"] for r in unseen), len(unseen))
        assert success_cells[i] == f"{100 * np.mean(per_task):.1f}% [{100 * lo:.0f}–{100 * hi:.0f}]"
    assert any(len(set(_table_cells(md, t)[0])) == 2 for t in tasks)  # the two methods differ somewhere
