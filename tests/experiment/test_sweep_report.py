"""The sweep report on synthetic cells: every number of the tables recomputed by hand."""

from __future__ import annotations

import json

import numpy as np
import pytest

from tvf.evaluate.closed_loop import summarise, wilson
from tvf.experiment.report import PAPER_TASKS_10_DEMOS, PAPER_UNSEEN, PAPER_UNSEEN_10_DEMOS, paper_unseen
from tvf.experiment.sweep_report import (
    aggregate,
    method_styles,
    paper_task_cell,
    read_cells,
    write_sweep_report,
)
from tvf.tasks import resolve_tasks

UNSEEN = [t.name for t in resolve_tasks("unseen")]
TRAIN = [t.name for t in resolve_tasks("train")]
SETTINGS = {"preset": "smoke", "methods": "oracle,gctn,tvf-large", "episodes": 10}


def records(task: str, successes: int, n: int = 10) -> list[dict]:
    return [{"task": task, "seed": 2 * i + 1, "success": i < successes, "progress": 0.5} for i in range(n)]


def write_summary(out, demos: int, seed: int, method: str, wins: dict[str, int]) -> None:
    """A cell's summary.json with ``wins[task]`` successes of 10 episodes per task."""
    rows = [r for task, k in wins.items() for r in records(task, k)]
    path = out / f"demos-{demos}" / f"seed-{seed}" / "eval" / method / "summary.json"
    path.parent.mkdir(parents=True)
    path.write_text(json.dumps(summarise(rows, method)))


@pytest.fixture
def sweep(tmp_path):
    """demos 1 and 10, seeds 0, 1, 2; gctn everywhere but (10, 2); tvf-large at 10 demos, seed 0 on
    only one unseen task; demos 100 planned, nothing finished."""
    gctn = {
        (1, 0): {UNSEEN[0]: 0, UNSEEN[1]: 1, TRAIN[0]: 5},
        (1, 1): {UNSEEN[0]: 2, UNSEEN[1]: 1, TRAIN[0]: 7},
        (1, 2): {UNSEEN[0]: 3, UNSEEN[1]: 0, TRAIN[0]: 9},
        (10, 0): {UNSEEN[0]: 6, UNSEEN[1]: 4, TRAIN[0]: 10},
        (10, 1): {UNSEEN[0]: 8, UNSEEN[1]: 6, TRAIN[0]: 10},
    }
    for (d, s), wins in gctn.items():
        write_summary(tmp_path, d, s, "gctn", wins)
    write_summary(tmp_path, 10, 0, "tvf-large", {UNSEEN[0]: 9})
    write_summary(tmp_path, 10, 1, "tvf-large", {UNSEEN[0]: 10, UNSEEN[1]: 7})
    return tmp_path


def cells(md: str, first: str, after: str = "") -> list[str]:
    """The cells of the first Markdown table row starting with ``first`` (after the text ``after``)."""
    for line in md[md.index(after) :].splitlines():
        parts = [c.strip() for c in line.strip().strip("|").split(" | ")]
        if parts[0] == first:
            return parts[1:]
    raise AssertionError(f"no row {first!r} after {after!r}")


def test_the_paper_table_is_in_one_place():
    assert sorted(PAPER_UNSEEN) == [1, 10, 100, 1000]
    assert PAPER_UNSEEN[1000] == {"gctn": 0.542, "tvf-small": 0.725, "tvf-large": 0.856}
    assert PAPER_UNSEEN_10_DEMOS is PAPER_UNSEEN[10]
    assert PAPER_TASKS_10_DEMOS["put-plane"] == {"gctn": 0.867, "tvf-large": 1.0}


def test_a_paper_rules_row_shares_the_papers_number_colour_and_cell():
    assert paper_unseen(100, "tvf-large-paper") == paper_unseen(100, "tvf-large") == 0.717
    assert paper_unseen(10, "oracle") is None and paper_unseen(3, "gctn") is None
    styles = method_styles(["gctn", "tvf-large", "gctn-paper", "tvf-large-paper", "mine"])
    assert styles["gctn"] == ("C0", "-", "o") and styles["gctn-paper"] == ("C0", ":", "s")
    assert styles["tvf-large"][0] == styles["tvf-large-paper"][0] == "C1" and styles["mine"][0] == "C2"
    rows = method_styles(["tvf-small", "tvf-small-paper", "tvf-small-no-image-rules"])  # a third variant
    assert rows["tvf-small-no-image-rules"] == ("C0", "-.", "^")
    assert paper_unseen(10, "tvf-small-no-image-rules") == paper_unseen(10, "tvf-small")
    assert paper_unseen(1000, "tvf-large-paper+rigid") == 0.856  # a foresight variant: its method's number
    rigid = method_styles(["tvf-large-paper", "tvf-large-paper+rigid"])
    assert rigid["tvf-large-paper+rigid"] == ("C0", ":", "s")  # its method's colour, a line of its own
    both = paper_task_cell(10, "put-plane", ["gctn", "gctn-paper", "tvf-large-paper"])
    assert both == "GCTN 86.7%, TVF-L 100.0%"  # each paper number once


