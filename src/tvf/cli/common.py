"""What every command shares: the output checks (from tvf.io) and the flag checks.

Commands import their pipeline inside ``run()``: torch, PyBullet and matplotlib take seconds to import,
and `tvf --help` (or a typo) should not pay for them.
"""

from __future__ import annotations

from tvf.errors import TvfError
from tvf.io import check_output_dir, check_output_file

__all__ = ["at_least_one", "check_output_dir", "check_output_file"]


def at_least_one(**flags: int) -> None:
    """Refuse counts below 1, naming every such flag of the command (``max_tries`` -> ``--max-tries``)."""
    if any(value < 1 for value in flags.values()):
        names = [f"--{n.replace('_', '-')}" for n in flags]
        listed = names[0] if len(names) == 1 else f"{', '.join(names[:-1])} and {names[-1]}"
        raise TvfError(f"{listed} must be at least 1")
