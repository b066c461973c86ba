"""The experiment's configuration: every flag of `tvf experiment`, stored in EXP/experiment.json.

The command line builds its parser from this class, so it imports no model code; the two methods that
read the registries import them when called (torch and PyBullet take seconds to import).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

from tvf.errors import TvfError
from tvf.seeds import TEST_SEED_START
from tvf.tasks import TaskTable, load_tasks

STAGES = ("data", "train", "eval-vf", "eval", "gifs", "report", "weights")
RECIPE_FLAGS = {
    f"{kind}_{field}": (kind, field) for kind in ("gctn", "vf") for field in ("steps", "batch", "lr")
}
RECIPE_FLAGS |= {"gctn_schedule": ("gctn", "schedule"), "gctn_warmup": ("gctn", "warmup"),
                 "vf_schedule": ("vf", "schedule"), "vf_warmup": ("vf", "warmup"),
                 "vf_changed_weight": ("vf", "vf_changed_weight"),
                 "vf_rollout": ("vf", "vf_rollout")}  # fmt: skip
"""Experiment flags that override a field of a model kind's recipe (tvf.train.registry)."""
NOT_RECORDED = ("workers", "envs_per_worker", "backend", "address", "stages", "ship", "device", "wandb")
"""Flags that may change between runs of the same experiment or sweep (how, not what, it computes)."""


def merged_methods(recorded: str | None, given: str) -> str:
    """The methods of a folder after a command: the recorded ones, then the new ones given. A later command
    may name other methods: it evaluates them with the same models, so it adds to the experiment."""
    names = [m.strip() for text in (recorded or "", given) for m in text.split(",") if m.strip()]
    return ",".join(dict.fromkeys(names))


