"""`tvf experiment` sweeps: folders per (demos, seed), data generated once per demo count, resume after an
interruption, the sweep report, and one value of each running exactly one experiment as before.

These tests run the real pipeline (its data stage, generation scheduler, closed-loop evaluation and
reports) with three light stand-ins: generation writes synthetic episodes, training writes a marker,
evaluation runs the oracle in a scripted world. test_sweep_smoke.py runs the real smoke pipeline (slow)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
import tyro

from tvf.cli.experiment import ExperimentCmd
from tvf.data.dataset import demo_subset, open_dataset
from tvf.data.format import Episode, episode_name, expected_layout, write_h5
from tvf.data.generation import Outcome
from tvf.errors import TvfError
from tvf.evaluate.closed_loop import evaluate
from tvf.experiment import pipeline
from tvf.experiment.config import ExperimentConfig
from tvf.experiment.sweep import cell_dir, data_dir, run_experiments, sweep_values
from tvf.io import atomic_write_json, read_jsonl, temp_path
from tvf.policies import PolicySpec

TRAIN_TASK, TEST_TASK = "stack-tower", "stack-stair"
STAGES = "data,train,eval,report"


def small_episode(task: str, split: str, seed: int) -> Episode:
    arrays = {name: np.zeros(shape, dtype) for name, (shape, dtype) in expected_layout(2, 3).items()}
    return Episode(task=task, seed=seed, split=split, attrs={"n_blocks": 3}, **arrays)


def fake_job(task, split: str, seed: int, folder: str) -> Outcome:
    """A generation job: seed 4 fails, the others write a tiny episode (as episode_job does)."""
    if seed == 4:
        return Outcome(task.name, seed, False, reason="fake failure")
    final = Path(folder) / task.name / episode_name(seed)
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_path(final)
    write_h5(tmp, small_episode(task.name, split, seed))
    return Outcome(task.name, seed, True, steps=2, tmp=str(tmp))


class ScriptedEnv:
    """Succeeds in one step unless (seed // 2 + bias) % 3 == 0."""

    def __init__(self, task, bias: int) -> None:
        self.task, self.bias, self.seed = task, bias, 0
        self.obs = {"color": np.zeros((4, 4, 3), np.uint8), "height": np.zeros((4, 4), np.float32)}

    def reset(self, *, seed=None, options=None):
        self.seed = seed
        return self.obs, {"goal": self.obs, "progress": 0.0}

    def step(self, action):
        success = (self.seed // 2 + self.bias) % 3 != 0
        info = {"success": success, "progress": float(success), "steps": 1, "primitive": "ok"}
        return self.obs, float(success), success, not success, info

    def oracle_action(self):
        return np.zeros((2, 4))


class ScriptedEnvs:
    def __init__(self, bias: int) -> None:
        self.bias = bias

    def __call__(self, task):
        return ScriptedEnv(task, self.bias)


class Stand_ins:  # noqa: N801 - a namespace of the stand-ins and what they saw
    def __init__(self) -> None:
        self.generated: list[tuple[str, str, int]] = []
        self.trained: list[tuple[int, int]] = []
        self.demos: dict[tuple[int, int], list[tuple[str, int]]] = {}
        self.interrupt: set[tuple[int, int]] = set()

    def generate(self, plan, workers, tasks=None, **where):
        report = REAL_GENERATE(plan, 1, progress=False, tasks=tasks, job=fake_job, log=lambda s: None)
        self.generated.append((str(plan.folder), plan.split, report.generated))
        return report

    def train(self, cfg: ExperimentConfig) -> None:
        cell = (cfg.demos, cfg.seed)
        if cell in self.interrupt:
            self.interrupt.discard(cell)
            raise KeyboardInterrupt
        chosen = demo_subset(open_dataset(cfg.data_root, split="train"), cfg.demos, cfg.seed)
        self.demos[cell] = [(e.task, e.seed) for eps in chosen.values() for e in eps]
        marker = cfg.out / "gctn" / "done.json"
        if not marker.exists():
            self.trained.append(cell)
            atomic_write_json(marker, {"demos": cfg.demos, "seed": cfg.seed})

    def evaluate(self, cfg: ExperimentConfig) -> None:
        tasks = cfg.task_table().resolve(cfg.tasks)
        for i, method in enumerate(cfg.method_list()):
            envs = ScriptedEnvs(bias=cfg.demos + cfg.seed + i)
            evaluate(PolicySpec("oracle"), tasks, cfg.episodes, cfg.seed_start, 1, cfg.out / "eval" / method,
                     envs=envs)  # fmt: skip


REAL_GENERATE = pipeline.generate


@pytest.fixture(scope="module")
def stand_ins():
    fakes = Stand_ins()
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(pipeline, "generate", fakes.generate)
        mp.setitem(pipeline.RUNNERS, "train", fakes.train)
        mp.setitem(pipeline.RUNNERS, "eval", fakes.evaluate)
        yield fakes


def base_config(out: Path, **kw) -> ExperimentConfig:
    flags = dict(out=out, preset="smoke", test_demos=1, train_tasks=TRAIN_TASK, tasks=TEST_TASK,
                 methods="gctn,tvf-large", episodes=3, workers=1, gifs=0, stages=STAGES)  # fmt: skip
    return ExperimentConfig(**{**flags, **kw})


def snapshot(out: Path) -> dict[str, bytes]:
    """Every file under ``out`` but the reports and the records of the commands -> its content."""
    skip = {"sweep.md", "sweep.html", "success-vs-demos.png", "report.md", "report.html", "success.png",
            "experiment.json", "sweep.json", "cost.jsonl"}  # fmt: skip
    return {
        str(p.relative_to(out)): p.read_bytes() for p in out.rglob("*") if p.is_file() and p.name not in skip
    }


@pytest.fixture(scope="module")
def sweep(stand_ins, tmp_path_factory):
    """A 2 x 2 sweep interrupted in its third cell, then run again to the end."""
    out = tmp_path_factory.mktemp("sweep")
    stand_ins.interrupt = {(2, 0)}
    with pytest.raises(KeyboardInterrupt):
        run_experiments(base_config(out), (1, 2), (0, 1))
    first = (list(stand_ins.generated), list(stand_ins.trained), snapshot(out))
    report = run_experiments(base_config(out), (1, 2), (0, 1))
    return out, report, first


def test_every_cell_is_an_experiment_in_its_folder(sweep):
    out, report, _ = sweep
    assert report == out / "sweep.md"
    for demos in (1, 2):
        for seed in (0, 1):
            record = json.loads((cell_dir(out, demos, seed) / "experiment.json").read_text())
            assert (record["demos"], record["seed"]) == (demos, seed)
            assert record["data"] == str(data_dir(out, demos))
            assert (cell_dir(out, demos, seed) / "eval" / "tvf-large" / "summary.json").is_file()
            assert (cell_dir(out, demos, seed) / "report.md").is_file()
    assert not (out / "experiment.json").exists()
    assert json.loads((out / "sweep.json").read_text())["demos"] == [1, 2]


def test_data_is_generated_once_per_demo_count_and_shared(sweep, stand_ins):
    out, _, _ = sweep
    made = [(Path(f).relative_to(out).as_posix(), n) for f, _, n in stand_ins.generated if n]
    # demos 1: one train episode (seed 0) and the test episodes of both tasks; demos 2: one more train
    # episode (seed 2; seed 0 is the 1-demo set's), its test split entirely the 1-demo set's
    assert made == [("data/demos-1/train", 1), ("data/demos-1/test", 2), ("data/demos-2/train", 1)]
    one, two = data_dir(out, 1) / "train" / TRAIN_TASK, data_dir(out, 2) / "train" / TRAIN_TASK
    assert os.path.samefile(one / episode_name(0), two / episode_name(0))
    assert sorted(p.name for p in two.glob("*.h5")) == [episode_name(0), episode_name(2)]
    assert os.path.samefile(data_dir(out, 1) / "test" / TEST_TASK / episode_name(1),
                            data_dir(out, 2) / "test" / TEST_TASK / episode_name(1))  # fmt: skip
    # the training seed does not change the demonstrations
    assert stand_ins.demos[(2, 0)] == stand_ins.demos[(2, 1)] == [(TRAIN_TASK, 0), (TRAIN_TASK, 2)]


def test_the_interrupted_sweep_resumes_without_redoing_work(sweep, stand_ins):
    out, _, (generated, trained, files) = sweep
    assert trained == [(1, 0), (1, 1)]  # the interruption came in the third cell's training
    assert stand_ins.trained == [(1, 0), (1, 1), (2, 0), (2, 1)]  # the re-run did only the rest
    now = snapshot(out)
    assert all(now[f] == content for f, content in files.items())  # nothing finished before has changed
    before, cells = snapshot(out), list(stand_ins.trained)
    n_generated = len(stand_ins.generated)
    run_experiments(base_config(out), (1, 2), (0, 1))  # a third run: nothing left to do
    assert stand_ins.trained == cells and snapshot(out) == before
    assert all(n == 0 for _, _, n in stand_ins.generated[n_generated:])


def test_every_stage_run_is_costed_and_the_report_sums_the_cells(sweep):
    out, report, _ = sweep
    interrupted = read_jsonl(cell_dir(out, 2, 0) / "cost.jsonl")
    train = [r["finished"] for r in interrupted if r["stage"] == "train"]
    assert train == [False, True, True]  # stopped, finished on the re-run, skipped on the third run
    for demos in (1, 2):
        for seed in (0, 1):
            stages = {r["stage"] for r in read_jsonl(cell_dir(out, demos, seed) / "cost.jsonl")}
            assert stages == set(STAGES.split(","))
    md = report.read_text()
    header = md[md.index("## Cost") :].splitlines()[4]
    assert header.startswith("| cell | data (CPU h) | train (CPU h) |") and header.endswith("| wall h |")
    total = next(line for line in md.splitlines() if line.startswith("| *all cells* |"))
    cells = [line for line in md[md.index("## Cost") :].splitlines() if line.startswith("| demos-")][:4]
    per_cell = [float(line.strip("|").split(" | ")[-2]) for line in cells]
    assert float(total.strip("|").split(" | ")[-2]) == pytest.approx(sum(per_cell), abs=0.011)


def test_the_sweep_report_reads_every_cell(sweep):
    out, report, _ = sweep
    md = report.read_text()
    assert md.startswith("# tvf sweep: smoke models, 1/2 demos per training task, seeds 0, 1")
    assert "| cells finished | 4 of 4 |" in md
    assert (out / "sweep.html").is_file() and (out / "success-vs-demos.png").is_file()
    summary = json.loads((cell_dir(out, 2, 1) / "eval" / "gctn" / "summary.json").read_text())
    k = summary["tasks"][0]["successes"]
    row = next(line for line in md.splitlines() if line.startswith("| demos-2/seed-1 |"))
    assert row.split(" | ")[1].startswith(f"{100 * k / 3:.1f}% [")


def test_report_stage_alone_remakes_the_report_without_starting_cells(sweep):
    out, report, _ = sweep
    report.unlink()
    files = snapshot(out)
    run_experiments(base_config(out, stages="report"), (1, 2, 3), (0, 1))
    assert not cell_dir(out, 3, 0).exists() and snapshot(out) == files
    md = report.read_text()
    assert "| demos-3/seed-0 | – | – |" in md and "| cells finished | 4 of 6 |" in md
    run_experiments(base_config(out, stages="report"), (10,), (0,))  # one value: still the sweep in OUT
    assert not (out / "experiment.json").exists() and not cell_dir(out, 10, 0).exists()


def test_other_shared_settings_are_refused(sweep):
    out, _, _ = sweep
    with pytest.raises(TvfError, match="holds a sweep with other episodes"):
        run_experiments(base_config(out, episodes=5, stages="report"), (1, 2), (0, 1))
    with pytest.raises(TvfError, match="--ship"):
        run_experiments(base_config(out, ship=True), (1, 2), (0, 1))


def test_a_later_command_with_other_methods_adds_their_rows(stand_ins, tmp_path):
    run_experiments(base_config(tmp_path, methods="gctn"), (1,), (0, 1))
    trained = list(stand_ins.trained)
    paper = base_config(tmp_path, methods="gctn-paper", stages="eval,report")
    report = run_experiments(paper, (1,), (0,))  # one cell, the paper's rules: no new data or training
    assert stand_ins.trained == trained
    assert json.loads((tmp_path / "sweep.json").read_text())["settings"]["methods"] == "gctn,gctn-paper"
    cell = cell_dir(tmp_path, 1, 0)
    assert json.loads((cell / "experiment.json").read_text())["methods"] == "gctn,gctn-paper"
    assert "| GCTN | GCTN, paper rules |" in (cell / "report.md").read_text()  # both columns
    md = report.read_text()
    assert "| cells finished | 1 of 2 |" in md  # seed 1 has not run gctn-paper
    row = next(line for line in md.splitlines() if line.startswith("| GCTN, paper rules |"))
    assert row.startswith("| GCTN, paper rules | 1 of 2 |") and row.endswith("| 1.3% |")  # the paper's GCTN
    with pytest.raises(TvfError, match="holds a sweep with other episodes"):  # methods add, others do not
        run_experiments(base_config(tmp_path, methods="tvf-large", episodes=5), (1,), (0,))


def test_one_value_of_each_runs_one_experiment_as_before(stand_ins, tmp_path):
    report = run_experiments(base_config(tmp_path), (1,), (0,))
    assert report == tmp_path / "report.md" and report.is_file()
    assert json.loads((tmp_path / "experiment.json").read_text())["data"] is None
    assert (tmp_path / "data" / "train" / TRAIN_TASK / episode_name(0)).is_file()
    assert not (tmp_path / "sweep.json").exists() and not (tmp_path / "demos-1").exists()
    with pytest.raises(TvfError, match="holds a single experiment"):
        run_experiments(base_config(tmp_path), (1, 2), (0,))


def test_flags():
    assert sweep_values("1000,1,10,100,10", 0, None) == ((1, 10, 100, 1000), (0,))
    assert sweep_values(10, 3, None) == ((10,), (3,))
    assert sweep_values("10", 0, "2,0,1") == ((10,), (0, 1, 2))
    for demos, seed, seeds, match in (("1,x", 0, None, "--demos takes"), ("0,10", 0, None, "at least 1"),
                                      ("10", 2, "0,1", "not both"), ("10", 0, "-1", "--seeds needs"),
                                      (",", 0, None, "at least one")):  # fmt: skip
        with pytest.raises(TvfError, match=match):
            sweep_values(demos, seed, seeds)
    cmd = tyro.cli(ExperimentCmd, args=["--demos", "1,10", "--seeds", "0,1", "--out", "x", "--episodes", "3"])
    cfg, demos, seeds = cmd.config()
    assert type(cfg) is ExperimentConfig and (cfg.demos, cfg.seed, cfg.episodes) == (1, 0, 3)
    assert (demos, seeds) == ((1, 10), (0, 1))
    one, demos, seeds = tyro.cli(ExperimentCmd, args=["--out", "x", "--seed", "4"]).config()
    assert (one.demos, one.seed, demos, seeds) == (10, 4, (10,), (4,))
