"""Test-wide settings.

* pytest-xdist runs two workers on two cores, so each uses one torch thread.
* Tasks registered from a user's task file (``--task-file``) are forgotten after each test.
* Policies cached by evaluation are forgotten after each test (tests swap the shipped weights).
"""

import pytest
import torch

import tvf.tasks

torch.set_num_threads(1)


@pytest.fixture(autouse=True)
def _forget_registered_tasks():
    before = dict(tvf.tasks._EXTRA)
    yield
    tvf.tasks._EXTRA.clear()
    tvf.tasks._EXTRA.update(before)


@pytest.fixture(autouse=True)
def _forget_cached_policies():
    yield
    from tvf.evaluate import closed_loop

    closed_loop._POLICIES.clear()
