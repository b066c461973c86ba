"""Fixtures of the training tests."""

from __future__ import annotations

import pytest
from test_training import TASKS, synthetic_episode

from tvf.data.format import episode_name, write_episode


@pytest.fixture
def own_data(tmp_path):
    """A dataset root of synthetic episodes: train seeds 0 and 2, test seed 1, of each of TASKS."""
    root = tmp_path / "demos"
    for split, seeds in (("train", (0, 2)), ("test", (1,))):
        for task in TASKS:
            for seed in seeds:
                write_episode(root / split / task / episode_name(seed), synthetic_episode(task, seed, split))
    return root
