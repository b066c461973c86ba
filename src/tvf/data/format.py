"""The episode file: one HDF5 file per demonstration, written atomically, read with validation.

Layout (``FORMAT_VERSION`` 2; the full description is docs/data.md). ``T`` is the number of steps::

    color     uint8   [T+1, 160, 160, 3]  top-down colour; frame 0 is the initial scene, frame T the goal
    height    float32 [T+1, 160, 160]     metres above the table
    pick      float32 [T, 4]              pick pose (x, y, z, yaw) in the world frame
    place     float32 [T, 4]              place pose (x, y, z, yaw) in the world frame
    random    bool    [T]                 True for the random (exploration) actions of the train split
    progress  float32 [T+1]               fraction of targets filled in each frame
    blocks    float32 [T+1, n, 4]         every block's (x, y, z, yaw) in each frame
    targets   float32 [n, 4]              every target's (x, y, z, yaw)

Images are stored one chunk per frame (gzip, byte shuffle, Fletcher-32 checksum), so one frame can be
read without decompressing the others.

Format 2 guards an episode twice. The file's first 512 bytes (an HDF5 user block) hold the SHA-256 of
all the bytes after them, the *seal*, checked before HDF5 parses anything: a damaged file can crash the
HDF5 library (a flipped byte did, with a segfault in its attribute reader), so it never sees one. And
the attribute ``sha256`` holds the SHA-256 of every dataset (of every frame for the images) and of all
other attributes, as the reader decodes them: the episode's content, whatever HDF5's byte layout,
checked by every read (a lazy frame read included) and recorded in the manifest. A damaged file is a
DataError naming it, never other data. Files of format 1 (neither) are read unverified, with one warning
per folder.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import sys
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from functools import cache
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from tvf import __version__
from tvf.errors import TvfError
from tvf.geometry import WORKSPACE, world_to_pixel, wrap_angle, yaw_to_bin
from tvf.io import atomic_path

FORMAT_VERSION = 2
"""Bumped whenever a field changes meaning or shape; readers refuse other versions but UNVERIFIED_VERSIONS."""
UNVERIFIED_VERSIONS = (1,)
"""Older versions of the same layout without checksums: read unverified, with a warning per folder."""
SEAL_SIZE = 512
"""Bytes of the HDF5 user block that holds the seal (HDF5's superblock follows it)."""
SEAL_MAGIC = b"tvf-episode sha256 "
_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
CHECKSUMS = "sha256"
"""The attribute holding the SHA-256 of every dataset (per frame for the images) and of the other
attributes, as JSON (format version 2)."""
SPLITS = ("train", "test")
EPISODE_SUFFIX = ".h5"
COMPRESSION = {"compression": "gzip", "compression_opts": 4, "shuffle": True, "fletcher32": True}

_REQUIRED_ATTRS = ("format_version", "task", "seed", "split", "success")
IMAGE_FIELDS = ("color", "height")
"""Checked one frame at a time (a list of SHA-256s each), so a lazy read of one frame is checked too."""
SMALL_FIELDS = ("pick", "place", "random", "progress", "blocks", "targets")
REGENERATE = "delete it and re-run `tvf demos` with the same flags to regenerate it"
_LOW_LEVEL = (OSError, ValueError, KeyError, RuntimeError, TypeError, IndexError, OverflowError)
"""What h5py and the decoders raise on a damaged file; turned into a DataError naming it."""


class DataError(TvfError):
    """A missing, truncated or corrupt data file, or one of another format version."""


def episode_name(seed: int) -> str:
    """File name of the episode with ``seed`` (inside its task folder)."""
    return f"{seed:06d}{EPISODE_SUFFIX}"


def world_to_subpixel(xy: np.ndarray) -> np.ndarray:
    """World ``(..., 2)`` x, y -> sub-pixel (row, col) where integer values are pixel centres.

    The inverse of :func:`tvf.geometry.pixel_to_world`; ``floor(world_to_subpixel(xy) + 0.5)`` equals
    :func:`tvf.geometry.world_to_pixel` (the floor rule). Image warps use the same frame.
    """
    xy = np.asarray(xy, dtype=np.float64)
    ws = WORKSPACE
    col = (xy[..., 0] - ws.x_min) / ws.pixel_size - 0.5
    row = (xy[..., 1] - ws.y_min) / ws.pixel_size - 0.5
    return np.stack([row, col], axis=-1)


def subpixel_to_pixel(rowcol: np.ndarray) -> np.ndarray:
    """Sub-pixel (row, col) -> the integer pixel that contains it (the pixel whose centre is nearest)."""
    return np.floor(np.asarray(rowcol, dtype=np.float64) + 0.5).astype(np.int64)


def expected_layout(steps: int, blocks: int) -> dict[str, tuple[tuple[int, ...], type]]:
    """The shape and type of every array of an episode of ``steps`` steps and ``blocks`` blocks."""
    t, n = steps, blocks
    h, w = WORKSPACE.shape
    return {
        "color": ((t + 1, h, w, 3), np.uint8),
        "height": ((t + 1, h, w), np.float32),
        "pick": ((t, 4), np.float32),
        "place": ((t, 4), np.float32),
        "random": ((t,), np.bool_),
        "progress": ((t + 1,), np.float32),
        "blocks": ((t + 1, n, 4), np.float32),
        "targets": ((n, 4), np.float32),
    }


@dataclass
class Episode:
    """One demonstration in memory. Frame ``t`` is the state before step ``t``; the last frame is the goal."""

    task: str
    seed: int
    split: str
    color: np.ndarray
    height: np.ndarray
    pick: np.ndarray
    place: np.ndarray
    random: np.ndarray
    progress: np.ndarray
    blocks: np.ndarray
    targets: np.ndarray
    success: bool = True
    attrs: dict[str, Any] = field(default_factory=dict)
    """Other attributes (versions, configuration, per-step primitive results)."""
    path: Path | None = None
    checksum: str | None = field(default=None, compare=False)
    """Read from a file: its content digest (as :attr:`EpisodeInfo.checksum`; None for format 1 files)."""

    @property
    def n_steps(self) -> int:
        return len(self.pick)

    @property
    def n_random(self) -> int:
        return int(np.count_nonzero(self.random))

    @property
    def goal_color(self) -> np.ndarray:
        return self.color[-1]

    @property
    def goal_height(self) -> np.ndarray:
        return self.height[-1]

    def pick_pixels(self) -> np.ndarray:
        """(T, 2) int64 (row, col) of the pick positions."""
        return world_to_pixel(self.pick[:, :2])

    def place_pixels(self) -> np.ndarray:
        """(T, 2) int64 (row, col) of the place positions."""
        return world_to_pixel(self.place[:, :2])

    def relative_yaws(self) -> np.ndarray:
        """(T,) turn of the picked block, ``place_yaw - pick_yaw`` wrapped to [-pi, pi)."""
        return np.asarray(wrap_angle(self.place[:, 3].astype(np.float64) - self.pick[:, 3]))

    def rotation_bins(self, n_rotations: int = 36) -> np.ndarray:
        """(T,) nearest rotation bin of the block's turn."""
        return yaw_to_bin(self.relative_yaws(), n_rotations)

    def validate(self) -> None:
        """Raise DataError if the arrays do not have the documented shapes and types."""
        where = str(self.path) if self.path else f"{self.task} seed {self.seed}"
        expect = expected_layout(self.n_steps, len(self.targets))
        for name, (shape, dtype) in expect.items():
            a = getattr(self, name)
            if a.shape != shape or a.dtype != dtype:
                raise DataError(
                    f"{where}: field {name!r} has shape {a.shape} {a.dtype}, "
                    f"expected {shape} {np.dtype(dtype)}"
                )
        if self.split not in SPLITS:
            raise DataError(f"{where}: split {self.split!r} is not one of {SPLITS}")


@dataclass(frozen=True)
class EpisodeInfo:
    """What a file's header says about its episode (no image data read)."""

    path: Path
    task: str
    seed: int
    split: str
    steps: int
    random_steps: int
    bytes: int
    checksum: str | None = None
    """SHA-256 of the file's checksums (one digest of its whole content); None for format 1 files."""

    def to_dict(self, root: Path | None = None) -> dict[str, Any]:
        d = asdict(self)
        d["path"] = str(self.path.relative_to(root) if root else self.path)
        return d


# ---- checksums: the SHA-256 of every array (per frame for the images) and of the attributes


def array_sha256(a: np.ndarray) -> str:
    """SHA-256 of an array's dtype, shape and bytes (C order)."""
    a = np.ascontiguousarray(a)
    digest = hashlib.sha256(f"{a.dtype.str} {a.shape} ".encode())
    digest.update(a)  # the buffer itself, no copy
    return digest.hexdigest()


def _canonical(value: Any) -> list:
    """An attribute value as the reader decodes it, as JSON data with its type (for the attributes' hash)."""
    if isinstance(value, np.ndarray):
        return ["ndarray", value.dtype.str, list(value.shape), repr(value.tolist())]
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, bytes):
        return ["bytes", value.hex()]
    if isinstance(value, str | bool | int | float):
        return [type(value).__name__, value]
    return [type(value).__name__, repr(value)]


