"""The episode file: one HDF5 file per demonstration, written atomically, read with validation.

Layout (``FORMAT_VERSION`` 1; the full description is docs/data.md). ``T`` is the number of steps::

    color     uint8   [T+1, 160, 160, 3]  top-down colour; frame 0 is the initial scene, frame T the goal
    height    float32 [T+1, 160, 160]     metres above the table
    pick      float32 [T, 4]              pick pose (x, y, z, yaw) in the world frame
    place     float32 [T, 4]              place pose (x, y, z, yaw) in the world frame
    random    bool    [T]                 True for the random (exploration) actions of the train split
    progress  float32 [T+1]               fraction of targets filled in each frame
    blocks    float32 [T+1, n, 4]         every block's (x, y, z, yaw) in each frame
    targets   float32 [n, 4]              every target's (x, y, z, yaw)

Images are stored one chunk per frame (gzip, byte shuffle, Fletcher-32 checksum), so one frame can be
read without decompressing the others, and a flipped byte is caught on read.
"""

from __future__ import annotations

import io
import json
import os
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from tvf import __version__
from tvf.errors import TvfError
from tvf.geometry import WORKSPACE, world_to_pixel, wrap_angle, yaw_to_bin
from tvf.io import atomic_path

FORMAT_VERSION = 1
"""Bumped whenever a field changes meaning or shape; readers refuse other versions."""
SPLITS = ("train", "test")
EPISODE_SUFFIX = ".h5"
COMPRESSION = {"compression": "gzip", "compression_opts": 4, "shuffle": True, "fletcher32": True}

_STEP_FIELDS = ("pick", "place", "random")
_FRAME_FIELDS = ("color", "height", "progress", "blocks")
_REQUIRED_ATTRS = ("format_version", "task", "seed", "split", "success")


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
        t = self.n_steps
        n = len(self.targets)
        h, w = WORKSPACE.shape
        expect = {
            "color": ((t + 1, h, w, 3), np.uint8),
            "height": ((t + 1, h, w), np.float32),
            "pick": ((t, 4), np.float32),
            "place": ((t, 4), np.float32),
            "random": ((t,), np.bool_),
            "progress": ((t + 1,), np.float32),
            "blocks": ((t + 1, n, 4), np.float32),
            "targets": ((n, 4), np.float32),
        }
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

    def to_dict(self, root: Path | None = None) -> dict[str, Any]:
        d = asdict(self)
        d["path"] = str(self.path.relative_to(root) if root else self.path)
        return d


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

    HDF5 builds the file in memory and one plain write puts it on disk: a full disk is then an ordinary
    ``OSError`` (HDF5 writing to a full disk itself leaves its library broken and the process segfaults).
    """
    episode.validate()
    image = io.BytesIO()
    with h5py.File(image, "w") as f:
        for name in ("color", "height"):
            a = getattr(episode, name)
            f.create_dataset(name, data=a, chunks=(1, *a.shape[1:]), **COMPRESSION)
        for name in ("pick", "place", "random", "progress", "blocks", "targets"):
            a = getattr(episode, name)
            f.create_dataset(
                name, data=a, chunks=a.shape if a.size else None, **(COMPRESSION if a.size else {})
            )
        extra = {k: v for k, v in episode.attrs.items() if k not in _REQUIRED_ATTRS}
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
    Path(path).write_bytes(image.getbuffer())
    return image.getbuffer().nbytes


def write_episode(path: str | Path, episode: Episode) -> int:
    """Write ``episode`` to ``path`` through a temporary file and a rename; returns the file size."""
    with atomic_path(path) as tmp:
        write_h5(tmp, episode)
    return Path(path).stat().st_size


class _Reader:
    """Opens an episode file and turns every low-level failure into a DataError naming the file."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.file = None

    def __enter__(self):
        if not self.path.is_file():
            raise DataError(f"{self.path}: no such episode file")
        try:
            self.file = h5py.File(self.path, "r")
        except (OSError, ValueError) as exc:
            raise DataError(
                f"{self.path}: not a readable HDF5 episode (truncated or corrupt): {exc}"
            ) from None
        try:
            check_header(self.path, self.file)
        except BaseException:
            self.file.close()
            raise
        return self.file

    def __exit__(self, exc_type, exc, tb) -> None:
        if self.file is not None:
            self.file.close()
        low_level = OSError | ValueError | KeyError | RuntimeError | TypeError
        if exc_type is not None and not issubclass(exc_type, DataError) and issubclass(exc_type, low_level):
            raise DataError(f"{self.path}: corrupt episode data: {exc}") from None


