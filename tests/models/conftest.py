"""Shared fixtures for the model tests: one CPU thread, fixed seeds, small synthetic scenes."""

from __future__ import annotations

import pytest
import torch


@pytest.fixture(autouse=True)
def _one_thread() -> None:
    """Keep each test on one thread (the machine is shared) and fix torch's global seed."""
    torch.set_num_threads(1)
    torch.manual_seed(0)


@pytest.fixture
def generator() -> torch.Generator:
    return torch.Generator().manual_seed(1234)