@dataclass(frozen=True)
class ExperimentConfig:
    """Everything an experiment depends on; stored in EXP/experiment.json and checked on resume."""

    out: Path
    """Experiment folder (data, runs, evaluations, report); re-running the same command resumes."""
    demos: int = 10
    """Demonstrations per training task (the paper: 1, 10, 100, 1000)."""
    preset: str = "lite"
    """Model size: lite (2-core CPU) | paper (the reference widths; a GPU job) | smoke (tests)."""
    data: Path | None = None
    """An existing dataset root made by `tvf demos` (default: EXP/data, generated here)."""
    test_demos: int = 5
    """Test-split episodes per task (validation and foresight evaluation)."""
    train_tasks: str = "train"
    """Tasks the models learn from."""
    tasks: str = "all"
    """Tasks evaluated in closed loop: train | unseen | all | NAME[,NAME...]."""
    methods: str = "oracle,gctn,tvf-small,tvf-large"
    """Methods evaluated, comma-separated (the registry's; gctn-paper, tvf-small-paper and tvf-large-paper
    run the paper's rules, for a row beside the paper's; the -no-image-rules three ours without the
    rules that read the height maps). METHOD+FORESIGHT runs a search method with another foresight than
    its VF, into its own folder: tvf-large-paper+rigid is tvf eval's --method tvf-large-paper --foresight
    rigid."""
    episodes: int = 20
    """Closed-loop episodes per task and method (the paper: 20)."""
    seed: int = 0
    """Training seed (demo subset, initialisation, batches)."""
    seed_start: int = TEST_SEED_START
    """Evaluation episode i uses seed seed_start + 2i (default: the test range, tvf.seeds)."""
    step_slack: int = 0
    """Extra steps beyond one per block (0 = the paper's protocol)."""
    gctn_steps: int | None = None
    """GCTN optimiser steps (default: the preset's, lite 21000)."""
    gctn_batch: int | None = None
    """GCTN batch (default: the preset's, lite 2)."""
    gctn_lr: float | None = None
    """GCTN Adam (peak) learning rate (default: the preset's, lite 2e-4)."""
    gctn_schedule: str | None = None
    """GCTN learning-rate schedule, constant | cosine (default: the preset's, lite cosine)."""
    gctn_warmup: int | None = None
    """GCTN warm-up steps of the cosine schedule (default: the preset's, lite 500)."""
    vf_steps: int | None = None
    """VF optimiser steps (default: the preset's, lite 3000)."""
    vf_batch: int | None = None
    """VF batch (default: the preset's, lite 8)."""
    vf_lr: float | None = None
    """VF Adam (peak) learning rate (default: the preset's)."""
    vf_schedule: str | None = None
    """VF learning-rate schedule, constant | cosine (default: the preset's)."""
    vf_warmup: int | None = None
    """VF warm-up steps of the cosine schedule (default: the preset's)."""
    vf_changed_weight: float | None = None
    """VF extra loss weight on the pixels whose height changes (0: the reference's loss; default: the
    preset's; docs/models.md)."""
    vf_rollout: int | None = None
    """VF rollout loss horizon: each training sample is this many consecutive steps, each predicted from
    the VF's own prediction (1: the reference's one-step loss; default: the preset's; docs/models.md)."""
    gctn_kernels: str | None = None
    """GCTN kernels: plain (the paper's) | c4 (tied over quarter turns: the GCTN's maps exactly
    equivariant to quarter turns of the scene, at the plain cost; docs/models.md); default: the preset's
    (plain)."""
    gctn_width: float | None = None
    """GCTN: the width multiplier of its attention and transport FCNs (tvf train gctn --gctn-width; lite
    0.125, paper 1; docs/training.md, "A wider GCTN"); default: the preset's."""
    gctn_hindsight: float = 0.0
    """GCTN: the share of training samples whose goal is a later frame of the same demonstration, a
    partial structure on the way, instead of its last frame (tvf train gctn --hindsight;
    docs/training.md, "Hindsight goals"); 0: the paper's."""
    gctn_mirror: float = 0.0
    """GCTN: the share of training samples mirrored left-right before their random turn (tvf train gctn
    --mirror; docs/training.md, "Mirror images"); 0: the paper's."""
    vf_tune: bool = False
    """After the VF's recipe, fine-tune it with the preset's second phase (lite: 3000 steps from its
    weights, lr 2e-4 cosine, three-step rollout loss, changed pixels weighted 21 times, the local head;
    tvf.train.registry.VF_TUNES) into EXP/vf-tuned, the VF every later stage uses. The shipped lite VF
    is made so (make reproduce); without it, the reference's one-phase VF."""
    workers: int = 2
    """Parallel processes for data generation and evaluation (with --backend ray: Ray tasks at once)."""
    envs_per_worker: int = 1
    """Closed-loop evaluation: simulators each process steps together, their decisions batched (pays on a
    GPU; the results are those of one at a time; docs/planner.md)."""
    backend: Literal["local", "ray"] = "local"
    """Where the episodes run: local (a process pool on this host) | ray (Ray tasks on a local Ray
    instance of --workers CPUs, or on the cluster at --address; pip install 'tvf[ray]'; docs/parallel.md).
    The results are the same bytes either way."""
    address: str | None = None
    """With --backend ray: the running Ray cluster to use, HOST:6379 (default: start a local instance)."""
    task_file: Path | None = None
    """A YAML or JSON file of extra tasks (docs/tasks.md) that --tasks and --train-tasks may name."""
    device: str = "auto"
    """auto | cpu | cuda: where the models train and run (auto: CUDA when present)."""
    vf_horizon: int = 3
    """Foresight rollouts of 1..H steps in the eval-vf stage (the model fed its own predictions)."""
    gifs: int = 1
    """TVF-L episodes recorded as GIFs per unseen task (0: none)."""
    stages: str = ",".join(STAGES)
    """Stages to run, comma-separated, in pipeline order: data,train,eval-vf,eval,gifs,report,weights."""
    ship: bool = False
    """After the weights stage, copy EXP/weights over the package's shipped weights (make reproduce)."""
    wandb: bool = False
    """Also log the two training runs to Weights & Biases (pip install 'tvf[wandb]'; docs/training.md)."""
    restart: bool = False
    """Start again what its inputs changed under: a training run whose episodes changed content, an
    evaluation whose weights or settings changed (without it such a folder is refused, naming the change)."""

    def resolved(self) -> ExperimentConfig:
        """Fill the training schedules from the preset's recipes (tvf.train.registry)."""
        from tvf.train.registry import recipe  # lazy: the registries import torch (see the module doc)

        return replace(self, **{
            flag: getattr(recipe(kind, self.preset), field)
            for flag, (kind, field) in RECIPE_FLAGS.items() if getattr(self, flag) is None
        })  # fmt: skip

    def task_table(self) -> TaskTable:
        return load_tasks(self.task_file)

    @property
    def data_root(self) -> Path:
        return Path(self.data) if self.data is not None else self.out / "data"

    def method_list(self) -> list[str]:
        from tvf.policies import METHODS, check_variant  # lazy, as above

        names = [m.strip() for m in self.methods.split(",") if m.strip()]
        if not names:
            raise TvfError(f"--methods names no method; choose from {', '.join(METHODS)}")
        for name in names:  # the method registry, or a foresight variant of a search method
            check_variant(name)
        return names

    def stage_list(self) -> list[str]:
        names = [s.strip() for s in self.stages.split(",") if s.strip()]
        bad = [s for s in names if s not in STAGES]
        if bad:
            raise TvfError(f"unknown stage(s) {', '.join(bad)}; choose from {', '.join(STAGES)}")
        return names
