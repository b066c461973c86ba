"""Checkpoints and weights: atomic save, validated load, model rebuild.

Two formats load through the same functions (:func:`load_checkpoint`, :func:`load_model`):

* a training checkpoint ``*.pt`` (runs, resumable; read with ``torch.load(weights_only=True)``), a dict
  of plain data and tensors::

    {"format": "tvf-checkpoint", "version": 2, "kind": "gctn" | "vf" | "latent", "config": {...},
     "step": int, "model": state_dict, "optimizer": state_dict | None, "extra": {...},
     "sha256": content_sha256(every entry above)}

* weights ``KIND-PRESET.safetensors`` (the shipped format, no pickle: ``safetensors.torch.load_file``)
  with a JSON config of the same name beside it::

    {"format": "tvf-weights", "version": 2, "kind": ..., "model_class": ..., "weights": FILE,
     "config": {...}, "step": int, "parameters": int, "tvf_version": ..., "extra": {...},
     "sha256": {"tensors": content_sha256(tensors), "config": SHA-256 of this JSON without "sha256"}}

``config`` must hold ``{"preset": ModelPreset.as_dict()}`` for :func:`load_model` to rebuild the
network (a class with a ``from_config(preset, config)`` classmethod reads its other entries too: the
latent model's ``"latent"`` sizes); anything else in it (and in ``extra``) must be plain Python data
(dict, list, str, numbers, bool, None) or tensors (checkpoints only).

Every load checks the content against its SHA-256 (:func:`content_sha256`: the values, not the
bytes), so a damaged file is one :class:`CheckpointError` naming it, never other weights. Files of
version 1 (no hash) load unverified, with one warning each.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

import safetensors
import safetensors.torch
import torch
from torch import nn

import tvf
from tvf.errors import TvfError
from tvf.io import atomic_path, atomic_write_bytes, atomic_write_json
from tvf.models.gctn import GCTN
from tvf.models.latent import LatentDynamics
from tvf.models.presets import ModelPreset, PresetError
from tvf.models.vf import VisualForesight
from tvf.runs import resolve_checkpoint
from tvf.weights import WEIGHTS_SUFFIX, config_path, shipped_checkpoint

FORMAT = "tvf-checkpoint"
VERSION = 2
WEIGHTS_FORMAT = "tvf-weights"
WEIGHTS_VERSION = 2
UNVERIFIED_VERSION = 1
"""The version before hashes (of both formats): still read, unverified, with a warning."""
HASH = "sha256"


class CheckpointError(TvfError):
    """A checkpoint is missing, unreadable, of another model kind or incompatible with the config."""


@dataclass
class Checkpoint:
    """A loaded checkpoint (``model``/``optimizer`` are state dicts)."""

    path: Path
    kind: str
    config: dict[str, Any]
    step: int
    model: dict[str, torch.Tensor]
    optimizer: dict[str, Any] | None = None
    extra: dict[str, Any] = field(default_factory=dict)


def model_kind(model: nn.Module) -> str:
    """The checkpoint kind of a model (its ``checkpoint_kind`` attribute)."""
    kind = getattr(model, "checkpoint_kind", None)
    if not isinstance(kind, str):
        raise TypeError(f"{type(model).__name__} has no checkpoint_kind attribute")
    return kind


_PLAIN = (str, int, float, bool, type(None), torch.Tensor)


def _check_plain(value: Any, where: str) -> None:
    """Refuse data that ``torch.load(weights_only=True)`` could not read back (numpy, objects)."""
    if isinstance(value, dict):
        for key, item in value.items():
            if not isinstance(key, str | int):
                raise TypeError(f"{where} has a non-string key {key!r}")
            _check_plain(item, f"{where}[{key!r}]")
    elif isinstance(value, list | tuple):
        for i, item in enumerate(value):
            _check_plain(item, f"{where}[{i}]")
    elif not isinstance(value, _PLAIN):
        raise TypeError(f"{where} is a {type(value).__name__}; checkpoints hold plain data and tensors only")


def _feed(digest, value: Any) -> None:
    """Feed a value of plain data and tensors to ``digest``, unambiguously (types, lengths, order)."""
    if isinstance(value, torch.Tensor):
        t = value.detach().cpu().contiguous()
        digest.update(f"T{t.dtype}{tuple(t.shape)}:".encode())
        digest.update(t.reshape(-1).view(torch.uint8).numpy())  # the buffer itself, no copy
    elif isinstance(value, dict):
        digest.update(f"d{len(value)}:".encode())
        for key, item in value.items():
            _feed(digest, key)
            _feed(digest, item)
    elif isinstance(value, list | tuple):
        digest.update(f"{'l' if isinstance(value, list) else 't'}{len(value)}:".encode())
        for item in value:
            _feed(digest, item)
    elif isinstance(value, str):
        data = value.encode()
        digest.update(f"s{len(data)}:".encode() + data)
    elif isinstance(value, float):
        digest.update(f"f{float(value).hex()};".encode())
    elif isinstance(value, bool | int) or value is None:
        digest.update(f"{type(value).__name__}{value!r};".encode())
    else:
        raise TypeError(f"cannot hash a {type(value).__name__}")


def content_sha256(value: Any) -> str:
    """SHA-256 of nested plain data and tensors (dtypes, shapes and bytes; dict order counts): what a
    checkpoint stores of its payload and a weights config of its tensors."""
    digest = hashlib.sha256()
    _feed(digest, value)
    return digest.hexdigest()


def _config_sha256(meta: dict[str, Any]) -> str:
    """SHA-256 of a weights config as JSON reads it back, without its ``sha256`` entry."""
    rest = {k: v for k, v in meta.items() if k != HASH}
    return hashlib.sha256(json.dumps(rest, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def _tensors_sha256(tensors: dict[str, torch.Tensor]) -> str:
    return content_sha256({name: tensors[name] for name in sorted(tensors)})


@cache
def _warn_unverified(path: Path) -> None:
    print(
        f"tvf: warning: {path} was written before checkpoints carried a SHA-256 (version "
        f"{UNVERIFIED_VERSION}) and is loaded unverified; export or train it again with this tvf",
        file=sys.stderr,
    )


def save_checkpoint(
    path: str | os.PathLike,
    model: nn.Module,
    optimizer: torch.optim.Optimizer | None = None,
    step: int = 0,
    config: dict[str, Any] | None = None,
    extra: dict[str, Any] | None = None,
) -> Path:
    """Write a checkpoint atomically (temporary file in the same folder, then ``os.replace``).

    ``config`` defaults to ``model.config()``. Returns the path written.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if config is None:
        config = model.config() if hasattr(model, "config") else {}
    _check_plain(config, "config")
    _check_plain(extra or {}, "extra")
    payload = {
        "format": FORMAT,
        "version": VERSION,
        "kind": model_kind(model),
        "config": config,
        "step": int(step),
        "model": model.state_dict(),
        "optimizer": optimizer.state_dict() if optimizer is not None else None,
        "extra": extra or {},
    }
    payload[HASH] = content_sha256(payload)
    with atomic_path(path) as tmp, tmp.open("wb") as f:
        torch.save(payload, f)
        f.flush()
        os.fsync(f.fileno())
    return path