def attrs_sha256(attrs: Mapping[str, Any]) -> str:
    """SHA-256 of every attribute but the checksums themselves: names, types and values, sorted by name."""
    items = [[key, *_canonical(attrs[key])] for key in sorted(attrs) if key != CHECKSUMS]
    return hashlib.sha256(json.dumps(items, separators=(",", ":")).encode()).hexdigest()


def episode_checksums(episode: Episode) -> dict[str, Any]:
    """The SHA-256 of every dataset of ``episode``: a list per frame for the images, one for the others."""
    sums: dict[str, Any] = {name: [array_sha256(a) for a in getattr(episode, name)] for name in IMAGE_FIELDS}
    sums.update({name: array_sha256(getattr(episode, name)) for name in SMALL_FIELDS})
    return sums


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split()) or type(exc).__name__


def _damaged(path: Path, what: str) -> DataError:
    return DataError(f"{path}: {what} (the file is damaged); {REGENERATE}")


# ---- the seal: the SHA-256 of a file's HDF5 bytes, in its user block


def _tail_sha256(f) -> str:
    """SHA-256 of the rest of an open binary file, read in blocks."""
    digest = hashlib.sha256()
    for block in iter(lambda: f.read(1 << 20), b""):
        digest.update(block)
    return digest.hexdigest()


