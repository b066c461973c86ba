"""What an experiment's stages cost: wall and CPU time, one line per stage run in ``EXP/cost.jsonl``.

Each run of a stage appends its line when it ends, also when it stops on an error or Ctrl-C
(``"finished": false``), so a resumed stage adds its pieces. CPU time is this process's (torch's
threads included) plus that of the child processes it waited for (the generation and evaluation
workers); jobs on another machine (``--backend ray``) and a process killed without notice (SIGKILL)
leave no record. The sweep report sums the lines per cell and stage.
"""

from __future__ import annotations

import resource
import time
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import UTC, datetime
from pathlib import Path

from tvf.io import append_jsonl, read_jsonl

COST_LOG = "cost.jsonl"


def cpu_seconds() -> float:
    """User and system CPU time of this process and of its waited-for children, in seconds."""
    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


@contextmanager
def costed(out: Path, stage: str) -> Iterator[None]:
    """Append ``stage``'s wall and CPU seconds to ``out/cost.jsonl`` when the block ends, however it ends."""
    started = datetime.now(UTC).isoformat(timespec="seconds")
    wall, cpu = time.monotonic(), cpu_seconds()
    finished = False
    try:
        yield
        finished = True
    finally:
        record = {"stage": stage, "started": started, "wall_s": round(time.monotonic() - wall, 1),
                  "cpu_s": round(cpu_seconds() - cpu, 1), "finished": finished}  # fmt: skip
        Path(out).mkdir(parents=True, exist_ok=True)
        append_jsonl(Path(out) / COST_LOG, record)


def hours(seconds: float) -> str:
    """Seconds as hours with two decimals, the unit the reports give cost in."""
    return f"{seconds / 3600:.2f}"


def stage_costs(out: Path) -> dict[str, dict[str, float]]:
    """``{stage: {"wall_s": ..., "cpu_s": ...}}`` summed over every recorded run of each stage in ``out``
    ({} when nothing is recorded)."""
    totals: dict[str, dict[str, float]] = {}
    for record in read_jsonl(Path(out) / COST_LOG):
        entry = totals.setdefault(str(record.get("stage")), {"wall_s": 0.0, "cpu_s": 0.0})
        for key in entry:
            entry[key] += float(record.get(key) or 0.0)
    return totals
