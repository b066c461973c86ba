"""Training samples for the GCTN and the visual-foresight (VF) model, SE(2)-augmented in batches.

Both samplers are ``torch.utils.data.IterableDataset`` s that yield whole batches (use a DataLoader
with ``batch_size=None``), drawn as the reference does (facts §5-6): a task uniformly, an episode of
it uniformly, then a step uniformly. ``sample(batch_size, rng)`` draws one batch directly
(``part=slice(i, j)`` builds only those samples of it: one training process's share); ``item``
gives a fixed, un-augmented sample for evaluation and ``batch(ep, step)`` the same for many steps.

* :class:`GctnSampler`: (current, goal = last frame, pick pixel, place pixel, rotation bin) from the
  oracle steps only (states reached after a random action are included); with ``hindsight`` > 0 that
  share of the samples takes a later frame of the same demonstration as its goal instead (a partial
  structure the expert's next steps reach, :meth:`GctnSampler.draw`); with ``mirror`` > 0 that
  share of the samples is mirrored left-right before its turn, its rotation bin negated.
* :class:`VfSampler`: (current, action, next) from every step, oracle and random, and with
  probability 1/8 an identity sample (place = pick, no turn, next = current).
* :class:`VfRolloutSampler`: H consecutive steps of one episode (the frames ``step .. step + H`` and the
  H actions between them, one SE(2) transform for all), for the VF's multi-step (rollout) loss.

A batch is a dict of tensors. Images are raw units: ``*_color`` (B, H, W, 3) float32 0..255 and
``*_height`` (B, H, W) float32 metres (``tvf.models.images.to_rgbh`` normalises them). Pixels are
(B, 2) int64 (row, col); ``rot_bin`` (B,) int64; the VF's ``yaw`` (B,) float32 is the block's turn
in radians. ``aug_yaw`` (B,), ``aug_shift`` (B, 2) and ``aug_mirror`` (B,) bool record the transform
applied, ``episode`` and ``step`` (B,) where the sample came from (``episode`` indexes
``sampler.episodes``).
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import numpy as np
import torch
from torch.utils.data import IterableDataset, get_worker_info

from tvf.data.augment import Se2, sample_se2, transform_points, warp
from tvf.data.format import DataError, Episode, subpixel_to_pixel, world_to_subpixel
from tvf.geometry import WORKSPACE

IDENTITY_FRACTION = 1 / 8
"""Share of VF samples that are identity samples (facts §5)."""
VF_MARGIN = 20
"""The VF keeps points this many pixels around the pick and place inside the image (facts §5)."""


class _Sampler(IterableDataset):
    """Shared machinery: episodes grouped by task, the reference's draw, batched augmentation."""

    margin: float = 0.0
    mirror: float = 0.0
    """The share of augmented samples mirrored before their turn (only the GCTN's sets it)."""

    def __init__(
        self,
        episodes: Sequence[Episode],
        batch_size: int = 1,
        augment: bool = True,
        seed: int = 0,
        n_rotations: int = 36,
    ) -> None:
        if not episodes:
            raise DataError("a sampler needs at least one episode")
        if batch_size < 1:
            raise ValueError(f"batch_size must be at least 1, got {batch_size}")
        self.episodes = list(episodes)
        self.batch_size = batch_size
        self.augment = augment
        self.seed = seed
        self.n_rotations = n_rotations
        tasks = sorted({e.task for e in self.episodes})
        self.tasks = tasks
        self._by_task = [[i for i, e in enumerate(self.episodes) if e.task == t] for t in tasks]
        self._steps = [self.eligible_steps(e) for e in self.episodes]
        self._by_task = [[i for i in ids if len(self._steps[i])] for ids in self._by_task]
        if not any(self._by_task):
            raise DataError("no episode has a step this sampler can use")
        self._by_task = [ids for ids in self._by_task if ids]
        self._yaws = [e.relative_yaws() for e in self.episodes]
        self._bins = [e.rotation_bins(n_rotations) for e in self.episodes]
        self._pick_sub = [world_to_subpixel(e.pick[:, :2]) for e in self.episodes]
        self._place_sub = [world_to_subpixel(e.place[:, :2]) for e in self.episodes]

    # ---- what subclasses define
    def eligible_steps(self, episode: Episode) -> np.ndarray:
        raise NotImplementedError

    def _points(self, ep: np.ndarray, step: np.ndarray, drawn: np.ndarray) -> np.ndarray:
        """The key sub-pixel points (B, 2, 2) of each sample (pick, place) that the augmentation moves."""
        raise NotImplementedError

    def _build(
        self, ep: np.ndarray, step: np.ndarray, drawn: np.ndarray, se2: Se2, pixels: np.ndarray
    ) -> dict[str, torch.Tensor]:
        """The samples of (ep, step, drawn) warped by ``se2``, with their moved key ``pixels``."""
        raise NotImplementedError

    # ---- drawing
    def __len__(self) -> int:
        """Number of distinct (episode, step) samples (identity samples not counted)."""
        return sum(len(s) for s in self._steps)

    def draw(self, batch_size: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(episode, step, third) per sample: a task uniformly, an episode of it uniformly, an eligible
        step uniformly; the third array is the subclass's own per-sample draw (:meth:`undrawn` here: the
        VF's identity flags, the GCTN's goal frames)."""
        ep = np.empty(batch_size, np.int64)
        step = np.empty(batch_size, np.int64)
        for k in range(batch_size):
            ids = self._by_task[rng.integers(len(self._by_task))]
            ep[k] = ids[rng.integers(len(ids))]
            steps = self._steps[ep[k]]
            step[k] = steps[rng.integers(len(steps))]
        return ep, step, self.undrawn(ep, step)

    def undrawn(self, ep: np.ndarray, step: np.ndarray) -> np.ndarray:
        """The third array of :meth:`draw` for fixed samples (:meth:`batch`): no identity samples."""
        return np.zeros(len(ep), bool)

    def sample(
        self, batch_size: int | None = None, rng: np.random.Generator | None = None, part: slice | None = None
    ) -> dict:
        """One batch drawn like the reference, augmented if ``self.augment``; with ``part``, only those
        samples of it are built (bit-identical to slicing the whole batch: every draw and transform of
        the batch is made first, the images only for ``part``; a training process's share)."""
        rng = rng if rng is not None else np.random.default_rng(self.seed)
        ep, step, drawn = self.draw(batch_size or self.batch_size, rng)
        return self._made(ep, step, drawn, rng, self.augment, part)

    def _made(
        self, ep: np.ndarray, step: np.ndarray, drawn: np.ndarray, rng: np.random.Generator,
        augment: bool, part: slice | None = None,
    ) -> dict[str, torch.Tensor]:  # fmt: skip
        se2, pixels = self._transform(self._points(ep, step, drawn), rng, augment)
        if part is not None:
            ep, step, drawn, pixels = ep[part], step[part], drawn[part], pixels[part]
            se2 = se2.subset(part)
        return self._build(ep, step, drawn, se2, pixels)

    def item(self, index: int) -> dict[str, torch.Tensor]:
        """The ``index``-th (episode, step) sample in a fixed order, without augmentation (batch of 1)."""
        for e, steps in enumerate(self._steps):
            if index < len(steps):
                return self.batch(np.array([e]), np.array([steps[index]]))
            index -= len(steps)
        raise IndexError("sample index out of range")

    def batch(self, ep: np.ndarray, step: np.ndarray) -> dict[str, torch.Tensor]:
        """The samples of the given (episode, step) pairs in order, as :meth:`item` builds them: no
        augmentation, no identity samples (``ep`` indexes ``self.episodes``)."""
        ep = np.asarray(ep, np.int64)
        step = np.asarray(step, np.int64)
        return self._made(ep, step, self.undrawn(ep, step), np.random.default_rng(0), False)

    def __iter__(self) -> Iterator[dict[str, torch.Tensor]]:
        """Endless batches; each DataLoader worker draws from its own stream (seed, worker id)."""
        info = get_worker_info()
        rng = np.random.default_rng([self.seed, info.id if info else 0])
        while True:
            yield self.sample(self.batch_size, rng)

    # ---- helpers for subclasses
    def _frames(self, ep: np.ndarray, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        color = np.stack([self.episodes[e].color[f] for e, f in zip(ep, frame, strict=True)])
        height = np.stack([self.episodes[e].height[f] for e, f in zip(ep, frame, strict=True)])
        return color, height

    def _transform(
        self, points: np.ndarray, rng: np.random.Generator, augment: bool
    ) -> tuple[Se2, np.ndarray]:
        """A transform per sample (identity without augmentation) and the moved key pixels (B, K, 2)."""
        if augment:
            se2 = sample_se2(points, rng, margin=self.margin, mirror=self.mirror)
        else:
            se2 = Se2.identity(len(points))
        px = subpixel_to_pixel(transform_points(points, se2))
        # Rejection sampling keeps the points inside; the clip only acts on the untransformed fallback.
        px[..., 0] = np.clip(px[..., 0], 0, WORKSPACE.rows - 1)
        px[..., 1] = np.clip(px[..., 1], 0, WORKSPACE.cols - 1)
        return se2, px

    @staticmethod
    def _stack_images(*pairs: tuple[np.ndarray, np.ndarray]) -> torch.Tensor:
        """(color, height) pairs -> one (B, 4 * len(pairs), H, W) float32 tensor for a single warp."""
        parts = []
        for color, height in pairs:
            parts.append(torch.from_numpy(color).permute(0, 3, 1, 2).to(torch.float32))
            parts.append(torch.from_numpy(height).unsqueeze(1))
        return torch.cat(parts, dim=1)

    @staticmethod
    def _split_images(images: torch.Tensor, names: Sequence[str]) -> dict[str, torch.Tensor]:
        out = {}
        for i, name in enumerate(names):
            block = images[:, 4 * i : 4 * i + 4]
            out[f"{name}_color"] = block[:, :3].permute(0, 2, 3, 1).contiguous()
            out[f"{name}_height"] = block[:, 3].contiguous()
        return out

    @staticmethod
    def _meta(ep: np.ndarray, step: np.ndarray, se2: Se2) -> dict[str, torch.Tensor]:
        return {
            "episode": torch.from_numpy(ep.astype(np.int64)),
            "step": torch.from_numpy(step.astype(np.int64)),
            "aug_yaw": torch.from_numpy(se2.yaw.astype(np.float32)),
            "aug_shift": torch.from_numpy(se2.shift.astype(np.float32)),
            "aug_mirror": torch.from_numpy(se2.mirrored()),
        }


class GctnSampler(_Sampler):
    """GCTN samples: current and goal images, pick and place pixels, rotation bin (oracle steps only).

    The goal is the demonstration's last frame (the reference's), or with probability ``hindsight`` a
    later frame that the expert's next steps reach with no random step between (hindsight goals: the
    partial structures on the way, so the goals are many shapes, not one per task; the label stays the
    expert's action, which is the first of the steps that reach that frame). With probability ``mirror``
    an augmented sample is mirrored left-right before its turn (both images and both points), and its
    rotation bin negated: the mirror images of the six training structures, which no demonstration
    shows (off by default; the reference never mirrors).
    """

    margin = 0.0

    def __init__(
        self,
        episodes: Sequence[Episode],
        batch_size: int = 1,
        augment: bool = True,
        seed: int = 0,
        n_rotations: int = 36,
        hindsight: float = 0.0,
        mirror: float = 0.0,
    ) -> None:
        if not 0.0 <= hindsight <= 1.0:
            raise ValueError(f"hindsight is a share of the samples, between 0 and 1; got {hindsight}")
        if not 0.0 <= mirror <= 1.0:
            raise ValueError(f"mirror is a share of the samples, between 0 and 1; got {mirror}")
        super().__init__(episodes, batch_size, augment, seed, n_rotations)
        self.hindsight = hindsight
        self.mirror = mirror
        self._reach = [expert_reach(e) for e in self.episodes]

    def eligible_steps(self, episode: Episode) -> np.ndarray:
        return np.flatnonzero(~episode.random)

    def undrawn(self, ep: np.ndarray, step: np.ndarray) -> np.ndarray:
        """Fixed samples take the last frame as their goal."""
        return np.array([self.episodes[e].n_steps for e in ep], np.int64)

    def draw(self, batch_size: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(episode, step, goal frame) per sample; without hindsight the rng is drawn as the reference's."""
        ep, step, goal = super().draw(batch_size, rng)
        if self.hindsight > 0:
            relabel = rng.random(batch_size) < self.hindsight
            reach = np.array([self._reach[e][s] for e, s in zip(ep, step, strict=True)], np.int64)
            later = step + 1 + (rng.random(batch_size) * (reach - step)).astype(np.int64)
            goal = np.where(relabel, np.minimum(later, reach), goal)
        return ep, step, goal

    def _points(self, ep: np.ndarray, step: np.ndarray, goal: np.ndarray) -> np.ndarray:
        return np.stack(
            [np.stack([self._pick_sub[e][s], self._place_sub[e][s]]) for e, s in zip(ep, step, strict=True)]
        )

    def _build(
        self, ep: np.ndarray, step: np.ndarray, goal: np.ndarray, se2: Se2, pixels: np.ndarray
    ) -> dict[str, torch.Tensor]:
        images = warp(self._stack_images(self._frames(ep, step), self._frames(ep, goal)), se2)
        bins = np.array([self._bins[e][s] for e, s in zip(ep, step, strict=True)], np.int64)
        bins = np.where(se2.mirrored(), -bins % self.n_rotations, bins)  # a reflection reverses the turn
        return {
            **self._split_images(images, ("current", "goal")),
            "pick": torch.from_numpy(pixels[:, 0]),
            "place": torch.from_numpy(pixels[:, 1]),
            "rot_bin": torch.from_numpy(bins),
            "goal_frame": torch.from_numpy(goal.astype(np.int64)),
            **self._meta(ep, step, se2),
        }


def expert_reach(episode: Episode) -> np.ndarray:
    """For every step, the last frame the expert's steps from it reach before a random step: the next
    random step's index (the frame just before that step), or the last frame when none follows."""
    reach = np.full(episode.n_steps, episode.n_steps, np.int64)
    nxt = episode.n_steps
    for s in range(episode.n_steps - 1, -1, -1):
        reach[s] = nxt
        if episode.random[s]:
            nxt = s
    return reach


class VfSampler(_Sampler):
    """VF samples: current image, action (pick, place, turn), next image; 1/8 identity samples."""

    margin = VF_MARGIN

    def __init__(
        self,
        episodes: Sequence[Episode],
        batch_size: int = 1,
        augment: bool = True,
        seed: int = 0,
        n_rotations: int = 36,
        identity_fraction: float = IDENTITY_FRACTION,
    ) -> None:
        super().__init__(episodes, batch_size, augment, seed, n_rotations)
        self.identity_fraction = identity_fraction

    def eligible_steps(self, episode: Episode) -> np.ndarray:
        return np.arange(episode.n_steps)

    def draw(self, batch_size: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        ep, step, _ = super().draw(batch_size, rng)
        return ep, step, rng.random(batch_size) < self.identity_fraction

    def _points(self, ep: np.ndarray, step: np.ndarray, identity: np.ndarray) -> np.ndarray:
        pick = np.stack([self._pick_sub[e][s] for e, s in zip(ep, step, strict=True)])
        place = np.stack([self._place_sub[e][s] for e, s in zip(ep, step, strict=True)])
        place = np.where(identity[:, None], pick, place)  # an identity sample places where it picks
        return np.stack([pick, place], axis=1)

    def _build(
        self, ep: np.ndarray, step: np.ndarray, identity: np.ndarray, se2: Se2, pixels: np.ndarray
    ) -> dict[str, torch.Tensor]:
        yaw = np.array([self._yaws[e][s] for e, s in zip(ep, step, strict=True)])
        bins = np.array([self._bins[e][s] for e, s in zip(ep, step, strict=True)], np.int64)
        nxt = np.where(identity, step, step + 1)
        images = warp(self._stack_images(self._frames(ep, step), self._frames(ep, nxt)), se2)
        return {
            **self._split_images(images, ("current", "next")),
            "pick": torch.from_numpy(pixels[:, 0]),
            "place": torch.from_numpy(pixels[:, 1]),
            "yaw": torch.from_numpy(np.where(identity, 0.0, yaw).astype(np.float32)),
            "rot_bin": torch.from_numpy(np.where(identity, 0, bins).astype(np.int64)),
            "identity": torch.from_numpy(identity),
            **self._meta(ep, step, se2),
        }


class VfRolloutSampler(VfSampler):
    """VF rollouts: ``horizon`` consecutive (action, next) steps from one start, no identity samples.

    Beside the single-step keys of :class:`VfSampler` (``current``, ``next`` = the frame after the first
    action, ``pick``, ``place``, ``yaw``, ``rot_bin`` of the first action), a batch holds every step:
    ``picks`` / ``places`` (B, H, 2), ``yaws`` (B, H) and the frames after each action as ``frame1_*`` ..
    ``frameH_*``. One transform moves all the frames and all 2H points, and keeps every point inside.
    """

    def __init__(
        self,
        episodes: Sequence[Episode],
        batch_size: int = 1,
        augment: bool = True,
        seed: int = 0,
        n_rotations: int = 36,
        horizon: int = 2,
    ) -> None:
        if horizon < 1:
            raise ValueError(f"a rollout needs a horizon of at least 1 step, got {horizon}")
        self.horizon = horizon  # before the base class asks eligible_steps
        super().__init__(episodes, batch_size, augment, seed, n_rotations, identity_fraction=0.0)

    def eligible_steps(self, episode: Episode) -> np.ndarray:
        return np.arange(episode.n_steps - self.horizon + 1)

    def _points(self, ep: np.ndarray, step: np.ndarray, identity: np.ndarray) -> np.ndarray:
        """(B, 2H, 2): the pick and place of each of the H steps, in order."""
        steps = np.arange(self.horizon)
        picks = np.stack([self._pick_sub[e][s + steps] for e, s in zip(ep, step, strict=True)])
        places = np.stack([self._place_sub[e][s + steps] for e, s in zip(ep, step, strict=True)])
        return np.stack([picks, places], axis=2).reshape(len(ep), 2 * self.horizon, 2)

    def _build(
        self, ep: np.ndarray, step: np.ndarray, identity: np.ndarray, se2: Se2, pixels: np.ndarray
    ) -> dict[str, torch.Tensor]:
        h = self.horizon
        frames = [self._frames(ep, step + k) for k in range(h + 1)]
        names = ("current", *(f"frame{k}" for k in range(1, h + 1)))
        images = self._split_images(warp(self._stack_images(*frames), se2), names)
        yaws = np.stack([[self._yaws[e][s + k] for k in range(h)] for e, s in zip(ep, step, strict=True)])
        bins = np.array([self._bins[e][s] for e, s in zip(ep, step, strict=True)], np.int64)
        picks, places = pixels[:, 0::2], pixels[:, 1::2]
        return {
            **images,
            "next_color": images["frame1_color"],
            "next_height": images["frame1_height"],
            "pick": torch.from_numpy(picks[:, 0].copy()),
            "place": torch.from_numpy(places[:, 0].copy()),
            "yaw": torch.from_numpy(yaws[:, 0].astype(np.float32)),
            "rot_bin": torch.from_numpy(bins),
            "identity": torch.zeros(len(ep), dtype=torch.bool),
            "picks": torch.from_numpy(picks.copy()),
            "places": torch.from_numpy(places.copy()),
            "yaws": torch.from_numpy(yaws.astype(np.float32)),
            **self._meta(ep, step, se2),
        }
