"""What every command shares: the output-folder check and the flag checks.

Commands import their pipeline inside ``run()``: torch, PyBullet and matplotlib take seconds to import,
and `tvf --help` (or a typo) should not pay for them.
"""

from __future__ import annotations

from pathlib import Path

from tvf.errors import TvfError


def check_output_dir(path: Path) -> Path:
    """Create ``path`` or fail with one clear line if it cannot be written."""
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / ".tvf-write-test"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise TvfError(
            f"cannot write to output directory {path}: {exc.strerror}; choose another --out"
        ) from None
    return path


def at_least_one(**flags: int) -> None:
    """Refuse counts below 1, naming every such flag of the command (``max_tries`` -> ``--max-tries``)."""
    if any(value < 1 for value in flags.values()):
        names = [f"--{n.replace('_', '-')}" for n in flags]
        listed = names[0] if len(names) == 1 else f"{', '.join(names[:-1])} and {names[-1]}"
        raise TvfError(f"{listed} must be at least 1")
