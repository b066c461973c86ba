"""The quick start's report: the run beside the shipped weights' recorded evaluation (read from their
provenance record, never from constants) and the paper's numbers; a headless browser renders it."""

from __future__ import annotations

import shutil
import subprocess

import imageio.v3 as iio
import numpy as np
import pytest

from tvf import __version__
from tvf.evaluate.closed_loop import summarise, wilson
from tvf.experiment.report import (
    comparison_rows,
    report_html,
    report_markdown,
    reported_record,
    shipped_rows,
    success_cell,
    write_report,
)
from tvf.tasks import resolve_tasks
from tvf.weights import provenance

UNSEEN = [t.name for t in resolve_tasks("unseen")]
TRAIN = [t.name for t in resolve_tasks("train")]


def entry(success: float, lo: float, hi: float, episodes: int = 160) -> dict:
    return {"success": success, "ci95": [lo, hi], "progress": 0.9, "episodes": episodes, "tasks": 8}


def fake_provenance(per_task: bool = False) -> dict:
    """A provenance record with numbers no constant in the code has."""
    record = {
        "experiment": {"demos": 7, "episodes": 13, "seed_start": 1_000_001},
        "models": {
            "gctn": {"file": "gctn-tiny.safetensors", "step": 123, "data_fingerprint": "feedc0ffee"},
            "vf": {"file": "vf-tiny.pt", "step": 45, "data_fingerprint": "feedc0ffee"},
        },
        "results": {
            "gctn": {
                "unseen": entry(0.321, 0.25, 0.40),
                "train": entry(0.612, 0.5, 0.7),
                "all": entry(0.4, 0.3, 0.5),
            },
            "tvf-large": {"unseen": entry(0.654, 0.58, 0.72), "all": entry(0.7, 0.6, 0.8)},
            "oracle": {"unseen": entry(1.0, 0.98, 1.0)},
        },
    }
    if per_task:
        record["task_results"] = {
            "gctn": [
                {
                    "task": UNSEEN[0],
                    "episodes": 13,
                    "successes": 4,
                    "success": 4 / 13,
                    "ci95": [0.12, 0.58],
                    "progress": 0.5,
                }
            ],  # fmt: skip
            "tvf-large": [
                {
                    "task": UNSEEN[0],
                    "episodes": 13,
                    "successes": 9,
                    "success": 9 / 13,
                    "ci95": [0.42, 0.87],
                    "progress": 0.8,
                }
            ],  # fmt: skip
        }
    return record


def run_summaries() -> dict[str, dict]:
    """GCTN 1 of 2 and TVF-L 2 of 2 on each unseen task."""

    def eps(task: str, k: int) -> list[dict]:
        return [{"task": task, "seed": 2 * i + 1, "success": i < k, "progress": 1.0 if i < k else 0.5}
                for i in range(2)]  # fmt: skip

    return {
        "gctn": summarise([r for t in UNSEEN for r in eps(t, 1)], "gctn"),
        "tvf-large": summarise([r for t in UNSEEN for r in eps(t, 2)], "tvf-large"),
    }


META = {"run": "GCTN and TVF-L on the same 16 episodes", "weights": "gctn-tiny + vf-tiny"}
TITLE = "tvf quick start: GCTN vs TVF-L on the 8 unseen tasks"


def md_row(md: str, first_cell: str) -> list[str]:
    for line in md.splitlines():
        cells = [c.strip() for c in line.strip("|").split(" | ")]
        if cells[0] == first_cell:
            return cells[1:]
    raise AssertionError(f"no row {first_cell!r} in\n{md}")


def test_the_comparison_puts_run_shipped_and_paper_side_by_side():
    methods, rows = comparison_rows(run_summaries(), fake_provenance())
    assert methods == ["gctn", "tvf-large"]
    kinds = [k for k, _, _ in rows]
    assert kinds == ["group", "run", "shipped", "paper"]
    by_kind = {k: cells for k, _, cells in rows}
    assert by_kind["run"][0].startswith("50.0% [") and by_kind["run"][1].startswith("100.0% [")
    assert by_kind["shipped"] == ["32.1% [25–40]", "65.4% [58–72]"]  # from the record
    assert by_kind["paper"] == ["55.4%", "78.5%"]
    names = [name for _, name, _ in rows]
    assert "this run (2 episodes per task)" in names and "shipped weights (13 episodes per task)" in names


def test_the_report_reads_every_shipped_number_from_the_record():
    md = report_markdown(run_summaries(), META, title=TITLE, shipped=fake_provenance())
    assert md.startswith(f"# {TITLE}")
    assert md_row(md, "*shipped weights (13 episodes per task)*") == ["32.1% [25–40]", "65.4% [58–72]"]
    full = md[md.index("## The shipped weights' recorded evaluation") : md.index("## Success per task")]
    assert md_row(full, "*unseen average*") == ["100.0% [98–100]", "32.1% [25–40]", "**65.4% [58–72]**"]
    assert md_row(full, "*training average*") == ["–", "**61.2% [50–70]**", "–"]
    assert f"gctn-tiny (step 123) + vf-tiny (step 45); tvf {__version__}; data feedc0ffee, 7 demos" in full
    assert "13 episodes per task, seeds 1000001, 1000003, 1000005, … (test range)" in full
    assert "43.8" not in md and "63.1" not in md  # no shipped number of today's weights is built in


def test_per_task_shipped_results_when_the_record_has_them():
    methods, rows = shipped_rows(fake_provenance(per_task=True))
    assert methods == ["oracle", "gctn", "tvf-large"]
    task = next(cells for kind, name, cells in rows if name == UNSEEN[0])
    assert task == ["–", "30.8% [12–58]", "**69.2% [42–87]**"]


