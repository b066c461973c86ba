"""Benchmark of the two backends of tvf.parallel: oracle demonstrations per second, process pool vs Ray.

``--episodes`` train-split episodes of ``--task`` are generated into a fresh temporary folder with the
local process pool and with Ray, each with ``--workers`` workers (``--repeats`` > 1 alternates them and
keeps each one's fastest run). The pool's time includes starting its worker processes (spawn, imports);
Ray's includes starting its worker processes but not the Ray instance itself (a cluster pays that once),
whose start-up is reported apart as ``ray_init_seconds``. ``identical`` says whether the two datasets are
the same bytes. Prints one JSON object. Needs Ray (pip install 'tvf[ray]').

Example: nice -n 5 .venv/bin/python benchmarks/backends.py --episodes 8 --workers 2
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import tempfile
import time
from pathlib import Path

from tvf.data import GenerationPlan, generate
from tvf.parallel import connect_ray


def run(backend: str, task: str, episodes: int, workers: int, out: Path) -> tuple[float, dict[str, bytes]]:
    """Seconds to generate the dataset, and its files' bytes."""
    plan = GenerationPlan((task,), "train", episodes, out)
    t0 = time.perf_counter()
    report = generate(plan, workers, progress=False, backend=backend)
    seconds = time.perf_counter() - t0
    if report.generated != episodes:
        raise SystemExit(f"{backend}: {report.generated} of {episodes} episodes generated")
    files = {str(p.relative_to(out)): p.read_bytes() for p in sorted(out.rglob("*")) if p.is_file()}
    return seconds, files


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", default="stack-tower")
    parser.add_argument("--episodes", type=int, default=8)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--repeats", type=int, default=1, help="alternating runs per backend (best kept)")
    args = parser.parse_args()
    t0 = time.perf_counter()
    connect_ray(args.workers)
    init = time.perf_counter() - t0
    best: dict[str, float] = {}
    datasets: dict[str, dict[str, bytes]] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for i in range(args.repeats):
            for backend in ("local", "ray"):
                seconds, datasets[backend] = run(
                    backend, args.task, args.episodes, args.workers, Path(tmp) / f"{backend}-{i}"
                )
                best[backend] = min(seconds, best.get(backend, seconds))
    rate = {b: args.episodes / s for b, s in best.items()}
    print(json.dumps({
        "task": args.task, "episodes": args.episodes, "workers": args.workers, "repeats": args.repeats,
        "seconds": {b: round(s, 2) for b, s in best.items()},
        "episodes_per_second": {b: round(r, 3) for b, r in rate.items()},
        "ray_vs_local": round(rate["ray"] / rate["local"], 3),
        "ray_init_seconds": round(init, 2),
        "identical": datasets["ray"] == datasets["local"],
        "load_average": [round(x, 2) for x in os.getloadavg()],
        "cpus": os.cpu_count(), "python": platform.python_version(),
    }, indent=1))  # fmt: skip


if __name__ == "__main__":
    main()
