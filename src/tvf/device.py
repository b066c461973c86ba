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


def mixes_environments(device: torch.device) -> bool:
    """Whether the rows of several environments may share one model call on ``device``.

    Not on the CPU: its convolutions round differently with the batch, so keeping each environment's
    rows in calls of their own makes N environments per process decide bit-for-bit as one at a time
    (and batching buys little there). Elsewhere (a GPU, where large batches are the point) they do.
    """
    return device.type != "cpu"
