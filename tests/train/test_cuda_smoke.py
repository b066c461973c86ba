"""The CUDA path end to end (skipped without a GPU): train both smoke models a few steps on CUDA (bf16
autocast), then one TVF search on CUDA from plain arrays (every output must be finite) and a closed-loop
evaluation there with two environments per worker."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch
from data_factory import make_episode

import tvf
from tvf.data.format import episode_name, write_episode
from tvf.models.checkpoint import load_checkpoint
from tvf.train.config import TrainConfig
from tvf.train.jobs import gctn_job, vf_job
from tvf.train.trainer import train

pytestmark = pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")

TASKS = ("stack-stair", "put-t")


def test_smoke_models_train_on_cuda_and_a_tvf_search_runs_there(tmp_path: Path):
    torch.cuda.reset_peak_memory_stats()
    decision = train_and_search(tmp_path, "cuda")
    assert torch.cuda.max_memory_allocated() > 0  # the models ran on the GPU
    assert decision.plan.counts["vf_calls"] >= 1
    from tvf.evaluate.closed_loop import evaluate
    from tvf.policies import PolicySpec

    spec = PolicySpec("tvf-small", gctn=str(tmp_path / "gctn"), vf=str(tmp_path / "vf"), device="cuda")
    summary = evaluate(spec, ["stack-stair"], 2, 1, 1, tmp_path / "eval", envs_per_worker=2)  # one batch
    assert summary["average"]["episodes"] == 2  # closed loop on the GPU, two environments' trees per call


def train_and_search(root: Path, device: str) -> tvf.api.Decision:
    """Train the smoke GCTN and VF 3 steps on ``device``, then plan one TVF-S step there; checks that
    the weights, the action and the search tree are finite."""
    for task in TASKS:
        for seed in (0, 2):
            write_episode(root / "demos" / task / episode_name(seed), make_episode(task, seed, rng_seed=seed))
    runs = {}
    for kind, job_of in (("gctn", gctn_job), ("vf", vf_job)):
        cfg = TrainConfig(
            data=root / "demos", out=root / kind, preset="smoke", demos=2, tasks=",".join(TASKS), steps=3,
            batch=2, lr=1e-3, schedule="constant", warmup=0, log_every=1, device=device, images_every=0,
            progress=False,
        )  # fmt: skip
        train(cfg, job_of(cfg))
        state = load_checkpoint(cfg.out / "checkpoints" / "last.pt", kind).model
        assert all(torch.isfinite(v).all() for v in state.values() if v.is_floating_point())
        runs[kind] = str(cfg.out)
    planner = tvf.load_planner("tvf-small", gctn=runs["gctn"], vf=runs["vf"], device=device, k=2)
    episode = make_episode("stack-stair", 7, rng_seed=7)
    decision = planner.next_action(episode.color[0], episode.height[0], episode.color[-1], episode.height[-1])
    assert np.isfinite(decision.as_array()).all()
    plan = decision.plan
    assert plan is not None and plan.nodes
    assert all(np.isfinite([n.distance, n.score]).all() for n in plan.nodes)
    assert torch.isfinite(plan.pick_logits).all() and torch.isfinite(plan.place_logits).all()
    return decision
