"""The evaluation protocol's three disjoint seed ranges (docs/results.md, "Protocol").

* **demonstrations**: the train split of `tvf demos`, even seeds from 0 (what the models learn from);
* **validation**: odd seeds from 1 (the test split of `tvf demos`, validation losses, and every
  closed-loop run that chooses a recipe, a lever or a checkpoint);
* **test**: odd seeds from 1 000 001 (reported numbers only; never used for a choice).

Every command that runs episodes uses the one seed rule: episode ``i`` has seed ``seed_start + 2 i``, so
a range is named by its first seed. A few thousand demonstrations or validation episodes stay far
below the test range.
"""

from __future__ import annotations

DEMO_FIRST_SEED = 0
VALIDATION_SEED_START = 1
TEST_SEED_START = 1_000_001
SEED_RANGES = {"validation": VALIDATION_SEED_START, "test": TEST_SEED_START}


def episode_seeds(seed_start: int, episodes: int) -> list[int]:
    """The one seed rule of every command: episode ``i`` uses seed ``seed_start + 2 i``."""
    return [seed_start + 2 * i for i in range(episodes)]


def seed_range(seed: int) -> str:
    """Which range a seed belongs to: demonstrations (even, below the test range), validation, test."""
    if seed >= TEST_SEED_START:
        return "test"
    return "validation" if seed % 2 else "demonstrations"
