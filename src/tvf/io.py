"""File writing that never leaves a half-written file: the one temp-file-and-rename writer of tvf.

Every output (images, JSON, checkpoints, episodes) is written to a hidden temporary file beside its
final path and renamed into place, so a reader sees the old file or the new one, never a torn one.
Append-only logs (``episodes.jsonl``, ``metrics.jsonl``, ``failures.jsonl``) go through the one pair
:func:`append_jsonl` / :func:`read_jsonl`: a whole line per write, read back tolerating a torn last line.
A full disk (``ENOSPC``, also wrapped by libraries) becomes a one-line :class:`~tvf.errors.DiskFullError`
naming the file, with no partial file or line left behind. Commands check their output folders and files
here before any work (:func:`check_output_dir`, :func:`output_dir`, :func:`check_output_file`).
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from tvf.errors import DiskFullError, TvfError

PUBLIC_FILE_MODE = 0o644
"""Outputs are meant to be shared (a temporary file would otherwise keep a private mode)."""
TMP_SUFFIX = ".tmp"
DISK_FULL_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT})
_DISK_FULL_TEXT = ("no space left on device", "disk quota exceeded", "errno = 28")  # HDF5 names errno 28


def is_disk_full(exc: BaseException | None) -> bool:
    """Whether ``exc``, or an error it was raised from or while handling, is a full disk (ENOSPC, EDQUOT).

    Libraries wrap it: torch's checkpoint writer raises a ``RuntimeError`` while handling the ``OSError``,
    HDF5 a ``RuntimeError`` whose message names errno 28.
    """
    seen: set[int] = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, DiskFullError):
            return True
        if isinstance(exc, OSError) and exc.errno in DISK_FULL_ERRNOS:
            return True
        if isinstance(exc, OSError | RuntimeError) and any(t in str(exc).lower() for t in _DISK_FULL_TEXT):
            return True
        exc = exc.__cause__ or exc.__context__
    return False


def as_disk_full(exc: BaseException, path: str | Path = "") -> DiskFullError | None:
    """``exc`` as a :class:`DiskFullError` naming ``path`` (its own path when it is one), or None."""
    if isinstance(exc, DiskFullError):
        return exc
    if isinstance(exc, Exception) and is_disk_full(exc):
        return DiskFullError(path or getattr(exc, "filename", None) or "")
    return None


def raise_if_disk_full(exc: BaseException, path: str | Path) -> None:
    """Re-raise ``exc`` as a :class:`DiskFullError` naming ``path`` when it is a full disk in another form
    (call it in an ``except`` block, then ``raise`` for every other error)."""
    full = as_disk_full(exc, path)
    if full is not None and full is not exc:
        raise full from exc


def note(message: str) -> None:
    """A one-line note on stderr about something tvf repaired or ignored (the work goes on)."""
    print(f"tvf: note: {message}", file=sys.stderr)


def temp_path(path: str | Path) -> Path:
    """A unique hidden temporary name beside ``path`` (folder scans skip it; ends in ``.tmp``)."""
    path = Path(path)
    return path.with_name(f".{path.name}.{os.getpid()}{TMP_SUFFIX}")


def commit(tmp: str | Path, path: str | Path) -> None:
    """Give a finished temporary file the public mode, flush it to the disk and rename it onto ``path``
    (atomic: after a power cut the name holds the old file or the whole new one)."""
    os.chmod(tmp, PUBLIC_FILE_MODE)
    fd = os.open(tmp, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)
    os.replace(tmp, path)


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path to write; on success it replaces ``path``, on any error it is removed
    (a full disk is then a :class:`DiskFullError` naming ``path``)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_path(path)
    try:
        yield tmp
        commit(tmp, path)
    except BaseException as exc:
        tmp.unlink(missing_ok=True)
        raise_if_disk_full(exc, path)
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


@contextmanager
def output_dir(path: str | Path, flag: str = "--out") -> Iterator[Path]:
    """:func:`check_output_dir`, for setup that may still fail: on an error inside the block, the folders
    this call created are removed again while they are empty (a refused command leaves nothing behind)."""
    path = Path(path)
    created = [p for p in (path, *path.parents) if not p.exists()]
    check_output_dir(path, flag)
    try:
        yield path
    except BaseException:
        for folder in created:  # deepest first
            with contextlib.suppress(OSError):
                folder.rmdir()  # only empty folders go
        raise


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
    """Append ``record`` as one whole line: one write of the complete line, flushed to the disk.

    A torn last line (a kill or a power cut mid-write) is cut away first, with a note, so the record
    starts on a fresh line; a write that fails (a full disk) is cut back off, so the file holds whole
    lines only and the error is a :class:`DiskFullError` naming the file.
    """
    path = Path(path)
    line = (json.dumps(record) + "\n").encode()
    fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_APPEND, PUBLIC_FILE_MODE)
    try:
        end, prefix = _end_of_whole_lines(fd, path)
        try:
            _write_all(fd, prefix + line)
            os.fsync(fd)
        except BaseException as exc:
            with contextlib.suppress(OSError):
                os.ftruncate(fd, end)
            raise_if_disk_full(exc, path)
            raise
    finally:
        os.close(fd)


def _write_all(fd: int, data: bytes) -> None:
    """Write every byte of ``data`` to ``fd`` (``os.write`` may write less than asked)."""
    view = memoryview(data)
    while view:
        view = view[os.write(fd, view) :]


def _end_of_whole_lines(fd: int, path: Path) -> tuple[int, bytes]:
    """(where the file's whole lines end, what the next line needs before it): a torn last line is cut
    off (with a note); a whole record that only lacks its newline keeps it, and gets one."""
    size = os.fstat(fd).st_size
    if size == 0 or os.pread(fd, 1, size - 1) == b"\n":
        return size, b""
    start = _last_line_start(fd, size)
    if _record(os.pread(fd, size - start, start)) is not None:
        return size, b"\n"
    os.ftruncate(fd, start)
    note(f"{path}: dropped a torn last line ({size - start} bytes, an interrupted write) before appending")
    return start, b""


def _last_line_start(fd: int, size: int, chunk: int = 1 << 16) -> int:
    """The offset just after the last newline before ``size`` (0 when there is none)."""
    end = size
    while end > 0:
        begin = max(0, end - chunk)
        found = os.pread(fd, end - begin, begin).rfind(b"\n")
        if found >= 0:
            return begin + found + 1
        end = begin
    return 0


def _record(line: bytes) -> dict | None:
    """The JSON object on ``line``, or None when it is not one."""
    try:
        value = json.loads(line)
    except (json.JSONDecodeError, UnicodeDecodeError):
        return None
    return value if isinstance(value, dict) else None


_NOTED: set[tuple[str, int]] = set()
"""(file, size) already noted by :func:`read_jsonl`, so a log read twice is noted once."""


def read_jsonl(path: str | Path) -> list[dict]:
    """The records of a JSON-lines file ([] when missing). A torn last line (no newline, not a whole
    record: an interrupted write) is ignored with a note, and so is any other line that is not a JSON
    object; the next :func:`append_jsonl` starts on a fresh line."""
    path = Path(path)
    if not path.is_file():
        return []
    data = path.read_bytes()
    *lines, last = data.split(b"\n")
    records, bad = [], 0
    for line in lines:
        record = _record(line)
        if record is not None:
            records.append(record)
        elif line.strip():
            bad += 1
    tail = _record(last) if last.strip() else None
    if tail is not None:  # a whole record that only lacks its newline
        records.append(tail)
    torn = bool(last.strip()) and tail is None
    key = (str(path.resolve()), len(data))
    if (bad or torn) and key not in _NOTED:
        _NOTED.add(key)
        parts = [f"a torn last line ({len(last)} bytes, an interrupted write)"] if torn else []
        parts += [f"{bad} line(s) that are not JSON records"] if bad else []
        note(f"{path}: ignored {' and '.join(parts)}")
    return records
