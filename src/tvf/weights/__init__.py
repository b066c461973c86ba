"""Shipped weights (GCTN and VF trained by `tvf experiment` at 10 demos per task), named after their preset.

Each model is two files: ``KIND-PRESET.safetensors`` (the tensors, read without pickle) and
``KIND-PRESET.json`` (model kind, preset, training step, format version). ``provenance.json`` beside
them records the command, seeds, data fingerprint, metrics and every file's SHA-256; ``README.md`` is
the model card generated from it (tvf.experiment.shipping). Commands load these by default when no
``--gctn`` / ``--vf`` is given.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from tvf.errors import TvfError

WEIGHTS_DIR = Path(__file__).resolve().parent
SHIPPED_PRESET = "lite"
"""The preset whose weights ship with the package."""
KINDS = ("gctn", "vf")
PROVENANCE = "provenance.json"
MODEL_CARD = "README.md"
WEIGHTS_SUFFIX = ".safetensors"
CONFIG_SUFFIX = ".json"


def shipped_name(kind: str, preset: str = SHIPPED_PRESET) -> str:
    """The file name of ``kind``'s weights of ``preset`` (``gctn-lite.safetensors``): the one naming rule."""
    if kind not in KINDS:
        raise TvfError(f"no shipped weights of kind {kind!r}; choose one of {', '.join(KINDS)}")
    return f"{kind}-{preset}{WEIGHTS_SUFFIX}"


def config_path(weights: str | Path) -> Path:
    """The JSON config that belongs to a safetensors weights file: same name, ``.json``."""
    return Path(weights).with_suffix(CONFIG_SUFFIX)


def shipped_files(preset: str = SHIPPED_PRESET) -> list[str]:
    """Every file of a shipped weights folder: weights and config per kind, the provenance, the card."""
    models = [shipped_name(kind, preset) for kind in KINDS]
    return [*(n for m in models for n in (m, config_path(m).name)), PROVENANCE, MODEL_CARD]


def shipped_checkpoint(kind: str, preset: str = SHIPPED_PRESET) -> Path:
    """The shipped weights file of ``kind`` (gctn | vf); a clear error when it is missing."""
    path = WEIGHTS_DIR / shipped_name(kind, preset)
    if not path.exists():
        raise TvfError(
            f"shipped {kind} weights {path} are missing; "
            f"pass --{kind} RUN or re-create them with `make reproduce`"
        )
    return path


def provenance(folder: Path | None = None) -> dict:
    """The provenance record of a weights folder (default: the shipped one; {} when there is none)."""
    path = (WEIGHTS_DIR if folder is None else folder) / PROVENANCE
    return json.loads(path.read_text()) if path.exists() else {}


def sha256_file(path: str | Path) -> str:
    """The SHA-256 of a file's bytes, in hex (what provenance.json records per shipped file)."""
    digest = hashlib.sha256()
    with Path(path).open("rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            digest.update(block)
    return digest.hexdigest()
