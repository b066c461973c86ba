"""Fixtures for the data tests: synthetic episodes (fast) and one tiny real dataset (a few seconds)."""

from __future__ import annotations

import pytest
from data_factory import make_episode

from tvf.data import Episode


@pytest.fixture
def episode() -> Episode:
    return make_episode()


@pytest.fixture(scope="session")
def real_root(tmp_path_factory):
    """Two real stack-stair train-split episodes generated in this process (OUT root)."""
    from tvf.data import GenerationPlan, generate

    out = tmp_path_factory.mktemp("demos")
    report = generate(GenerationPlan(("stack-stair",), "train", 2, out), workers=1, progress=False)
    assert not report.short, report
    return out
