"""Shipped `lite` weights (GCTN and VF trained by `tvf experiment` at 10 demos per task).

``provenance.json`` beside them records the command, seeds, data fingerprint and metrics. Commands load
these by default when no ``--gctn`` / ``--vf`` is given.
"""

from __future__ import annotations

import json
from pathlib import Path

from tvf.errors import TvfError

WEIGHTS_DIR = Path(__file__).resolve().parent
FILES = {"gctn": "gctn-lite.pt", "vf": "vf-lite.pt"}


def shipped_checkpoint(kind: str) -> Path:
    """The shipped checkpoint of ``kind`` (gctn | vf); a clear error when it is missing."""
    if kind not in FILES:
        raise TvfError(f"no shipped weights of kind {kind!r}; choose one of {', '.join(FILES)}")
    path = WEIGHTS_DIR / FILES[kind]
    if not path.exists():
        raise TvfError(
            f"shipped {kind} weights {path} are missing; "
            f"pass --{kind} RUN or re-create them with `make reproduce`"
        )
    return path


def provenance() -> dict:
    """The shipped weights' provenance record ({} when there is none)."""
    path = WEIGHTS_DIR / "provenance.json"
    return json.loads(path.read_text()) if path.exists() else {}
