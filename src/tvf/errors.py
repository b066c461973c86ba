"""Errors that the CLI turns into one clear line and exit code 2."""

from __future__ import annotations

import os

RERUN = "re-run the same command to resume"


class TvfError(Exception):
    """Base class for every error caused by bad input (names, files, arguments, actions)."""


class StaleError(TvfError):
    """A folder (a run, an evaluation) made from other inputs than the ones given now: other settings,
    weights or data. The message names what changed; a restart flag lets the command start it again."""


class Terminated(KeyboardInterrupt):
    """SIGTERM while a pool runs (:func:`tvf.parallel.sigterm_raises`): an interrupt, so the pool's workers
    are ended on the way out and the command exits as after Ctrl-C (code 143), finished work kept."""


class DiskFullError(TvfError):
    """No space left on the device while writing ``path``: the partial file is gone, finished work is kept.

    ``kept`` says what survived ("3 episodes kept in OUT/train"), ``rerun`` how to continue; commands fill
    them in with :meth:`keeping` as the error passes their boundary.
    """

    def __init__(self, path: str | os.PathLike = "", kept: str = "", rerun: str = RERUN) -> None:
        super().__init__(str(path), kept, rerun)  # the arguments, so the error pickles across workers
        self.path, self.kept, self.rerun = str(path), kept, rerun

    def keeping(self, kept: str, rerun: str | None = None) -> DiskFullError:
        """The same error, saying what was kept (and how to continue)."""
        return DiskFullError(self.path, kept, rerun or self.rerun)

    def __str__(self) -> str:
        where = f"{mount_point(self.path)} (writing {self.path})" if self.path else "device"
        kept = f", {self.kept}" if self.kept else ""
        return f"no space left on {where}{kept}; free space and {self.rerun}"


def mount_point(path: str | os.PathLike) -> str:
    """The mount point of the file system that holds ``path`` (which need not exist yet)."""
    p = os.path.abspath(path)
    while not os.path.ismount(p) and os.path.dirname(p) != p:
        p = os.path.dirname(p)
    return p
