"""Datasets: a folder of episode files (``SPLIT/TASK/SEED.h5``) plus its ``manifest.json``.

A dataset directory holds one split. ``tvf demos --out ROOT --split S`` writes ``ROOT/S/``; both
:func:`open_dataset` and ``tvf data info`` accept either the split folder or the root above it.
The manifest is a summary written after each generation run, with each file's content checksum; the
files are the truth, so a missing, stale or older manifest is rebuilt by reading the file headers.
:func:`verify` reads every file in full and checks it against its checksums and the manifest's.
"""

from __future__ import annotations

import json
import zlib
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tvf import __version__
from tvf.data.format import (
    EPISODE_SUFFIX,
    FORMAT_VERSION,
    SPLITS,
    DataError,
    Episode,
    EpisodeInfo,
    read_episode,
    read_info,
)
from tvf.geometry import WORKSPACE
from tvf.io import atomic_write_bytes
from tvf.tasks import all_tasks

MANIFEST = "manifest.json"
FAILURES = "failures.jsonl"
MOVES_FILE = "moves.json"
"""Names the method whose own moves a split folder made with ``tvf demos --moves`` holds."""
EAGER_IMAGE_BYTES = 2 << 30
"""Up to this many bytes of images (2 GiB), :meth:`DemoDataset.load_all` reads them into memory;
above it they stay on disk (:class:`~tvf.data.format.LazyFrames`)."""


def image_bytes(infos: Iterable[EpisodeInfo]) -> int:
    """Memory the colour (uint8) and height (float32) frames of these episodes take when read."""
    h, w = WORKSPACE.shape
    per_frame = h * w * (3 * np.dtype(np.uint8).itemsize + np.dtype(np.float32).itemsize)
    return sum((e.steps + 1) * per_frame for e in infos)


def episode_files(root: Path) -> list[Path]:
    """Every episode file under ``root/TASK/`` (temporary and hidden files excluded), sorted."""
    return sorted(p for p in root.glob(f"*/*{EPISODE_SUFFIX}") if not p.name.startswith("."))


def _task_order(names: Iterable[str]) -> list[str]:
    """Task names in the task table's order, unknown (user) tasks after them alphabetically."""
    table = {name: i for i, name in enumerate(all_tasks())}
    return sorted(set(names), key=lambda n: (table.get(n, len(table)), n))


@dataclass
class DemoDataset:
    """The episodes of one split, grouped by task (sorted by seed)."""

    root: Path
    split: str
    episodes: dict[str, list[EpisodeInfo]]

    @property
    def tasks(self) -> list[str]:
        return list(self.episodes)

    def __len__(self) -> int:
        return sum(len(v) for v in self.episodes.values())

    def infos(self) -> list[EpisodeInfo]:
        return [e for eps in self.episodes.values() for e in eps]

    def n_transitions(self, task: str | None = None) -> int:
        eps = self.episodes.get(task, []) if task else self.infos()
        return sum(e.steps for e in eps)

    def size_bytes(self, task: str | None = None) -> int:
        eps = self.episodes.get(task, []) if task else self.infos()
        return sum(e.bytes for e in eps)

    def info(self, task: str, seed: int) -> EpisodeInfo:
        for e in self.episodes.get(task, []):
            if e.seed == seed:
                return e
        raise DataError(f"{self.root}: no episode of task {task!r} with seed {seed}")

    def load(self, task: str, seed: int) -> Episode:
        return read_episode(self.info(task, seed).path)

    def load_all(self, infos: Iterable[EpisodeInfo] | None = None, lazy: bool | None = None) -> list[Episode]:
        """Read the given episodes (default: all); ``lazy`` leaves the images on disk until indexed (each
        frame read and checked when a sampler draws it). None: lazy when their images would take more
        than :data:`EAGER_IMAGE_BYTES` of memory (the 1000-demo set: about 8 GB)."""
        infos = list(self.infos() if infos is None else infos)
        if lazy is None:
            lazy = image_bytes(infos) > EAGER_IMAGE_BYTES
        return [read_episode(e.path, lazy) for e in infos]

    def summary(self) -> dict[str, Any]:
        """Per-task and total counts (what ``tvf data info`` prints and the manifest stores)."""
        tasks = {
            t: {
                "episodes": len(eps),
                "transitions": sum(e.steps for e in eps),
                "random_transitions": sum(e.random_steps for e in eps),
                "bytes": sum(e.bytes for e in eps),
            }
            for t, eps in self.episodes.items()
        }
        n = self.n_transitions()
        return {
            "split": self.split,
            "episodes": len(self),
            "transitions": n,
            "bytes": self.size_bytes(),
            "bytes_per_transition": self.size_bytes() / n if n else 0.0,
            "tasks": tasks,
        }


