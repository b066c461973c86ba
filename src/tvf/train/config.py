"""The flags of a training run (`tvf train gctn|vf`), as a frozen dataclass without heavy imports: the
command line builds its parser from it, so `tvf --help` does not import torch (the trainer does)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class TrainConfig:
    """Flags shared by `tvf train gctn` and `tvf train vf`."""

    data: Path
    """Dataset root (with train/ and test/) or a train split folder, made by `tvf demos`."""
    out: Path
    """Run directory (created; holds config.json, metrics.jsonl, tb/, checkpoints/)."""
    demos: int = 10
    """Demonstrations per task drawn for this run (the subset depends on --seed)."""
    preset: str = "lite"
    """Model size: paper | lite | smoke."""
    steps: int | None = None
    """Optimiser steps in total (a resumed run continues up to this number); default: the preset's recipe
    (lite: GCTN 21000, VF 3000)."""
    batch: int | None = None
    """Batch size (the global batch: under torchrun each of N processes builds and trains on 1/N of it);
    default: the preset's recipe (lite: GCTN 2, VF 8)."""
    lr: float | None = None
    """Learning rate (the peak one with --schedule cosine); default: the preset's recipe."""
    schedule: str | None = None
    """constant | cosine: linear warm-up over --warmup steps, then a cosine decay to 0 at --steps
    (a cosine run cannot later be extended to more steps); default: the preset's recipe."""
    warmup: int | None = None
    """Linear warm-up steps of the cosine schedule; default: the preset's recipe."""
    seed: int = 0
    """Run seed: demo subset, weight initialisation and every batch's augmentation."""
    tasks: str = "train"
    """Tasks to train on: train | unseen | all | NAME[,NAME...]."""
    task_file: Path | None = None
    """A YAML or JSON file of extra tasks (docs/tasks.md) that --tasks may name."""
    vf_head: str | None = None
    """VF only: image (the reference's) | blend (edits the input) | local (redraws only the pick and place
    windows); docs/models.md; default: the preset's."""
    vf_changed_weight: float | None = None
    """VF only: extra L1 weight on the pixels whose height changes (weight 1 + this there; 0: the
    reference's loss, every pixel alike; docs/models.md, "Changed-pixel loss"); default: the preset's
    recipe."""
    vf_rollout: int | None = None
    """VF only: train on rollouts of this many consecutive steps, each predicted from the model's own
    prediction of the step before (the planner's use; docs/models.md, "Rollout loss"; each step costs
    about this many single steps); 1: the reference's one-step loss; default: the preset's recipe."""
    turns: int | None = None
    """GCTN only: train the GCTN's maps averaged over 1, 2 or 4 quarter turns of the scene (8: and their
    mirror images), the maps that `--turns` plans with (tvf.models.symmetry): its weights then learn
    under the exactly equivariant loss; each step costs about TURNS plain steps; default 1 (the paper's)."""
    gctn_kernels: str | None = None
    """GCTN only: plain (the paper's) | c4: every kernel of its FCNs tied over quarter turns, so its maps
    are exactly equivariant to quarter turns of the scene by construction, at the plain FCNs' cost (a
    quarter of the free weights; tvf.models.c4, docs/models.md); default: the preset's (plain)."""
    gctn_width: float | None = None
    """GCTN only: the width multiplier of its attention and transport FCNs (a multiple of the paper's
    channels: lite 0.125, paper 1; a wider GCTN costs more per step, docs/training.md); default: the
    preset's."""
    hindsight: float = 0.0
    """GCTN only: the share of training samples whose goal is a later frame of the same demonstration (a
    partial structure the expert's next steps reach) instead of its last frame: hindsight goals, many
    shapes instead of one per task (docs/training.md, "Hindsight goals"); validation keeps the last
    frame; 0: the paper's."""
    mirror: float = 0.0
    """GCTN only: the share of training samples mirrored left-right before their random turn (both images
    and the action; the turn's sense reversed): the six structures' mirror images, which no
    demonstration shows (docs/training.md, "Mirror images"); 0: the paper's."""
    init: Path | None = None
    """Start from these weights instead of a random initialisation: a run folder, a .pt or a .safetensors
    file of the same model kind and preset (e.g. the shipped GCTN, to fine-tune it with --turns 4)."""
    extra_data: Path | None = None
    """VF and latent only: a folder of a method's own moves (`tvf demos --moves`); all its episodes of the
    run's tasks are added to the drawn demonstrations (docs/data.md, "The planner's own moves")."""
    val_data: Path | None = None
    """Test split for validation; default: the `test` folder beside the train split, if any."""
    val_every: int = 250
    val_samples: int = 48
    checkpoint_every: int = 250
    keep: int = 0
    """Keep only the newest N step checkpoints (RUN/checkpoints/last.pt is always kept; older ones are
    deleted once the new one is written); 0: keep all."""
    log_every: int = 25
    images_every: int = 1
    """TensorBoard images at every Nth validation and the last (GCTN: pick and place heat maps; VF: input,
    prediction and truth; of one fixed validation sample); 0: none."""
    wandb: bool = False
    """Also log the numbers and images to Weights & Biases (pip install 'tvf[wandb]'; files in RUN/wandb/;
    WANDB_PROJECT, WANDB_MODE=offline etc. as W&B documents them)."""
    resume: bool = False
    """Continue from RUN/checkpoints/last.pt (the config must match)."""
    restart: bool = False
    """With --resume: when the run's training or validation episodes changed content since it was made,
    delete its checkpoints and metrics and train again from step 0 (without it such a run is refused)."""
    device: str = "auto"
    """auto | cpu | cuda (auto: CUDA when present)."""
    threads: int = 0
    """Torch CPU threads (0: torch's default)."""
    loader_workers: int = 0
    """DataLoader worker processes that build the batches ahead of the training step (0: the training
    thread builds them); the batches are the same either way."""
    progress: bool = True
