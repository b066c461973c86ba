"""The one owner of the run-folder layout (LeRobot-style), used by training, evaluation and the CLI::

RUN/config.json              the resolved configuration, the model preset and the data fingerprint
                             (`tvf train --config RUN/config.json` relaunches the run from it)
RUN/metrics.jsonl            one JSON object per logged step ({"step", "split": "train"|"val", ...})
RUN/tb/                      TensorBoard events (the same numbers, and validation images)
RUN/wandb/                   Weights & Biases files, with `tvf train --wandb`
RUN/checkpoints/step_N.pt    checkpoints (tvf.models.checkpoint format), written atomically
RUN/checkpoints/last.pt      the newest one; `--resume` continues from it (`--keep N` deletes all but the
                             newest N step checkpoints, never last.pt)
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

from tvf.errors import TvfError
from tvf.io import append_jsonl, atomic_write_bytes, atomic_write_json, read_json, read_jsonl

STEP_FILE = re.compile(r"step_(\d+)\.pt")
"""The name of a step checkpoint (:meth:`RunDir.step_checkpoint`)."""


class RunError(TvfError):
    """A run directory that cannot be created, resumed or read."""


class RunDir:
    """Files of one training run."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self.checkpoints = self.root / "checkpoints"
        self.config_path = self.root / "config.json"
        self.metrics_path = self.root / "metrics.jsonl"
        self.tb = self.root / "tb"

    @property
    def last(self) -> Path:
        return self.checkpoints / "last.pt"

    def step_checkpoint(self, step: int) -> Path:
        return self.checkpoints / f"step_{step:06d}.pt"

    def step_checkpoints(self) -> list[tuple[int, Path]]:
        """(step, path) of every RUN/checkpoints/step_N.pt, oldest step first (other files are ignored)."""
        if not self.checkpoints.is_dir():
            return []
        found = [(p, STEP_FILE.fullmatch(p.name)) for p in self.checkpoints.iterdir()]
        return sorted((int(m.group(1)), p) for p, m in found if m and p.is_file())

    def read_config(self) -> dict[str, Any]:
        return read_json(self.config_path, f"is {self.root} a run made by `tvf train`?")

    def prepare(self, config: dict[str, Any], resume: bool, match: tuple[str, ...]) -> None:
        """Create the run directory, or check that a resumed one agrees with ``config`` on ``match``."""
        if self.config_path.exists():
            old = self.read_config()
            old.setdefault("schedule", {"name": "constant"})  # runs made before schedules existed
            if not resume:
                raise RunError(
                    f"{self.root} already holds a run; pass --resume to continue it or choose another --out"
                )
            changed = [k for k in match if old.get(k) != config.get(k)]
            if changed:
                raise RunError(
                    f"{self.root} was made with different {', '.join(changed)}; resume with the same flags"
                )
        elif resume and self.last.exists():
            raise RunError(f"{self.root} has checkpoints but no config.json; it is not a tvf run")
        self.root.mkdir(parents=True, exist_ok=True)
        atomic_write_json(self.config_path, config, indent=2)

    def log(self, record: dict[str, Any]) -> None:
        append_jsonl(self.metrics_path, record)

    def metrics(self) -> list[dict[str, Any]]:
        return read_jsonl(self.metrics_path)

    def last_validation(self) -> dict[str, Any]:
        """The newest validation record ({} when there is none)."""
        vals = [r for r in self.metrics() if r.get("split") == "val"]
        return vals[-1] if vals else {}

    def truncate_metrics(self, step: int) -> None:
        """Drop records past ``step`` (logged after the checkpoint a resumed run restarts from)."""
        if not self.metrics_path.exists():
            return
        keep = [r for r in self.metrics() if r.get("step", 0) <= step]
        atomic_write_bytes(self.metrics_path, "".join(json.dumps(r) + "\n" for r in keep).encode())


def resolve_checkpoint(path: str | Path) -> Path:
    """A run directory (its checkpoints/last.pt), a checkpoint or a weights file; a clear error otherwise."""
    path = Path(path)
    if path.is_dir():
        last = RunDir(path).last
        if not last.exists():
            raise RunError(f"{path} holds no checkpoints/last.pt; pass a run directory made by `tvf train`")
        return last
    if not path.exists():
        raise RunError(f"checkpoint {path} does not exist; pass a run directory, a .pt or .safetensors file")
    return path