def build_manifest(dataset: DemoDataset, failures: int = 0) -> dict[str, Any]:
    return {
        "format_version": FORMAT_VERSION,
        "tvf_version": __version__,
        **dataset.summary(),
        "failures": failures,
        "files": [e.to_dict(dataset.root) for e in dataset.infos()],
    }


def write_manifest(dataset: DemoDataset, failures: int = 0) -> Path:
    """Write ``manifest.json`` atomically (temporary file + rename, ordinary permissions)."""
    path = dataset.root / MANIFEST
    atomic_write_bytes(path, (json.dumps(build_manifest(dataset, failures), indent=1) + "\n").encode())
    return path


def _manifest_infos(root: Path, files: list[Path]) -> list[EpisodeInfo] | None:
    """The manifest's episode list if it describes exactly ``files`` (same names and sizes), else None."""
    path = root / MANIFEST
    if not path.is_file():
        return None
    try:
        doc = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise DataError(f"{path}: unreadable manifest ({exc}); delete it to rebuild from the files") from None
    version = doc.get("format_version") if isinstance(doc, dict) else None
    if isinstance(version, int) and 0 < version < FORMAT_VERSION:
        return None  # an older manifest: rebuilt from the files (format 1 files are read unverified)
    if version != FORMAT_VERSION:
        raise DataError(
            f"{path}: dataset format version {version}, this tvf reads version {FORMAT_VERSION}; "
            "regenerate the dataset with `tvf demos`"
        )
    try:
        infos = [
            EpisodeInfo(
                root / d["path"],
                d["task"],
                int(d["seed"]),
                d["split"],
                int(d["steps"]),
                int(d["random_steps"]),
                int(d["bytes"]),
                d.get("checksum"),
            )
            for d in doc["files"]
        ]
    except (KeyError, TypeError, ValueError):
        return None
    on_disk = {p: p.stat().st_size for p in files}
    if {e.path: e.bytes for e in infos} != on_disk:
        return None
    return infos


def scan(root: Path, split: str | None = None, use_manifest: bool = True) -> DemoDataset:
    """Index the episode files of one split folder (headers are read unless the manifest is current)."""
    files = episode_files(root)
    infos = _manifest_infos(root, files) if use_manifest else None
    if infos is None:
        infos = [read_info(p) for p in files]
    return _index(root, infos, split)


def _index(root: Path, infos: list[EpisodeInfo], split: str | None) -> DemoDataset:
    """The dataset of these episodes, grouped by task and sorted by seed; misplaced files are refused."""
    split = split or (root.name if root.name in SPLITS else None)
    for e in infos:
        if split is None:
            split = e.split
        if e.split != split:
            raise DataError(f"{e.path}: episode of split {e.split!r} inside the {split!r} dataset {root}")
        if e.path.parent.name != e.task:
            raise DataError(
                f"{e.path}: episode of task {e.task!r} inside the folder of {e.path.parent.name!r}"
            )
    grouped: dict[str, list[EpisodeInfo]] = {t: [] for t in _task_order(e.task for e in infos)}
    for e in infos:
        grouped[e.task].append(e)
    for eps in grouped.values():
        eps.sort(key=lambda e: e.seed)
    return DemoDataset(root, split or "train", grouped)


@dataclass
class Verification:
    """What :func:`verify` found in one split folder."""

    dataset: DemoDataset
    """The episodes that read back intact."""
    failures: dict[Path, str] = field(default_factory=dict)
    """Damaged file -> the one-line reason."""
    unverified: int = 0
    """Format 1 files: read without checksums."""