def sealed(data: bytes) -> bytes:
    """An HDF5 image with a 512-byte user block, that block holding the SHA-256 of the bytes after it."""
    digest = hashlib.sha256(data[SEAL_SIZE:]).hexdigest()
    return (SEAL_MAGIC + digest.encode() + b"\n").ljust(SEAL_SIZE, b"\0") + data[SEAL_SIZE:]


def seal(path: str | Path) -> None:
    """Seal a file in place (:func:`sealed`; a test re-seals a file it changed through HDF5 to simulate
    another writer)."""
    path = Path(path)
    path.write_bytes(sealed(path.read_bytes()))


def check_seal(path: Path) -> bool:
    """Whether ``path`` is sealed (False: an HDF5 file without a user block, format 1); DataError if
    its bytes do not match the seal or it is neither. Reads the whole file, before HDF5 parses it."""
    with path.open("rb") as f:
        head = f.read(SEAL_SIZE)
        if head.startswith(_HDF5_SIGNATURE):
            return False
        if len(head) < SEAL_SIZE or not head.startswith(SEAL_MAGIC):
            raise DataError(
                f"{path}: not a readable HDF5 episode (neither a tvf seal nor an HDF5 signature at its "
                f"start: truncated, corrupt or another kind of file); {REGENERATE}"
            )
        expected = head[len(SEAL_MAGIC) : len(SEAL_MAGIC) + 64]
        if _tail_sha256(f).encode() != expected:
            raise _damaged(
                path, "its bytes do not match the SHA-256 in its first 512 bytes: truncated, corrupt or "
                "changed since tvf wrote it"
            )  # fmt: skip
    return True


# ---- writing


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, Path):
        return str(value)
    raise TypeError(f"cannot store {type(value).__name__} in an episode attribute")


def write_h5(path: Path, episode: Episode) -> int:
    """Write ``episode`` to ``path`` (not atomic; see :func:`write_episode`); returns the file size.

    HDF5 builds the file in memory (:func:`h5_bytes`) and one plain write puts it on disk: a full disk is
    then an ordinary ``OSError`` (HDF5 writing to a full disk itself leaves its library broken and the
    process segfaults).
    """
    data = h5_bytes(episode)
    Path(path).write_bytes(data)
    return len(data)


