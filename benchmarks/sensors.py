"""Benchmark of the sensor models (tvf.sim.sensors): how far each rig's fused images are from the ideal
three cameras', and how long one observation takes to render and fuse.

For the first observation and the goal of ``--episodes`` unseen-task episodes (task i of the unseen
split in turn, validation seed 1 + 2 i), per sensor: the height MAE (mm) against the ideal sensor's
image, the fraction of pixels more than 5 mm off, and the coverage (pixels measured before hole
filling). Then the median time of ``env.observe()`` (render + sensor + fuse) per sensor.

Prints one JSON object; ``taskset -c 0 .venv/bin/python benchmarks/sensors.py`` for the timings.
Takes about a minute.
"""

from __future__ import annotations

import argparse
import json
import time

import numpy as np

from tvf.sim.env import TvfEnv
from tvf.tasks import BUILTIN

SENSORS = ("ideal", "d415", "one", "d415-one", "d415-one-calib", "d415-one-calib-level", "d415-one-goal2")


def images(sensor: str, jobs: list[tuple[str, int]]) -> list[dict]:
    """The first observation and the goal of each (task, seed), with the coverage of each."""
    out = []
    for task, seed in jobs:
        env = TvfEnv(task, sensor=sensor)
        try:
            obs, info = env.reset(seed=seed)
            out.append({"obs": obs["height"], "goal": info["goal"]["height"], **{
                f"coverage_{k}": v for k, v in env.coverage.items()}})  # fmt: skip
        finally:
            env.close()
    return out


def observe_time(sensor: str, task: str, repeats: int) -> float:
    env = TvfEnv(task, sensor=sensor)
    try:
        env.reset(seed=1)
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            env.observe()
            times.append(time.perf_counter() - t0)
        return float(np.median(times))
    finally:
        env.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=5)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    unseen = [t.name for t in BUILTIN.resolve("unseen")]
    jobs = [(unseen[i % len(unseen)], 1 + 2 * i) for i in range(args.episodes)]
    ideal = images("ideal", jobs)
    report: dict = {"episodes": [f"{t}:{s}" for t, s in jobs], "sensors": {}}
    for sensor in SENSORS:
        got = ideal if sensor == "ideal" else images(sensor, jobs)
        row = {}
        for kind in ("obs", "goal"):
            err = np.stack([np.abs(g[kind] - i[kind]) for g, i in zip(got, ideal, strict=True)])
            row[f"{kind}_mae_mm"] = round(1000 * float(err.mean()), 3)
            row[f"{kind}_gross_frac"] = round(float((err > 0.005).mean()), 4)
            row[f"{kind}_coverage"] = round(float(np.mean([g[f"coverage_{kind}"] for g in got])), 4)
        row["observe_s"] = round(observe_time(sensor, jobs[0][0], args.repeats), 3)
        report["sensors"][sensor] = row
    print(json.dumps(report, indent=2))


if __name__ == "__main__":
    main()
