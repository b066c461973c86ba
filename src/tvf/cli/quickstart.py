"""`tvf quickstart`: the README's main job."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from tvf.cli.common import at_least_one, check_output_dir
from tvf.seeds import VALIDATION_SEED_START


@dataclass(frozen=True)
class QuickstartCmd:
    """The README's main job: GCTN and TVF-L with the shipped lite weights on the same episodes of every
    unseen task, reported beside the shipped weights' recorded evaluation and the paper's numbers.

    Writes OUT/report.html and OUT/report.md (the comparison, success per task with 95% intervals, GIFs),
    OUT/success.png, OUT/eval/METHOD/ (episodes and summary) and OUT/gifs/METHOD/TASK-0.gif (each step
    labelled: action, progress, the end's success or failure; TVF-L's imagined best path beside the real
    observation). --expert instead runs the scripted expert once on every task.
    """

    out: Path = Path("out/quickstart")
    """Output directory."""
    episodes: int = 5
    """Episodes per task and method (5: 40 per method on the unseen tasks, a few minutes on 2 cores)."""
    seed_start: int = VALIDATION_SEED_START
    """Episode i uses seed SEED_START + 2i (the one seed rule of every command)."""
    workers: int = 2
    """Parallel processes."""
    tasks: str = "unseen"
    """train | unseen | all | NAME[,NAME...] (see `tvf tasks`)."""
    expert: bool = False
    """Run the expert on every task and write a gallery (index.md) instead."""
    task_file: Path | None = None
    """A YAML or JSON file of extra tasks (docs/tasks.md) that --tasks may name."""
    device: str = "auto"
    """auto | cpu | cuda: where the models run (auto: CUDA when present)."""

    def run(self) -> None:
        from tvf.experiment.quickstart import oracle_gallery, run_quickstart
        from tvf.tasks import load_tasks

        at_least_one(episodes=self.episodes, workers=self.workers)
        table = load_tasks(self.task_file)
        out = check_output_dir(self.out)
        if self.expert:
            oracle_gallery(out, self.seed_start, self.workers, table)
        else:
            run_quickstart(out, self.episodes, self.seed_start, self.workers, self.tasks, table, self.device)