def test_without_a_record_the_comparison_still_shows_the_paper():
    md = report_markdown(run_summaries(), META, title=TITLE, shipped={})
    assert "## The comparison" in md and "shipped weights" not in md.split("## Success per task")[0]
    assert md_row(md, "*paper (10 demos)*") == ["55.4%", "78.5%"]
    assert "## The shipped weights' recorded evaluation" not in md


def test_html_names_the_run_and_the_weights_not_paths_or_commands():
    gifs = {UNSEEN[0]: {"gctn": "gifs/gctn/a.gif", "tvf-large": "gifs/tvf-large/a.gif"}}
    page = report_html(run_summaries(), META, gifs, "success.png", TITLE, fake_provenance())
    assert f"<title>{TITLE}</title>" in page and f"<h1>{TITLE}</h1>" in page
    assert "<th>GCTN</th><th>TVF-L</th>" in page
    assert '<tr class="shipped"><td>shipped weights (13 episodes per task)</td><td>32.1% [25–40]</td>' in page
    assert '<tr class="paper"><td>paper (10 demos)</td><td>55.4%</td><td>78.5%</td></tr>' in page
    assert page.index("The comparison") < page.index("recorded evaluation") < page.index("Success per task")
    assert '<div class="episodes">' in page and page.index("gifs/gctn/a.gif") < page.index(
        "gifs/tvf-large/a.gif"
    )
    assert "src/tvf" not in page and "tvf experiment --" not in page and "<script" not in page


def _episode_gif(path, success: bool) -> None:
    """A small labelled GIF of a synthetic two-step episode."""
    from tvf.evaluate.recording import RecordedEpisode, RecordedStep
    from tvf.viz.recorded import episode_gif

    rng = np.random.default_rng(0)
    obs = {
        "color": rng.integers(0, 255, (160, 160, 3), dtype=np.uint8),
        "height": np.zeros((160, 160), np.float32),
    }
    act = np.array([[0.4, 0.0, 0.02, 0.0], [0.5, 0.1, 0.02, 1.0]])
    steps = [RecordedStep(obs, obs, None, act, 0.0, "ok"), RecordedStep(obs, obs, None, None, 0.5)]
    episode_gif(path, RecordedEpisode(UNSEEN[0], 1, "GCTN", 2, 2, success), steps)


@pytest.mark.skipif(
    shutil.which("chromium") is None, reason="needs Debian's chromium (apt-get install chromium)"
)
def test_a_headless_browser_renders_the_report(tmp_path):
    for m in ("gctn", "tvf-large"):
        (tmp_path / "gifs" / m).mkdir(parents=True)
        _episode_gif(tmp_path / "gifs" / m / "a.gif", m == "tvf-large")
    gifs = {UNSEEN[0]: {m: f"gifs/{m}/a.gif" for m in ("gctn", "tvf-large")}}
    _, page = write_report(tmp_path, run_summaries(), META, gifs, TITLE, fake_provenance())
    shot = tmp_path / "shot.png"
    flags = ["--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--window-size=1400,2400"]
    subprocess.run(
        ["chromium", *flags, f"--screenshot={shot}", page.as_uri()],
        check=True,
        capture_output=True,
        timeout=120,
    )
    image = iio.imread(shot)[..., :3]
    assert image.shape[:2] == (2400, 1400)
    dark = image.min(axis=2) < 100  # text, table borders, images
    assert dark[:200].sum() > 2000  # the title and the header are drawn at the top
    assert dark.sum() > 50_000 and image.std() > 20  # a page with tables, the chart and the GIFs, not blank
    rows_with_ink = np.flatnonzero(dark.any(axis=1))
    assert rows_with_ink.max() > 1200  # the content runs down the page (chart, tables, episodes)


def test_reports_show_the_test_range_evaluations_recorded_with_the_weights():
    record = fake_provenance()
    assert reported_record(record) is record  # nothing recorded later: the experiment's own results
    tested = {"all": entry(0.5, 0.4, 0.6, 280), "unseen": entry(0.444, 0.37, 0.52)}
    record["evaluations"] = [
        {"name": "GCTN", "method": "gctn", "episodes": 17, "seed_start": 1_000_001, "seed_range": "test",
         "results": tested, "tasks": {"put-t": {"success": 0.25, "episodes": 17}}},
        {"name": "GCTN, another setting", "method": "gctn", "episodes": 17, "seed_start": 1_000_001,
         "seed_range": "test", "results": {"unseen": entry(0.9, 0.8, 1.0)}, "tasks": {}},
    ]  # fmt: skip
    view = reported_record(record)
    assert view["results"] == {"gctn": tested}  # the entry named by the label, not the variant
    (cell,) = view["task_results"]["gctn"]
    assert cell == {
        "task": "put-t",
        "success": 0.25,
        "episodes": 17,
        "successes": 4,
        "ci95": list(wilson(4, 17)),
        "progress": None,
    }  # an older record: no progress kept
    assert view["experiment"]["episodes"] == 17 and view["models"] == record["models"]
    _, rows = shipped_rows(view)
    assert ("task", "put-t", [f"**{success_cell(cell)}**"]) in rows and "25.0% [" in success_cell(cell)


def test_the_real_shipped_record_renders_per_task_and_on_average():
    """The quick start's report of the committed weights: every recorded method, task by task."""
    view = reported_record(provenance())
    methods, rows = shipped_rows(view)
    assert methods and len(view["task_results"][methods[0]]) == 14
    cells = {name: cells for _, name, cells in rows}
    assert all("%" in c for c in cells["put-t"]) and len(cells["put-t"]) == len(methods)
