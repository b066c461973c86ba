"""Test-wide settings.

* pytest-xdist runs two workers on two cores, so each uses one torch thread.
* Policies cached by evaluation are forgotten after each test (tests swap the shipped weights).
"""

import pytest
import torch

from tvf.policies import forget_cached_policies

torch.set_num_threads(1)


@pytest.fixture(autouse=True)
def _forget_cached_policies():
    yield
    forget_cached_policies()