def test_aggregate_over_seeds(sweep):
    found = read_cells(sweep, [1, 10, 100], [0, 1, 2], ["gctn", "tvf-large"])
    assert sorted(found) == [(1, 0), (1, 1), (1, 2), (10, 0), (10, 1)]
    a = aggregate(found, 1, "gctn", UNSEEN[:2])  # the unseen tasks the cells have
    assert a.seeds == (0, 1, 2)
    assert a.values == pytest.approx((0.05, 0.15, 0.15))  # each seed: mean over its two unseen tasks
    assert a.mean == pytest.approx(0.35 / 3)
    assert a.std == pytest.approx(np.std([0.05, 0.15, 0.15], ddof=1))
    assert (a.successes, a.episodes) == (7, 60) and a.ci95 == wilson(7, 60) and not a.partial
    t = aggregate(found, 10, "tvf-large", UNSEEN[:2])
    assert t.values == pytest.approx((0.9, 0.85)) and t.partial and (t.successes, t.episodes) == (26, 30)
    one = aggregate(found, 10, "tvf-large", [UNSEEN[1]])
    assert one.seeds == (1,) and one.std is None
    assert aggregate(found, 100, "gctn", UNSEEN) is None
    assert aggregate(found, 1, "tvf-large", UNSEEN) is None


def test_markdown_tables(sweep):
    md_path, html_path = write_sweep_report(sweep, [1, 10, 100], [0, 1, 2], SETTINGS, ["tvf experiment x"])
    md = md_path.read_text()
    assert md.startswith("# tvf sweep: smoke models, 1/10/100 demos per training task, seeds 0, 1, 2")
    assert "| cells finished | 0 of 9 |" in md  # no cell has every method (oracle never ran)
    unseen = "## Success on the unseen tasks"
    lo, hi = wilson(7, 60)
    spread = np.std([0.05, 0.15, 0.15], ddof=1)
    pooled = f"11.7% [{100 * lo:.0f}–{100 * hi:.0f}] of 60"
    row = ["3 of 3", "11.7%", f"{100 * spread:.1f}", "5.0–15.0%", pooled, "1.3%"]
    assert cells(md, "GCTN", unseen) == row
    after10 = md.index("**10 demos**", md.index(unseen))
    lo, hi = wilson(24, 40)
    pooled = f"60.0% [{100 * lo:.0f}–{100 * hi:.0f}] of 40"
    assert cells(md[after10:], "GCTN") == ["2 of 3", "60.0%", "14.1", "50.0–70.0%", pooled, "55.4%"]
    assert cells(md[after10:], "TVF-L")[1] == "87.5% \\*"  # seed 0 has one of the unseen tasks
    assert cells(md[after10:], "TVF-L")[-1] == "78.5%"
    after100 = md.index("**100 demos**", md.index(unseen))
    assert cells(md[after100:], "GCTN") == ["0 of 3", "–", "–", "–", "–", "49.0%"]
    assert cells(md[after100:], "oracle")[-1] == "–"
    train = md[md.index("## Success on the training tasks") :]
    assert cells(train, "GCTN")[:4] == ["3 of 3", "70.0%", "20.0", "50.0–90.0%"]
    assert "paper" not in train.splitlines()[4]  # no paper column for the training tasks
    assert cells(md, "demos-10/seed-2", "## Cells") == ["–", "–", "–"]
    lo, hi = wilson(14, 20)
    assert (
        cells(md, UNSEEN[0], "## Per task, 10 demos")[1]
        == f"70.0% (60.0–80.0) [{100 * lo:.0f}–{100 * hi:.0f}]"
    )
    assert "## Per task, 100 demos" not in md
    put_plane = cells(md, "put-plane", "## Per task, 10 demos")
    assert put_plane[-1] == "GCTN 86.7%, TVF-L 100.0%" and put_plane[0] == "–"
    page = html_path.read_text()
    assert (
        page.startswith("<!DOCTYPE html>") and "<script" not in page and 'src="success-vs-demos.png"' in page
    )
    png = (sweep / "success-vs-demos.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 1000


def test_a_sweep_with_no_finished_cell_is_all_dashes(tmp_path):
    md, _ = write_sweep_report(tmp_path, [1, 10], [0], SETTINGS, [])
    text = md.read_text()
    assert cells(text, "TVF-L", "**10 demos**") == ["0 of 1", "–", "–", "–", "–", "78.5%"]
    assert not (tmp_path / "success-vs-demos.png").exists() and "success-vs-demos.png" not in text