def save_weights(
    path: str | os.PathLike,
    model: nn.Module,
    step: int = 0,
    config: dict[str, Any] | None = None,
    extra: dict[str, Any] | None = None,
) -> Path:
    """Write ``model``'s tensors as safetensors to ``path`` and its JSON config beside it (both atomically).

    ``config`` defaults to ``model.config()``; ``extra`` (plain data) is kept in the JSON. Returns ``path``.
    """
    path = Path(path)
    if path.suffix != WEIGHTS_SUFFIX:
        raise CheckpointError(f"weights file {path} must end in {WEIGHTS_SUFFIX}")
    config = model.config() if config is None else config
    extra = extra or {}
    _check_plain(config, "config")
    _check_plain(extra, "extra")
    kind = model_kind(model)
    tensors = {k: v.detach().cpu().contiguous() for k, v in model.state_dict().items()}
    header = {WEIGHTS_FORMAT: kind}  # one key: safetensors writes several in any order (same bytes each time)
    atomic_write_bytes(path, safetensors.torch.save(tensors, metadata=header))
    meta = json.loads(
        json.dumps(
            {
                "format": WEIGHTS_FORMAT,
                "version": WEIGHTS_VERSION,
                "kind": kind,
                "model_class": type(model).__name__,
                "weights": path.name,
                "config": config,
                "step": int(step),
                "parameters": sum(p.numel() for p in model.parameters()),
                "tvf_version": tvf.__version__,
                "extra": extra,
            },
            default=str,
        )
    )  # fmt: skip  (as a reader will decode it, for its hash)
    meta[HASH] = {"tensors": _tensors_sha256(tensors), "config": _config_sha256(meta)}
    atomic_write_json(config_path(path), meta, indent=2)
    return path


