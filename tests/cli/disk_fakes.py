"""A disk that fills up on cue, and a scripted world, for the full-disk tests (issue 16, case 3).

:class:`FakeDisk` routes every way tvf writes a file through one byte budget: ``Path.write_bytes``
(episodes, JSON, summaries), ``os.write`` (the JSON-lines logs), ``torch.save`` (checkpoints) and
``shutil.copyfile`` (``last.pt``). A write that crosses the budget writes what fits, then raises
``OSError(ENOSPC)`` the way the real call does (``torch.save`` wraps it in its ``RuntimeError``).
Without a budget it only counts the writes, so a test can aim at the middle of a chosen one.
"""

from __future__ import annotations

import errno
import os
import shutil
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch


def no_space() -> OSError:
    return OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


class FakeDisk:
    """A byte budget over tvf's write primitives; ``writes`` counts the write calls per file name."""

    def __init__(self, monkeypatch) -> None:
        self.free: int | None = None  # None: unlimited
        self.writes: Counter[str] = Counter()
        self.target: tuple[str, int] | None = None
        real_write_bytes, real_write, real_save = Path.write_bytes, os.write, torch.save
        disk = self

        def write_bytes(path: Path, data) -> int:
            data = memoryview(data).cast("B")
            n = disk.take(path.name, len(data))
            real_write_bytes(path, data[:n])
            if n < len(data):
                raise no_space()
            return n

        def write(fd: int, data) -> int:
            data = memoryview(data).cast("B")
            n = disk.take(Path(os.readlink(f"/proc/self/fd/{fd}")).name, len(data))
            if n == 0 and len(data):
                raise no_space()
            return real_write(fd, data[:n])

        def save(obj, f, *args, **kwargs) -> None:
            real_save(obj, _BudgetFile(disk, f), *args, **kwargs)

        def copyfile(src, dst, *args, **kwargs):
            data = Path(src).read_bytes()
            write_bytes(Path(dst), data)
            return dst

        monkeypatch.setattr(Path, "write_bytes", write_bytes)
        monkeypatch.setattr(os, "write", write)
        monkeypatch.setattr(torch, "save", save)
        monkeypatch.setattr(shutil, "copyfile", copyfile)

    def take(self, name: str, size: int) -> int:
        """Bytes of a ``size``-byte write to ``name`` that fit (all of them without a budget)."""
        if name.startswith(".") and name.endswith(".tmp"):  # tvf.io.temp_path: .NAME.PID.tmp
            name = name[1:].rsplit(".", 2)[0]
        self.writes[name] += 1
        if self.target == (name, self.writes[name]):
            self.target, self.free = None, size // 2  # the disk fills halfway through this write
        if self.free is None:
            return size
        n = min(size, self.free)
        self.free -= n
        return n

    def fill_during(self, name: str, occurrence: int = 1) -> None:
        """Fill the disk halfway through the ``occurrence``-th write (one call) to a file called ``name``;
        every write after it fails too, until ``free`` is set again (writes are counted from this call)."""
        self.target, self.writes = (name, occurrence), Counter()

    @property
    def filled(self) -> bool:
        """Whether the disk filled up (the aimed-at write happened)."""
        return self.free is not None


class _BudgetFile:
    """The file object ``torch.save`` writes to, through the disk's budget."""

    def __init__(self, disk: FakeDisk, f) -> None:
        self.disk, self.f = disk, f
        self.name = Path(getattr(f, "name", "checkpoint")).name

    def write(self, data) -> int:
        data = memoryview(data).cast("B")
        n = self.disk.take(self.name, len(data))
        self.f.write(data[:n])
        if n < len(data):
            raise no_space()
        return n

    def flush(self) -> None:
        self.f.flush()


# ------------------------------------------------------------------------------------ a scripted world
class ScriptedWorld:
    """An episode succeeds at its first step unless its seed is divisible by 3 (no simulator)."""

    def __init__(self, task) -> None:
        self.task, self.seed = task, 0
        self.obs = {"color": np.zeros((4, 4, 3), np.uint8), "height": np.zeros((4, 4), np.float32)}

    def reset(self, *, seed=None, options=None):
        self.seed = seed
        return self.obs, {"goal": self.obs, "progress": 0.0}

    def step(self, action):
        success = self.seed % 3 != 0
        info = {"success": success, "progress": 1.0 if success else 0.5, "steps": 1, "primitive": "ok"}
        return self.obs, info["progress"], success, not success, info

    def oracle_action(self):
        return np.zeros((2, 4))


@dataclass(frozen=True)
class ScriptedWorlds:
    """``tvf eval --env disk_fakes:ScriptedWorlds``."""

    def __call__(self, task) -> ScriptedWorld:
        return ScriptedWorld(task)
