"""`tvf experiment`: data, training, evaluation of every method and the report, in one resumable command."""

from __future__ import annotations

from dataclasses import dataclass

from tvf.experiment.config import ExperimentConfig


@dataclass(frozen=True)
class ExperimentCmd(ExperimentConfig):
    """The paper's experiment: GCTN vs TVF-Small vs TVF-Large (and the expert) on unseen and training tasks.

    Generates demonstrations, trains the GCTN and the VF, evaluates every method in closed loop and writes
    EXP/report.md and EXP/report.html (table with 95% intervals, chart, GIFs). Every stage resumes.
    Example: tvf experiment --demos 10 --preset lite --out runs/exp-lite-10
    """

    def run(self) -> None:
        from tvf.experiment.pipeline import run_experiment

        report = run_experiment(self)
        print(f"done: {report} and {report.with_suffix('.html')}")
