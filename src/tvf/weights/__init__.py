"""Shipped weights (GCTN and VF trained by `tvf experiment` at 10 demos per task), named after their preset.

``provenance.json`` beside them records the command, seeds, data fingerprint and metrics. Commands load
these by default when no ``--gctn`` / ``--vf`` is given.
"""

from __future__ import annotations

import json
from pathlib import Path

from tvf.errors import TvfError

WEIGHTS_DIR = Path(__file__).resolve().parent
SHIPPED_PRESET = "lite"
"""The preset whose weights ship with the package."""
KINDS = ("gctn", "vf")
PROVENANCE = "provenance.json"


def shipped_name(kind: str, preset: str = SHIPPED_PRESET) -> str:
    """The file name of ``kind``'s weights of ``preset`` (``gctn-lite.pt``): the one naming rule."""
    if kind not in KINDS:
        raise TvfError(f"no shipped weights of kind {kind!r}; choose one of {', '.join(KINDS)}")
    return f"{kind}-{preset}.pt"


def shipped_checkpoint(kind: str, preset: str = SHIPPED_PRESET) -> Path:
    """The shipped checkpoint of ``kind`` (gctn | vf); a clear error when it is missing."""
    path = WEIGHTS_DIR / shipped_name(kind, preset)
    if not path.exists():
        raise TvfError(
            f"shipped {kind} weights {path} are missing; "
            f"pass --{kind} RUN or re-create them with `make reproduce`"
        )
    return path


def provenance() -> dict:
    """The shipped weights' provenance record ({} when there is none)."""
    path = WEIGHTS_DIR / PROVENANCE
    return json.loads(path.read_text()) if path.exists() else {}
