"""Benchmark of the demonstration data: generation speed, bytes on disk, augmented samples per second.

* Generation: ``--episodes`` train-split episodes of each of ``--tasks`` into a temporary folder, with
  1 and with 2 worker processes (a fresh folder each time). Episodes (and transitions) per minute.
* Storage: bytes per stored transition (file bytes / steps, so the initial frame is included).
* Samplers: augmented batches of one (the reference's batch size) drawn in this process with one
  torch thread, from the episodes just generated; samples per second for GCTN and VF (batch 8 too).

Prints one JSON object. ``--dataset DIR`` measures storage and samplers on an existing split folder
instead of the generated one. Takes about 2 minutes with the defaults on 2 free cores. Worker
start-up (spawn, imports: a few seconds) is included, so small runs understate the 2-worker rate.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from tvf.data import GctnSampler, GenerationPlan, VfSampler, generate, open_dataset


def generation_rate(tasks: tuple[str, ...], episodes: int, workers: int, out: Path) -> dict:
    t0 = time.perf_counter()
    report = generate(GenerationPlan(tasks, "train", episodes, out), workers=workers, progress=False)
    seconds = time.perf_counter() - t0
    ds = open_dataset(out / "train")
    return {
        "workers": workers,
        "episodes": report.generated,
        "failed_seeds": len(report.failures),
        "seconds": round(seconds, 1),
        "episodes_per_minute": round(60 * report.generated / seconds, 2),
        "transitions_per_minute": round(60 * ds.n_transitions() / seconds, 1),
    }


def sampler_rate(sampler, batch_size: int, seconds: float, seed: int = 0) -> float:
    rng = np.random.default_rng(seed)
    sampler.sample(batch_size, rng)  # warm-up
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        sampler.sample(batch_size, rng)
        n += batch_size
    return round(n / (time.perf_counter() - t0), 1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", default="stack-stair,stack-t,stack-pyramid")
    ap.add_argument("--episodes", type=int, default=4, help="episodes per task per worker setting")
    ap.add_argument("--dataset", type=Path, default=None, help="existing split folder for storage/samplers")
    ap.add_argument("--sample-seconds", type=float, default=5.0)
    args = ap.parse_args()
    torch.set_num_threads(1)
    tasks = tuple(t.strip() for t in args.tasks.split(","))
    result: dict = {"machine": platform.processor() or platform.machine(), "cpus": os.cpu_count()}
    with tempfile.TemporaryDirectory() as tmp:
        result["generation"] = [generation_rate(tasks, args.episodes, w, Path(tmp) / f"w{w}") for w in (1, 2)]
        ds = open_dataset(args.dataset or Path(tmp) / "w2" / "train")
        summary = ds.summary()
        result["storage"] = {
            "dataset": str(args.dataset or "generated"),
            "episodes": summary["episodes"],
            "transitions": summary["transitions"],
            "bytes_per_transition": round(summary["bytes_per_transition"]),
            "bytes_per_frame": round(summary["bytes"] / (summary["transitions"] + summary["episodes"])),
        }
        episodes = ds.load_all()
        result["samplers"] = {
            "torch_threads": torch.get_num_threads(),
            **{
                f"{name}_b{b}_samples_per_s": sampler_rate(cls(episodes), b, args.sample_seconds)
                for name, cls in (("gctn", GctnSampler), ("vf", VfSampler))
                for b in (1, 8)
            },
        }
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
