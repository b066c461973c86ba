"""`tvf experiment`: data, training, evaluation of every method and the report, in one resumable command."""

from __future__ import annotations

from dataclasses import dataclass, fields

from tvf.experiment.config import ExperimentConfig


@dataclass(frozen=True)
class ExperimentCmd(ExperimentConfig):
    """The paper's experiment: GCTN vs TVF-Small vs TVF-Large (and the expert) on unseen and training tasks.

    Generates demonstrations, trains the GCTN and the VF, evaluates every method in closed loop and writes
    EXP/report.md and EXP/report.html (table with 95% intervals, chart, GIFs). Every stage resumes.
    Several --demos or --seeds values make a sweep: one experiment per (demos, seed) in
    OUT/demos-N/seed-S, one dataset per demo count, and OUT/sweep.md, sweep.html, success-vs-demos.png.
    Example: tvf experiment --demos 10 --preset lite --out runs/exp-lite-10
    """

    demos: str = "10"  # type: ignore[assignment]  # parsed into ExperimentConfig.demos (int) by run()
    """Demonstrations per training task (the paper: 1, 10, 100, 1000); several, comma-separated, make a
    sweep (1,10,100,1000)."""
    seeds: str | None = None
    """Training seeds of a sweep, comma-separated (0,1,2); one seed: --seed."""

    def config(self) -> tuple[ExperimentConfig, tuple[int, ...], tuple[int, ...]]:
        """The experiment of the flags (the first cell of a sweep), the demo counts and the seeds."""
        from tvf.experiment.sweep import sweep_values

        demos, seeds = sweep_values(self.demos, self.seed, self.seeds)
        flags = {f.name: getattr(self, f.name) for f in fields(ExperimentConfig)}
        return ExperimentConfig(**{**flags, "demos": demos[0], "seed": seeds[0]}), demos, seeds

    def run(self) -> None:
        from tvf.experiment.sweep import run_experiments

        report = run_experiments(*self.config())
        print(f"done: {report} and {report.with_suffix('.html')}")
