"""Which torch device a command runs its models on (``--device auto | cpu | cuda``)."""

from __future__ import annotations

import torch

from tvf.errors import TvfError

DEVICES = ("auto", "cpu", "cuda")


def pick_device(name: str = "auto") -> torch.device:
    """``auto`` is CUDA when present, else the CPU; asking for CUDA without one is a clear error."""
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name == "cuda" and not torch.cuda.is_available():
        raise TvfError("--device cuda was asked for but no CUDA device is available; use --device cpu")
    if name not in DEVICES:
        raise TvfError(f"unknown device {name!r}; choose auto, cpu or cuda")
    return torch.device(name)
