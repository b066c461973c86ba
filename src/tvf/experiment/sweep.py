"""`tvf experiment` over several demo counts and training seeds: the paper's whole table, resumable.

``--demos 1,10,100,1000 --seeds 0,1,2`` runs one ordinary experiment (tvf.experiment.pipeline) per
(demos, seed). One value of each runs one experiment in OUT itself, exactly as before sweeps existed.
A sweep's OUT holds::

    OUT/sweep.json                  the settings every cell shares, the grid, every command
    OUT/data/demos-N/{train,test}   one dataset per demo count, shared by its seeds
    OUT/demos-N/seed-S/             one experiment: experiment.json, gctn/, vf/, eval/, report.md, ...
    OUT/sweep.md, OUT/sweep.html    the report over every cell finished so far (tvf.experiment.sweep_report)
    OUT/success-vs-demos.png

Cells run demo count by demo count (smallest first), seeds in order; every cell resumes as an experiment
does, so the same command continues an interrupted sweep. Before a demo count's data stage its dataset
is started from another count's (tvf.data.generation.reuse_episodes, hard links): generation keeps the
first successes by seed order, so the 10-demo set is the first 10 episodes per task of the 100-demo set
and only the other 90 are generated. A dataset holds exactly its count per task, so the training seed
does not change the demonstrations (every seed's demo subset is the whole set).
"""

from __future__ import annotations

import json
import re
import sys
from dataclasses import asdict, replace
from pathlib import Path

from tvf.data.generation import reuse_episodes
from tvf.errors import TvfError
from tvf.experiment.config import NOT_RECORDED, ExperimentConfig, merged_methods
from tvf.experiment.pipeline import check_experiment, data_plans, run_experiment
from tvf.experiment.sweep_report import write_sweep_report
from tvf.io import atomic_write_json, check_output_dir, read_json

SWEEP_RECORD = "sweep.json"
PER_CELL = ("out", "demos", "seed")
"""Settings that differ between the cells of a sweep."""
CELL_DIR = re.compile(r"demos-(\d+)/seed-(\d+)")


def _say(message: str) -> None:
    print(f"[sweep] {message}", flush=True)


def parse_values(text: str | int, flag: str, minimum: int) -> tuple[int, ...]:
    """``"10,1,10"`` -> (1, 10): the distinct whole numbers of a comma-separated list, sorted."""
    try:
        values = sorted({int(v) for v in str(text).split(",") if v.strip()})
    except ValueError:
        raise TvfError(f"{flag} takes comma-separated whole numbers such as 1,10,100, got {text!r}") from None
    if not values or values[0] < minimum:
        raise TvfError(f"{flag} needs at least one value, each at least {minimum}, got {text!r}")
    return tuple(values)


def sweep_values(demos: str | int, seed: int, seeds: str | None) -> tuple[tuple[int, ...], tuple[int, ...]]:
    """The demo counts and training seeds of the command line (``--seeds`` or else ``--seed``)."""
    if seeds is not None and seed != 0:
        raise TvfError("give the training seed with --seed or --seeds, not both")
    counts = parse_values(demos, "--demos", 1)
    return counts, parse_values(seed if seeds is None else seeds, "--seeds", 0)


def is_sweep(out: Path, demos: tuple[int, ...], seeds: tuple[int, ...]) -> bool:
    """Several values, or an OUT that already holds a sweep (one cell of it is then run, or re-reported)."""
    return len(demos) > 1 or len(seeds) > 1 or (Path(out) / SWEEP_RECORD).is_file()


def cell_dir(out: Path, demos: int, seed: int) -> Path:
    return Path(out) / f"demos-{demos}" / f"seed-{seed}"


def data_dir(out: Path, demos: int) -> Path:
    return Path(out) / "data" / f"demos-{demos}"


def cell_config(base: ExperimentConfig, demos: int, seed: int) -> ExperimentConfig:
    """The experiment of one cell: its own folder, and the shared dataset of its demo count (or --data)."""
    data = base.data if base.data is not None else data_dir(base.out, demos)
    return replace(base, out=cell_dir(base.out, demos, seed), demos=demos, seed=seed, data=data)


def found_cells(out: Path) -> list[tuple[int, int]]:
    """(demos, seed) of every cell folder that holds an experiment, sorted."""
    cells = set()
    for record in Path(out).glob("demos-*/seed-*/experiment.json"):
        match = CELL_DIR.fullmatch(record.parent.relative_to(out).as_posix())
        if match:
            cells.add((int(match[1]), int(match[2])))
    return sorted(cells)