def h5_bytes(episode: Episode) -> bytes:
    """The bytes of ``episode``'s file; the same episode gives the same bytes (the checksums depend on the
    content only), so a file may be built in one process and written by another."""
    episode.validate()
    image = io.BytesIO()
    with h5py.File(image, "w", userblock_size=SEAL_SIZE) as f:
        for name in ("color", "height"):
            a = getattr(episode, name)
            f.create_dataset(name, data=a, chunks=(1, *a.shape[1:]), **COMPRESSION)
        for name in ("pick", "place", "random", "progress", "blocks", "targets"):
            a = getattr(episode, name)
            f.create_dataset(
                name, data=a, chunks=a.shape if a.size else None, **(COMPRESSION if a.size else {})
            )
        extra = {k: v for k, v in episode.attrs.items() if k not in (*_REQUIRED_ATTRS, CHECKSUMS)}
        f.attrs.update(
            {
                "format_version": FORMAT_VERSION,
                "tvf_version": __version__,
                "task": episode.task,
                "seed": int(episode.seed),
                "split": episode.split,
                "success": bool(episode.success),
                "workspace": json.dumps(WORKSPACE.as_dict()),
            }
        )
        for key, value in extra.items():
            f.attrs[key] = (
                value
                if isinstance(value, str | int | float | bool)
                else json.dumps(value, default=_json_default)
            )
        sums = {**episode_checksums(episode), "attrs": attrs_sha256(f.attrs)}  # the attributes as read back
        f.attrs[CHECKSUMS] = json.dumps(sums, sort_keys=True, separators=(",", ":"))
    return sealed(image.getvalue())


def write_episode(path: str | Path, episode: Episode) -> int:
    """Write ``episode`` to ``path`` through a temporary file and a rename; returns the file size."""
    with atomic_path(path) as tmp:
        write_h5(tmp, episode)
    return Path(path).stat().st_size


# ---- reading: every defect is a DataError naming the file


@cache
def _warn_unverified(folder: Path) -> None:
    """One warning per folder of format 1 files (printed, as the CLI's warnings are)."""
    print(
        f"tvf: warning: {folder}: episode files of format version 1 carry no checksums and are read "
        "unverified; delete them and re-run `tvf demos` to regenerate them with checksums",
        file=sys.stderr,
    )


@dataclass
class _Opened:
    """An open episode file whose header (and attributes' checksum) passed: its checksums (None: format 1)."""

    path: Path
    file: Any
    sums: dict[str, Any] | None
    raw_sums: str | None

    def array(self, name: str) -> np.ndarray:
        """A small dataset, read in full and checked."""
        a = self.file[name][()]
        if self.sums is not None and array_sha256(a) != self.sums[name]:
            raise _damaged(self.path, f"dataset {name!r} does not match its SHA-256")
        return a

    def frames(self, name: str, order: np.ndarray) -> np.ndarray:
        """Frames ``order`` (sorted, unique) of an image dataset, read and checked one by one."""
        a = self.file[name][order]
        check_frames(self.path, name, self.sums[name] if self.sums else None, order, a)
        return a


def check_frames(
    path: Path, name: str, sums: list[str] | None, order: np.ndarray, frames: np.ndarray
) -> None:  # fmt: skip
    """Raise DataError unless each ``frames[i]`` (frame ``order[i]`` of ``name``) matches its SHA-256."""
    if sums is None:
        return
    for index, frame in zip(order, frames, strict=True):
        if array_sha256(frame) != sums[index]:
            raise _damaged(path, f"frame {index} of {name!r} does not match its SHA-256")


