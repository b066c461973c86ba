"""File writing that never leaves a half-written file: the one temp-file-and-rename writer of tvf.

Every output (images, JSON, checkpoints, episodes) is written to a hidden temporary file beside its
final path and renamed into place, so a reader sees the old file or the new one, never a torn one.
Append-only logs (``episodes.jsonl``, ``metrics.jsonl``, ``failures.jsonl``) are written a whole line
at a time and read back tolerating a torn last line. Commands check their output folders and files
here before any work (:func:`check_output_dir`, :func:`check_output_file`).
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from tvf.errors import TvfError

PUBLIC_FILE_MODE = 0o644
"""Outputs are meant to be shared (a temporary file would otherwise keep a private mode)."""
TMP_SUFFIX = ".tmp"


def temp_path(path: str | Path) -> Path:
    """A unique hidden temporary name beside ``path`` (folder scans skip it; ends in ``.tmp``)."""
    path = Path(path)
    return path.with_name(f".{path.name}.{os.getpid()}{TMP_SUFFIX}")


def commit(tmp: str | Path, path: str | Path) -> None:
    """Give a finished temporary file the public mode and rename it onto ``path`` (atomic)."""
    os.chmod(tmp, PUBLIC_FILE_MODE)
    os.replace(tmp, path)


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path to write; on success it replaces ``path``, on any error it is removed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_path(path)
    try:
        yield tmp
        commit(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` through a temporary file in the same folder and a rename."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)


def atomic_write_json(path: str | Path, value: Any, indent: int = 1) -> None:
    """Write ``value`` as JSON (``default=str`` for paths), atomically."""
    atomic_write_bytes(path, json.dumps(value, indent=indent, default=str).encode())


def _file_in_the_way(path: Path) -> Path | None:
    """The first existing non-folder on the way to (or at) ``path``, or None."""
    for part in (*reversed(path.parents), path):
        if part.exists() and not part.is_dir():
            return part
    return None


def check_output_dir(path: str | Path, flag: str = "--out") -> Path:
    """Create the folder ``path`` (and a probe file in it) or fail with one line naming ``flag``."""
    path = Path(path)
    blocker = _file_in_the_way(path)
    if blocker is not None:
        raise TvfError(
            f"cannot write to output directory {path}: {blocker} is a file, not a folder; "
            f"choose another {flag}"
        )
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / ".tvf-write-test"
        probe.write_bytes(b"")
        probe.unlink()
    except OSError as exc:
        raise TvfError(
            f"cannot write to output directory {path}: {exc.strerror}; choose another {flag}"
        ) from None
    return path


def check_output_file(path: str | Path, flag: str) -> Path:
    """Check, before any work, that the file ``path`` can be written (its folder is made if missing)."""
    path = Path(path)
    if path.is_dir():
        raise TvfError(f"cannot write {path}: it is a folder; give {flag} a file name")
    check_output_dir(path.parent, flag)
    return path


_REQUIRED = object()


def read_json(path: str | Path, fix: str, default: Any = _REQUIRED) -> Any:
    """The JSON value in ``path``; ``default`` when the file is missing (if given). A missing (without a
    default) or unreadable file is a one-line :class:`TvfError` naming the file and ``fix``."""
    path = Path(path)
    if not path.exists():
        if default is not _REQUIRED:
            return default
        raise TvfError(f"{path} is missing; {fix}")
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError, UnicodeDecodeError):
        raise TvfError(f"{path} is not valid JSON; {fix}") from None


def append_jsonl(path: str | Path, record: dict) -> None:
    """Append one JSON record as a whole line (a torn line left by a crash is ended first)."""
    path = Path(path)
    line = json.dumps(record) + "\n"
    with path.open("ab") as f:
        if f.tell() > 0:
            with path.open("rb") as r:
                r.seek(-1, os.SEEK_END)
                if r.read(1) != b"\n":
                    line = "\n" + line
        f.write(line.encode())
        f.flush()


def read_jsonl(path: str | Path) -> list[dict]:
    """The records of a JSON-lines file ([] when missing); torn or invalid lines are skipped."""
    path = Path(path)
    if not path.exists():
        return []
    out = []
    for line in path.read_text(errors="replace").splitlines():
        try:
            record = json.loads(line)
        except json.JSONDecodeError:  # a line cut by an interruption
            continue
        if isinstance(record, dict):
            out.append(record)
    return out