def shared_settings(cfg: ExperimentConfig) -> dict:
    """The settings every cell of a sweep shares, as JSON values."""
    keep = {k: v for k, v in asdict(cfg).items() if k not in PER_CELL + NOT_RECORDED}
    return json.loads(json.dumps(keep, default=str))


def record_sweep(base: ExperimentConfig, demos: tuple[int, ...], seeds: tuple[int, ...]) -> dict:
    """Write OUT/sweep.json (the grid grows with each command's values) and return it; other shared
    settings than the recorded ones are refused, as in one experiment's folder."""
    path = base.out / SWEEP_RECORD
    recorded = read_json(path, "restore it or choose another --out", {})
    settings = shared_settings(base)
    defaults = shared_settings(ExperimentConfig(out=base.out, preset=base.preset).resolved())
    before = recorded.get("settings", {})
    settings["methods"] = merged_methods(before.get("methods"), settings["methods"])  # other methods add
    compared = [k for k in settings if recorded and k != "methods"]
    changed = sorted(k for k in compared if before.get(k, defaults.get(k)) != settings[k])
    if changed:
        raise TvfError(
            f"{base.out} holds a sweep with other {', '.join(changed)}; use the same flags or another --out"
        )
    record = {
        "settings": settings,
        "demos": sorted({*recorded.get("demos", []), *demos}),
        "seeds": sorted({*recorded.get("seeds", []), *seeds}),
        "commands": [*recorded.get("commands", []), " ".join(["tvf", *sys.argv[1:]]) or "tvf experiment"],
    }
    atomic_write_json(path, record)
    return record


def share_data(out: Path, cell: ExperimentConfig) -> int:
    """Start the cell's dataset from the nearest other demo count's in OUT/data (the largest smaller one,
    else the smallest larger one), split by split; returns the episodes linked."""
    names = [p.name.removeprefix("demos-") for p in (Path(out) / "data").glob("demos-*")]
    counts = [int(n) for n in names if n.isdigit() and int(n) != cell.demos]
    donors = sorted(counts, key=lambda c: (c > cell.demos, abs(c - cell.demos)))
    added = 0
    for plan in data_plans(cell):
        source = next((s for c in donors if (s := data_dir(out, c) / plan.split).is_dir()), None)
        if source is not None:
            added += reuse_episodes(source, plan)
    return added


def run_sweep(base: ExperimentConfig, demos: tuple[int, ...], seeds: tuple[int, ...]) -> Path:
    """Run (or resume) every cell of the grid in order, keeping OUT/sweep.md current; returns its path.

    With only the ``report`` and ``weights`` stages, cells not started yet are left out (shown as –)."""
    if base.ship:
        raise TvfError("--ship copies one experiment's weights: run that cell alone, not a sweep")
    base = check_experiment(base)
    check_output_dir(base.out)
    if (base.out / "experiment.json").is_file():
        raise TvfError(
            f"{base.out} holds a single experiment (experiment.json); choose another --out for a sweep"
        )
    record = record_sweep(base, demos, seeds)
    stages = base.stage_list()
    starts = bool(set(stages) - {"report", "weights"})
    for n in demos:
        if "data" in stages and base.data is None:
            linked = share_data(base.out, cell_config(base, n, seeds[0]))
            if linked:
                _say(f"{data_dir(base.out, n)}: {linked} episodes shared with another demo count")
        for seed in seeds:
            cell = cell_config(base, n, seed)
            if not starts and not (cell.out / "experiment.json").is_file():
                continue
            _say(f"cell {n} demos, seed {seed}: {cell.out}")
            run_experiment(cell)
            if "report" in stages and starts:
                sweep_report(base.out, record)
    if "report" in stages:
        sweep_report(base.out, record)
    return base.out / "sweep.md"


def sweep_report(out: Path, record: dict) -> tuple[Path, Path]:
    """OUT/sweep.md, sweep.html and success-vs-demos.png over the grid and every cell found on disk."""
    cells = found_cells(out)
    demos = sorted({*record["demos"], *(d for d, _ in cells)})
    seeds = sorted({*record["seeds"], *(s for _, s in cells)})
    return write_sweep_report(out, demos, seeds, record["settings"], record.get("commands", []))


def run_experiments(base: ExperimentConfig, demos: tuple[int, ...], seeds: tuple[int, ...]) -> Path:
    """One experiment in OUT for one value of each (as before sweeps), else the sweep; returns its report."""
    if not is_sweep(base.out, demos, seeds):
        return run_experiment(replace(base, demos=demos[0], seed=seeds[0]))
    return run_sweep(base, demos, seeds)