def verify(root: Path, split: str | None = None) -> Verification:
    """Read every episode file of a split folder in full, checking every array and attribute against its
    SHA-256, and each file's content checksum against the manifest's record when the manifest is current.
    A damaged file is listed, not raised, so that every one is named."""
    files = episode_files(root)
    infos, failures, unverified = [], {}, 0
    try:
        recorded = {e.path: e.checksum for e in _manifest_infos(root, files) or []}
    except DataError as exc:  # a damaged manifest is one more failure; the files are still checked
        recorded, failures[root / MANIFEST] = {}, str(exc)
    for path in files:
        try:
            info = read_info(path)
            read_episode(path)
        except DataError as exc:
            failures[path] = str(exc)
            continue
        if recorded.get(path, info.checksum) != info.checksum:
            failures[path] = (
                f"{path}: its content differs from its record in {MANIFEST} (the file was replaced); "
                "re-run `tvf demos` with the same flags to rewrite the manifest"
            )
            continue
        unverified += info.checksum is None
        infos.append(info)
    return Verification(_index(root, infos, split), failures, unverified)


def moves_of(folder: Path) -> str | None:
    """The method whose own moves a split folder holds (``moves.json``), None for demonstrations."""
    path = Path(folder) / MOVES_FILE
    if not path.exists():
        return None
    try:
        return str(json.loads(path.read_text())["moves"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise DataError(f"{path}: unreadable ({exc!r}); it names the method whose moves the folder holds"
                        ) from None  # fmt: skip


def split_dirs(path: str | Path) -> list[Path]:
    """The split folders at ``path``: itself if it is one, else its ``train``/``test`` children."""
    path = Path(path)
    if not path.is_dir():
        raise DataError(f"{path}: no such dataset directory")
    nested = [path / s for s in SPLITS if (path / s).is_dir()]
    if path.name in SPLITS and nested and not episode_files(path):
        raise DataError(
            f"{path} is a split folder holding another split ({nested[0]}): the dataset was made with "
            f"--out pointing at a split; use {nested[0]} here, and give `tvf demos` the root next time"
        )
    if (path / MANIFEST).is_file() or episode_files(path) or path.name in SPLITS:
        return [path]
    found = [path / s for s in SPLITS if (path / s).is_dir()]
    if not found:
        raise DataError(f"{path}: no episodes here (expected TASK/SEED.h5 files or train/ and test/ folders)")
    return found


def open_dataset(
    path: str | Path, split: str | None = None, tasks: Sequence[str] | None = None
) -> DemoDataset:
    """Open a dataset: a split folder, or a root holding ``train/`` and ``test/`` (then give ``split``).

    ``tasks`` keeps only those tasks and fails if one has no episodes.
    """
    path = Path(path)
    dirs = split_dirs(path)
    if split is not None:
        if split not in SPLITS:
            raise DataError(f"split {split!r} is not one of {', '.join(SPLITS)}")
        dirs = [d for d in dirs if d.name == split] or ([path / split] if (path / split).is_dir() else [])
        if not dirs:
            raise DataError(f"{path}: no {split!r} split here")
    if len(dirs) != 1:
        raise DataError(f"{path}: holds several splits ({', '.join(d.name for d in dirs)}); choose one")
    dataset = scan(dirs[0], split)
    if tasks is not None:
        missing = [t for t in tasks if not dataset.episodes.get(t)]
        if missing:
            raise DataError(f"{dataset.root}: no episodes of {', '.join(missing)}")
        dataset.episodes = {t: dataset.episodes[t] for t in tasks}
    if not len(dataset):
        raise DataError(f"{dataset.root}: the dataset holds no episodes")
    return dataset


def demo_subset(
    dataset: DemoDataset, n_demos: int, run_seed: int, tasks: Sequence[str] | None = None
) -> dict[str, list[EpisodeInfo]]:
    """The ``n_demos`` episodes per task that training run ``run_seed`` uses (facts §4).

    Each task draws from its own stream, seeded by (run_seed, crc32(task name)), a random permutation
    of its episodes (sorted by seed) and keeps the first ``n_demos``. So a task's subset does not
    depend on which other tasks are chosen, and smaller subsets are nested in larger ones.
    """
    if n_demos < 1:
        raise DataError(f"n_demos must be at least 1, got {n_demos}")
    chosen: dict[str, list[EpisodeInfo]] = {}
    for task in tasks if tasks is not None else dataset.tasks:
        eps = dataset.episodes.get(task, [])
        if len(eps) < n_demos:
            raise DataError(
                f"{dataset.root}: task {task!r} has {len(eps)} episodes, {n_demos} demos requested"
            )
        rng = np.random.default_rng([run_seed, zlib.crc32(task.encode())])
        keep = np.sort(rng.permutation(len(eps))[:n_demos])
        chosen[task] = [eps[i] for i in keep]
    return chosen