def _read_weights(path: Path) -> dict[str, Any]:
    """A safetensors weights file and its JSON config, as a checkpoint payload (no optimiser), checked
    against the hashes the config records."""
    meta_path = config_path(path)
    if not meta_path.is_file():
        raise CheckpointError(
            f"weights {path} have no config {meta_path.name} beside them; copy it along or re-export them"
        )
    try:
        meta = json.loads(meta_path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
        raise CheckpointError(f"weights config {meta_path} is not valid JSON ({e}); re-export it") from e
    if not isinstance(meta, dict) or meta.get("format") != WEIGHTS_FORMAT:
        raise CheckpointError(f"{meta_path} is not a tvf weights config; pass weights written by tvf")
    hashes, what = meta.get(HASH), f"weights config {meta_path}"
    fix, upgrade = "copy it again or re-export the weights", "re-export the weights with this version"
    if hashes is None:
        _check_unhashed(what, meta.get("version"), WEIGHTS_VERSION, upgrade, fix)
    else:
        if not isinstance(hashes, dict) or _config_sha256(meta) != hashes.get("config"):
            raise CheckpointError(f"{what} does not match its SHA-256 (the file is damaged); {fix}")
        _check_version(what, meta.get("version"), WEIGHTS_VERSION, upgrade)
    try:
        tensors = safetensors.torch.load_file(path, device="cpu")
        with safetensors.safe_open(path, framework="pt") as f:
            header = f.metadata() or {}
    except Exception as e:  # the Rust reader raises several kinds on a damaged header
        raise CheckpointError(
            f"weights {path} are corrupt or not safetensors ({type(e).__name__}); pass another file"
        ) from e
    if header.get(WEIGHTS_FORMAT) != meta.get("kind"):
        raise CheckpointError(
            f"weights {path} hold a {header.get(WEIGHTS_FORMAT)!r} model but {meta_path.name} describes a "
            f"{meta.get('kind')!r} one; pass matching files"
        )
    if hashes is None:
        _warn_unverified(path)
    elif _tensors_sha256(tensors) != hashes.get("tensors"):
        raise CheckpointError(
            f"weights {path} do not match the SHA-256 of their tensors in {meta_path.name} (the file is "
            "damaged or belongs to other weights); copy it again or re-export the weights"
        )
    return {
        "format": FORMAT, "version": VERSION, "kind": meta["kind"], "config": meta.get("config"),
        "step": meta.get("step", 0), "model": tensors, "optimizer": None, "extra": meta.get("extra"),
    }  # fmt: skip


def _read(path: Path) -> dict[str, Any]:
    if not path.is_file():
        raise CheckpointError(f"checkpoint {path} does not exist; train a model first or pass the right path")
    if path.suffix == WEIGHTS_SUFFIX:
        return _read_weights(path)
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as e:  # on arbitrary bytes torch.load raises anything (KeyError for a text file)
        raise CheckpointError(
            f"checkpoint {path} is corrupt or not a tvf checkpoint (torch.load: {type(e).__name__}); "
            "pass another file or train again"
        ) from e
    if not isinstance(payload, dict) or payload.get("format") != FORMAT:
        raise CheckpointError(f"{path} is not a tvf checkpoint; pass a file written by tvf training")
    _check_payload(path, payload)
    return payload


def _check_unhashed(what: str, version: Any, current: int, upgrade: str, fix: str) -> None:
    """A file without a hash: of the version before hashes it is read (unverified); of the current
    version it is damaged; of another one it is refused."""
    if version == UNVERIFIED_VERSION:
        return
    if version == current:
        raise CheckpointError(f"{what} has no SHA-256 to check it against (the file is damaged); {fix}")
    _check_version(what, version, current, upgrade)


def _check_version(what: str, version: Any, current: int, upgrade: str) -> None:
    """Refuse a file of a version this tvf does not write (checked after its hash, if it has one)."""
    if version != current:
        raise CheckpointError(f"{what} has format version {version}, this tvf reads {current}; {upgrade}")


def _check_payload(path: Path, payload: dict[str, Any]) -> None:
    """The payload's version is one this tvf reads and its content matches its SHA-256 (popped)."""
    digest, version, what = payload.pop(HASH, None), payload.get("version"), f"checkpoint {path}"
    fix, upgrade = (
        "train again or pass another checkpoint (RUN/checkpoints/step_N.pt)",
        "retrain with this version",
    )
    if digest is None:
        _check_unhashed(what, version, VERSION, upgrade, fix)
        _warn_unverified(path)
        return
    try:
        ok = isinstance(digest, str) and content_sha256(payload) == digest
    except TypeError:
        ok = False
    if not ok:
        raise CheckpointError(f"{what} does not match its SHA-256 (the file is damaged); {fix}")
    _check_version(what, version, VERSION, upgrade)


def _config_differences(found: dict[str, Any], expected: dict[str, Any], prefix: str = "") -> list[str]:
    diffs = []
    for key in sorted(set(found) | set(expected)):
        a, b = found.get(key, "<missing>"), expected.get(key, "<missing>")
        if isinstance(a, dict) and isinstance(b, dict):
            diffs += _config_differences(a, b, f"{prefix}{key}.")
        elif a != b:
            diffs.append(f"{prefix}{key}: checkpoint {a!r} vs expected {b!r}")
    return diffs


def _check_config(path: Path, found: dict[str, Any], expected: dict[str, Any]) -> None:
    diffs = _config_differences(found, expected)
    if diffs:
        raise CheckpointError(
            f"checkpoint {path} was trained with another config ({'; '.join(diffs)}); "
            "use the matching preset/config or retrain"
        )


def load_checkpoint(
    path: str | os.PathLike,
    expected_kind: str,
    model: nn.Module | None = None,
    optimizer: torch.optim.Optimizer | None = None,
    expected_config: dict[str, Any] | None = None,
) -> Checkpoint:
    """Read and validate a checkpoint; optionally load it into ``model`` and ``optimizer``.

    Raises :class:`CheckpointError` (one message naming the file and the fix) when the file is missing
    or corrupt, holds another model kind, its config differs from ``expected_config`` (defaults to
    ``model.config()`` when a model is given), or its weights do not fit ``model``.
    """
    path = Path(path)
    payload = _read(path)
    kind = payload.get("kind")
    if kind != expected_kind:
        raise CheckpointError(
            f"checkpoint {path} holds a {kind!r} model, expected {expected_kind!r}; "
            f"pass a {expected_kind} checkpoint"
        )
    config = payload.get("config") or {}
    if expected_config is None and model is not None and hasattr(model, "config"):
        expected_config = model.config()
    if expected_config is not None:
        _check_config(path, config, expected_config)
    ckpt = Checkpoint(
        path=path,
        kind=kind,
        config=config,
        step=int(payload.get("step", 0)),
        model=payload["model"],
        optimizer=payload.get("optimizer"),
        extra=payload.get("extra") or {},
    )
    if model is not None:
        load_weights(model, ckpt)
    if optimizer is not None and ckpt.optimizer is not None:
        try:
            optimizer.load_state_dict(ckpt.optimizer)
        except (ValueError, KeyError, RuntimeError) as e:
            raise CheckpointError(
                f"optimizer state in {path} does not fit this optimizer ({e}); resume with the same optimizer"
            ) from e
    return ckpt


def load_weights(model: nn.Module, ckpt: Checkpoint) -> None:
    """Load a checkpoint's weights into ``model``; a shape or key mismatch raises :class:`CheckpointError`."""
    try:
        model.load_state_dict(ckpt.model)
    except RuntimeError as e:
        details = " ".join(str(e).split())[:300]
        raise CheckpointError(
            f"checkpoint {ckpt.path} does not fit this {ckpt.kind} model ({details}); "
            "use the preset it was trained with or retrain"
        ) from e


def preset_of(ckpt: Checkpoint) -> ModelPreset:
    """The :class:`ModelPreset` stored in a checkpoint's config."""
    try:
        return ModelPreset.from_dict(ckpt.config["preset"])
    except (KeyError, TypeError, PresetError) as e:
        raise CheckpointError(
            f"checkpoint {ckpt.path} has no valid model preset in its config ({e}); retrain with this tvf"
        ) from e


def load_initial_weights(
    model: nn.Module, path: str | os.PathLike, kind: str, free: tuple[str, ...] = ()
) -> Checkpoint:
    """Load the weights of ``path`` into ``model`` to start training from them. The checkpoint's config must
    be the model's, with the preset fields the file predates at their defaults and the preset fields
    named in ``free`` taken as the model's (the VF's head: how one network's output is used); the
    weights must still fit."""
    ckpt = load_checkpoint(path, kind)
    preset = preset_of(ckpt).replace(**{name: getattr(model.preset, name) for name in free})
    _check_config(ckpt.path, {**ckpt.config, "preset": preset.as_dict()}, model.config())
    load_weights(model, ckpt)
    return ckpt


MODEL_CLASSES: dict[str, type[nn.Module]] = {
    cls.checkpoint_kind: cls for cls in (GCTN, VisualForesight, LatentDynamics)
}
"""Model kind -> network class (the training side of each kind lives in tvf.train.registry)."""


def build_model(ckpt: Checkpoint) -> nn.Module:
    """An untrained network of the checkpoint's kind and sizes (its preset; a class's ``from_config`` also
    reads the rest of the config)."""
    cls = MODEL_CLASSES[ckpt.kind]
    preset = preset_of(ckpt)
    from_config = getattr(cls, "from_config", None)
    if from_config is None:
        return cls(preset)
    try:
        return from_config(preset, ckpt.config)
    except (KeyError, TypeError, PresetError) as e:
        raise CheckpointError(
            f"checkpoint {ckpt.path} has no valid {ckpt.kind} sizes in its config ({e}); "
            "retrain with this tvf"
        ) from e


def load_model(path: str | os.PathLike, expected_kind: str) -> tuple[nn.Module, Checkpoint]:
    """Rebuild a model of ``expected_kind`` from its checkpoint (sizes from its config), load its weights."""
    if expected_kind not in MODEL_CLASSES:
        raise CheckpointError(f"unknown model kind {expected_kind!r}; choose one of {sorted(MODEL_CLASSES)}")
    ckpt = load_checkpoint(path, expected_kind)
    model = build_model(ckpt)
    load_weights(model, ckpt)
    return model, ckpt


def export_weights(source: str | os.PathLike, kind: str, out: str | os.PathLike) -> Path:
    """Write the model of a run directory, a ``.pt`` checkpoint or weights as ``out`` (``*.safetensors``)
    plus its JSON config: the same step, config and extra, without optimiser state. Returns ``out``."""
    model, ckpt = load_model(resolve_checkpoint(source), kind)
    return save_weights(out, model, ckpt.step, ckpt.config, ckpt.extra)


def trained_checkpoint(path: str | os.PathLike | None, kind: str) -> Path:
    """A run directory (its last checkpoint), a checkpoint or weights file, or None (the shipped weights)."""
    return shipped_checkpoint(kind) if path is None else resolve_checkpoint(path)


def load_trained(path: str | os.PathLike | None, kind: str, device: str | torch.device = "cpu") -> nn.Module:
    """A model of ``kind`` (gctn | vf | latent) in eval mode, from a run, a file or the shipped weights
    (``path`` None; none ship for the latent baseline)."""
    model, _ = load_model(trained_checkpoint(path, kind), kind)
    return model.eval().to(device)