class _Reader:
    """Opens an episode file and turns every low-level failure into a DataError naming the file."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.file = None

    def __enter__(self) -> _Opened:
        if not self.path.is_file():
            raise DataError(f"{self.path}: no such episode file")
        try:
            sealed = check_seal(self.path)  # before HDF5 sees a byte
            self.file = h5py.File(self.path, "r")
        except (OSError, ValueError) as exc:
            raise DataError(
                f"{self.path}: not a readable HDF5 episode (truncated or corrupt: {_one_line(exc)}); "
                f"{REGENERATE}"
            ) from None
        try:
            raw = check_header(self.path, self.file, sealed)
            sums = json.loads(raw) if raw is not None else None
            check_layout(self.path, self.file, sums)
        except BaseException as exc:
            self.file.close()
            if isinstance(exc, _LOW_LEVEL) and not isinstance(exc, DataError):
                raise _damaged(self.path, f"corrupt episode header: {_one_line(exc)}") from None
            raise
        return _Opened(self.path, self.file, sums, raw)

    def __exit__(self, exc_type, exc, tb) -> None:
        if self.file is not None:
            self.file.close()
        if exc_type is not None and not issubclass(exc_type, DataError) and issubclass(exc_type, _LOW_LEVEL):
            raise _damaged(self.path, f"corrupt episode data: {_one_line(exc)}") from None


def check_header(path: Path, f, sealed: bool = True) -> str | None:
    """Check that ``f`` is an episode file of a version this tvf reads (format 2: ``sealed``), with every
    attribute and field, and that its attributes match their SHA-256. Returns the checksums' JSON (None
    for a format 1 file)."""
    attrs = {key: f.attrs[key] for key in f.attrs}
    if "format_version" not in attrs:
        raise DataError(f"{path}: not a tvf episode file (no format_version attribute)")
    version = int(attrs["format_version"])
    if version != FORMAT_VERSION and version not in UNVERIFIED_VERSIONS:
        raise DataError(
            f"{path}: episode format version {version}, this tvf reads version {FORMAT_VERSION}; "
            "regenerate the dataset with `tvf demos`"
        )
    missing = [k for k in _REQUIRED_ATTRS if k not in attrs]
    missing += [k for k in (*IMAGE_FIELDS, *SMALL_FIELDS) if not isinstance(f.get(k), h5py.Dataset)]
    if missing:
        raise DataError(f"{path}: episode file lacks {', '.join(missing)}; {REGENERATE}")
    raw = attrs.get(CHECKSUMS)
    if version == FORMAT_VERSION and not sealed:
        raise _damaged(path, f"a format {FORMAT_VERSION} episode without its seal (a 512-byte user block)")
    if raw is None and version == FORMAT_VERSION:
        raise _damaged(path, f"no {CHECKSUMS!r} attribute in a format {FORMAT_VERSION} episode")
    if raw is not None:
        if not isinstance(raw, str):
            raise _damaged(path, f"the {CHECKSUMS!r} attribute is not text")
        _check_sums_shape(path, json.loads(raw))
        if attrs_sha256(attrs) != json.loads(raw)["attrs"]:
            raise _damaged(path, "the attributes do not match their SHA-256")
    else:
        _warn_unverified(path.parent)
    return raw


def _check_sums_shape(path: Path, sums: Any) -> None:
    """The checksums attribute holds a digest per small field and the attributes, a list per image field."""
    names = {*IMAGE_FIELDS, *SMALL_FIELDS, "attrs"}
    ok = isinstance(sums, dict) and set(sums) == names
    ok = ok and all(isinstance(sums[k], str) for k in names - set(IMAGE_FIELDS))
    ok = ok and all(isinstance(sums[k], list) for k in IMAGE_FIELDS)
    ok = ok and all(isinstance(d, str) for k in IMAGE_FIELDS for d in sums[k])
    if not ok:
        raise _damaged(path, f"the {CHECKSUMS!r} attribute is malformed")


def check_layout(path: Path, f, sums: dict[str, Any] | None) -> None:
    """Every dataset has the shape and type its step count (from the checksums, else ``pick``) implies,
    checked before anything is read (a damaged shape must not read zeros or allocate a huge array)."""
    t = len(sums["color"]) - 1 if sums is not None else f["pick"].shape[0]
    n = f["targets"].shape[0] if f["targets"].ndim == 2 else -1
    expect = expected_layout(t, n)
    if sums is not None and len(sums["height"]) != t + 1:
        raise _damaged(path, f"{len(sums['height'])} height checksums for {t + 1} colour frames")
    for name, (shape, dtype) in expect.items():
        d = f[name]
        if d.shape != shape or d.dtype != dtype:
            if sums is None and name in ("color", "height") and d.shape[:1] != (t + 1,):
                raise DataError(f"{path}: {t} steps but {d.shape[0]} frames (expected {t + 1}); {REGENERATE}")
            raise _damaged(path, f"dataset {name!r} has shape {d.shape} {d.dtype}, expected {shape} "
                                 f"{np.dtype(dtype)}")  # fmt: skip


def read_info(path: str | Path) -> EpisodeInfo:
    """Read the header and the small fields of an episode file (checked), not its images."""
    path = Path(path)
    with _Reader(path) as r:
        small = {name: r.array(name) for name in SMALL_FIELDS}  # all checked: they are tiny
        return EpisodeInfo(
            path=path,
            task=str(r.file.attrs["task"]),
            seed=int(r.file.attrs["seed"]),
            split=str(r.file.attrs["split"]),
            steps=int(r.file["pick"].shape[0]),
            random_steps=int(np.count_nonzero(small["random"])),
            bytes=path.stat().st_size,
            checksum=_content_sha256(r.raw_sums),
        )


def _content_sha256(raw_sums: str | None) -> str | None:
    return hashlib.sha256(raw_sums.encode()).hexdigest() if raw_sums is not None else None


def _decode_attr(value: Any) -> Any:
    if isinstance(value, bytes):
        value = value.decode()
    if isinstance(value, str) and value[:1] in "[{":
        try:
            return json.loads(value)
        except json.JSONDecodeError:
            return value
    if isinstance(value, np.generic):
        return value.item()
    return value


class LazyFrames:
    """An image field (``color`` or ``height``) of an episode file, read one frame chunk at a time.

    Indexing reads from the file (a few open files are kept per process) and checks every frame it
    reads against its SHA-256; it is never pickled open.
    """

    _open: dict[tuple, Any] = {}
    MAX_OPEN = 32

    def __init__(
        self, path: Path, name: str, shape: tuple[int, ...], dtype: np.dtype, sums: list[str] | None = None
    ) -> None:
        self.path, self.name, self.shape, self.dtype = path, name, tuple(shape), np.dtype(dtype)
        self.sums = sums

    @property
    def ndim(self) -> int:
        return len(self.shape)

    def __len__(self) -> int:
        return self.shape[0]

    def _file(self):
        try:
            stat = self.path.stat()  # a rewritten file is opened anew (and checked against these sums)
        except OSError as exc:
            raise DataError(f"{self.path}: cannot reopen episode file: {_one_line(exc)}") from None
        key = (os.getpid(), self.path, stat.st_ino, stat.st_mtime_ns, stat.st_size)
        f = LazyFrames._open.get(key)
        if f is None:
            if len(LazyFrames._open) >= LazyFrames.MAX_OPEN:
                LazyFrames._open.pop(next(iter(LazyFrames._open))).close()
            try:
                check_seal(self.path)
                f = LazyFrames._open[key] = h5py.File(self.path, "r")
            except OSError as exc:
                raise DataError(f"{self.path}: cannot reopen episode file: {_one_line(exc)}") from None
        return f

    def __getitem__(self, index) -> np.ndarray:
        if isinstance(index, tuple):
            first, rest = (index[0] if index else slice(None)), index[1:]
        else:
            first, rest = index, ()
        frames = np.arange(len(self))[first]
        order = np.unique(frames)
        try:
            data = self._file()[self.name][order]
        except _LOW_LEVEL as exc:
            raise _damaged(self.path, f"corrupt episode data in {self.name!r}: {_one_line(exc)}") from None
        check_frames(self.path, self.name, self.sums, order, data)
        out = data[np.searchsorted(order, frames)]
        return out[rest] if rest else out

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        a = self[()]
        return a if dtype is None else a.astype(dtype)


def read_episode(path: str | Path, lazy: bool = False) -> Episode:
    """Read an episode file, checking every array and attribute against its SHA-256; any defect raises a
    DataError that names the file.

    With ``lazy`` the images stay on disk (:class:`LazyFrames`, one frame read and checked per index)
    and only the small fields are loaded: for datasets larger than memory.
    """
    path = Path(path)
    with _Reader(path) as r:
        arrays: dict[str, Any] = {name: r.array(name) for name in SMALL_FIELDS}
        for name in IMAGE_FIELDS:
            shape, dtype = r.file[name].shape, r.file[name].dtype
            sums = r.sums[name] if r.sums else None
            arrays[name] = (
                LazyFrames(path, name, shape, dtype, sums) if lazy else r.frames(name, np.arange(shape[0]))
            )
        attrs = {k: _decode_attr(v) for k, v in r.file.attrs.items() if k != CHECKSUMS}
        checksum = _content_sha256(r.raw_sums)
    episode = Episode(
        task=str(attrs.pop("task")),
        seed=int(attrs.pop("seed")),
        split=str(attrs.pop("split")),
        success=bool(attrs.pop("success")),
        attrs=attrs,
        path=path,
        checksum=checksum,
        **arrays,
    )
    episode.validate()
    return episode


def read_frames(path: str | Path, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Read the colour and height of the given frame indices only (one chunk each, each checked)."""
    frames = np.asarray(frames, dtype=np.int64)
    with _Reader(path) as r:
        order = np.unique(frames)
        color = r.frames("color", order)
        height = r.frames("height", order)
    where = np.searchsorted(order, frames)
    return color[where], height[where]
