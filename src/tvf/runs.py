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

from tvf.errors import StaleError, TvfError
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

    def prepare(
        self, config: dict[str, Any], resume: bool, match: tuple[str, ...], restart: bool = False
    ) -> None:
        """Create the run directory, or check that a resumed one agrees with ``config`` on ``match`` and
        on the content of its data (``data_content``: a :class:`~tvf.errors.StaleError` naming the changed
        episodes, or with ``restart`` its checkpoints and logs are deleted and it starts again)."""
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
            stale = data_changes(old.get("data_content"), config.get("data_content"))
            if stale and not restart:
                raise StaleError(
                    f"{self.root} was trained on other data ({stale}); resume on the data it was made "
                    "with, pass --restart to train it again from step 0, or choose another --out"
                )
            if stale:
                print(f"tvf: {self.root}: the data changed ({stale}); training again from step 0", flush=True)
                self.clear()
        elif resume and self.last.exists():
            raise RunError(f"{self.root} has checkpoints but no config.json; it is not a tvf run")
        self.root.mkdir(parents=True, exist_ok=True)
        atomic_write_json(self.config_path, config, indent=2)

    def clear(self) -> None:
        """Delete the run's checkpoints, metrics and TensorBoard events (for a restart)."""
        for path in (*(p for _, p in self.step_checkpoints()), self.last, self.metrics_path):
            path.unlink(missing_ok=True)
        if self.tb.is_dir():
            for event in self.tb.iterdir():
                if event.is_file():
                    event.unlink()

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


def data_changes(before: dict[str, Any] | None, now: dict[str, Any] | None) -> str:
    """What differs between two ``data_content`` records ("" when they agree, or when ``before`` is
    missing: a run from before contents were recorded is trusted on its episode list), e.g.
    ``2 episodes changed content (train:stack-tower/3, val:put-plane/1), 1 added (train:x/5)``."""
    if not before or not now or before.get("digest") == now.get("digest"):
        return ""
    old, new = before.get("episodes", {}), now.get("episodes", {})
    parts = []
    for what, names in (
        ("changed content", [k for k in old if k in new and old[k] != new[k]]),
        ("added", [k for k in new if k not in old]),
        ("removed", [k for k in old if k not in new]),
    ):
        if names:
            shown = ", ".join(sorted(names)[:3]) + (", …" if len(names) > 3 else "")
            parts.append(f"{len(names)} episode{'s' * (len(names) != 1)} {what} ({shown})")
    return ", ".join(parts) or f"content {str(before.get('digest'))[:8]}… → {str(now.get('digest'))[:8]}…"


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
