"""The stage cost log: wall and CPU seconds per stage run, children's CPU counted, interrupted runs kept."""

from __future__ import annotations

import subprocess
import sys

import pytest

from tvf.experiment.cost import COST_LOG, costed, stage_costs
from tvf.io import read_jsonl

BURN = "import time\nt = time.process_time()\nwhile time.process_time() - t < 0.4: pass"


def test_a_stage_records_its_wall_and_cpu_time_with_its_childrens(tmp_path):
    with costed(tmp_path, "eval"):
        subprocess.run([sys.executable, "-c", BURN], check=True)  # a worker's CPU, waited for
    (record,) = read_jsonl(tmp_path / COST_LOG)
    assert record["stage"] == "eval" and record["finished"] is True
    assert record["cpu_s"] >= 0.35 and record["wall_s"] >= 0.35
    assert record["started"].endswith("+00:00")  # UTC


def test_an_interrupted_stage_is_recorded_and_its_pieces_add_up(tmp_path):
    with pytest.raises(KeyboardInterrupt), costed(tmp_path, "train"):
        raise KeyboardInterrupt
    with costed(tmp_path, "train"):
        pass
    records = read_jsonl(tmp_path / COST_LOG)
    assert [r["finished"] for r in records] == [False, True]
    totals = stage_costs(tmp_path)
    assert set(totals) == {"train"}
    assert totals["train"]["cpu_s"] == pytest.approx(sum(r["cpu_s"] for r in records))
    assert stage_costs(tmp_path / "none") == {}