def check_header(path: Path, f) -> None:
    """Raise DataError unless ``f`` is an episode file of this format version with every field."""
    try:
        attrs = {k: f.attrs[k] for k in _REQUIRED_ATTRS if k in f.attrs}
    except (OSError, KeyError, ValueError, RuntimeError) as exc:
        raise DataError(f"{path}: corrupt episode header: {exc}") from None
    missing = [k for k in _REQUIRED_ATTRS if k not in attrs]
    if "format_version" in missing:
        raise DataError(f"{path}: not a tvf episode file (no format_version attribute)")
    version = int(attrs["format_version"])
    if version != FORMAT_VERSION:
        raise DataError(
            f"{path}: episode format version {version}, this tvf reads version {FORMAT_VERSION}; "
            "regenerate the dataset with `tvf demos`"
        )
    fields = [*_STEP_FIELDS, *_FRAME_FIELDS, "targets"]
    missing += [k for k in fields if k not in f]
    if missing:
        raise DataError(f"{path}: episode file lacks {', '.join(missing)}")


def read_info(path: str | Path) -> EpisodeInfo:
    """Read only the header of an episode file (validated), not its images."""
    path = Path(path)
    with _Reader(path) as f:
        steps = int(f["pick"].shape[0])
        if f["color"].shape[0] != steps + 1 or f["height"].shape[0] != steps + 1:
            raise DataError(f"{path}: {steps} steps but {f['color'].shape[0]} frames (expected {steps + 1})")
        return EpisodeInfo(
            path=path,
            task=str(f.attrs["task"]),
            seed=int(f.attrs["seed"]),
            split=str(f.attrs["split"]),
            steps=steps,
            random_steps=int(np.count_nonzero(f["random"][:])),
            bytes=path.stat().st_size,
        )


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

    Indexing reads from the file (a few open files are kept per process); it is never pickled open.
    """

    _open: dict[tuple[int, Path], Any] = {}
    MAX_OPEN = 32

    def __init__(self, path: Path, name: str, shape: tuple[int, ...], dtype: np.dtype) -> None:
        self.path, self.name, self.shape, self.dtype = path, name, tuple(shape), np.dtype(dtype)

    @property
    def ndim(self) -> int:
        return len(self.shape)

    def __len__(self) -> int:
        return self.shape[0]

    def _file(self):
        key = (os.getpid(), self.path)
        f = LazyFrames._open.get(key)
        if f is None:
            if len(LazyFrames._open) >= LazyFrames.MAX_OPEN:
                LazyFrames._open.pop(next(iter(LazyFrames._open))).close()
            try:
                f = LazyFrames._open[key] = h5py.File(self.path, "r")
            except OSError as exc:
                raise DataError(f"{self.path}: cannot reopen episode file: {exc}") from None
        return f

    def __getitem__(self, index) -> np.ndarray:
        try:
            return self._file()[self.name][index]
        except (OSError, ValueError, KeyError, RuntimeError) as exc:
            raise DataError(f"{self.path}: corrupt episode data in {self.name!r}: {exc}") from None

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        a = self[()]
        return a if dtype is None else a.astype(dtype)


def read_episode(path: str | Path, lazy: bool = False) -> Episode:
    """Read an episode file; any defect raises a DataError that names the file.

    With ``lazy`` the images stay on disk (:class:`LazyFrames`, one frame read per index) and only
    the small fields are loaded: for datasets larger than memory.
    """
    path = Path(path)
    with _Reader(path) as f:
        names = (
            (*_STEP_FIELDS, "progress", "blocks", "targets")
            if lazy
            else (*_STEP_FIELDS, *_FRAME_FIELDS, "targets")
        )
        arrays: dict[str, Any] = {name: f[name][()] for name in names}
        if lazy:
            for name in ("color", "height"):
                arrays[name] = LazyFrames(path, name, f[name].shape, f[name].dtype)
        attrs = {k: _decode_attr(v) for k, v in f.attrs.items()}
    episode = Episode(
        task=str(attrs.pop("task")),
        seed=int(attrs.pop("seed")),
        split=str(attrs.pop("split")),
        success=bool(attrs.pop("success")),
        attrs=attrs,
        path=path,
        **arrays,
    )
    episode.validate()
    return episode


def read_frames(path: str | Path, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Read the colour and height of the given frame indices only (one chunk each)."""
    frames = np.asarray(frames, dtype=np.int64)
    with _Reader(path) as f:
        order = np.unique(frames)
        color = f["color"][order]
        height = f["height"][order]
    where = np.searchsorted(order, frames)
    return color[where], height[where]
