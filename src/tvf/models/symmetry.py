"""Test-time rotation symmetrisation of a GCTN: average its maps over quarter turns of the scene.

A pick-and-place scene turned by 90 degrees asks for the same action, turned: the pick and the place
pixel move with the scene and the object's turn stays the same (planar rotations commute), so a
place-map channel keeps its meaning. The GCTN learns this only from augmentation. Averaging its
logits over the ``turns`` quarter turns of the scene (``torch.rot90``, an exact permutation of the
pixels, :func:`tvf.geometry.quarter_turn_pixels`) makes the maps exactly equivariant to those turns
(the group average of Huang et al.'s C4 argument, done at inference instead of in the kernels). It
costs ``turns`` GCTN evaluations per state; the weights are unchanged.

``turns`` = 8 adds the mirror images of the four turns (D4, the eight symmetries of the square image):
the scene is flipped left-right (``torch.flip``, :func:`tvf.geometry.mirror_pixels`), which turns the
object's turn ``theta`` into ``-theta``, so a mirrored place map's channels are read back in reverse
(:func:`mirrored_channels`). The world is mirror-symmetric (cubes, a square grid, gravity); the GCTN's
training never showed it a mirrored scene.
"""

from __future__ import annotations

import torch

from tvf.errors import TvfError
from tvf.geometry import mirror_pixels, quarter_turn_pixels
from tvf.models.gctn import GCTN, GctnWrapper, labelled_loss

TURNS = (1, 2, 4, 8)
"""Symmetrisations: none, the half turn (C2), the four quarter turns (C4), and those with their mirror
images (D4)."""

Element = tuple[int, bool]
"""One symmetry of the square image: ``(quarter turns, mirrored first)``."""


def check_turns(turns: int) -> int:
    """``turns`` if it is one of :data:`TURNS`; otherwise a one-line error naming the choices."""
    if turns not in TURNS:
        raise TvfError(
            f"--turns must be 1, 2, 4 (quarter turns the GCTN is averaged over) or 8 (and their mirror "
            f"images), got {turns}"
        )
    return turns


def group_elements(turns: int) -> tuple[Element, ...]:
    """The symmetries averaged over for ``turns``; the identity ``(0, False)`` comes first."""
    if check_turns(turns) == 8:
        return tuple((k, m) for m in (False, True) for k in range(4))
    return tuple((k, False) for k in range(0, 4, 4 // turns))


def _turn(images: torch.Tensor, k: int) -> torch.Tensor:
    return torch.rot90(images, k, dims=(-2, -1)) if k % 4 else images


def transform(images: torch.Tensor, element: Element) -> torch.Tensor:
    """The images (..., H, W) under ``element``: mirrored left-right first when it says so, then turned."""
    k, mirrored = element
    return _turn(torch.flip(images, dims=(-1,)) if mirrored else images, k)


def untransform(maps: torch.Tensor, element: Element) -> torch.Tensor:
    """The inverse of :func:`transform` on maps (..., H, W)."""
    k, mirrored = element
    back = _turn(maps, -k)
    return torch.flip(back, dims=(-1,)) if mirrored else back


def transform_pixels(pixels, element: Element, size: int):
    """Where integer pixels ``(..., 2)`` of a ``size`` x ``size`` image go under :func:`transform`."""
    k, mirrored = element
    return quarter_turn_pixels(mirror_pixels(pixels, size) if mirrored else pixels, k, size)


def mirrored_channels(channels: int) -> torch.Tensor:
    """The place-map channel order that reads a mirrored scene's map back: channel ``c`` of the scene
    is channel ``-c mod P`` of its mirror image (the channels' signed turns, :func:`tvf.models.gctn.
    channel_bins`, change sign; a full turn's bins too)."""
    return (-torch.arange(channels)) % channels


class SymmetrizedGCTN(GctnWrapper):
    """A GCTN whose pick and place logits are averaged over ``turns`` evenly spaced quarter turns (8: the
    four and their mirror images)."""

    def __init__(self, gctn: GCTN, turns: int) -> None:
        super().__init__(gctn)
        self.turns = check_turns(turns)
        self.elements = group_elements(turns)

    def pick_logits(self, current: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """Pick logits (B, H, W), the mean over the turns of the GCTN's, turned back."""
        maps = [
            untransform(self.gctn.pick_logits(transform(current, g), transform(goal, g)), g)
            for g in self.elements
        ]
        return torch.stack(maps).mean(dim=0)

    def goal_features(self, goal: torch.Tensor) -> torch.Tensor:
        """The transport's goal features of every turned goal, stacked: (turns, B, C, P, P)."""
        return torch.stack([self.gctn.goal_features(transform(goal, g)) for g in self.elements])

    def plain_goal_features(self, stacked: torch.Tensor) -> torch.Tensor:
        """The plain GCTN's goal features from :meth:`goal_features`' stack (its unturned entry)."""
        return stacked[self.elements.index((0, False))]

    def place_maps(
        self,
        current: torch.Tensor,
        goal: torch.Tensor | None,
        picks: torch.Tensor,
        goal_features: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Place logits (B, P, R, H, W) at P picks per state, averaged over the turns.

        ``goal_features`` are :meth:`goal_features`' stacked maps (computed from ``goal`` when None).
        """
        if goal_features is None:
            if goal is None:
                raise ValueError("pass goal or goal_features")
            goal_features = self.goal_features(goal)
        if goal_features.dim() != 5 or goal_features.shape[0] != self.turns:
            raise ValueError(
                f"expected goal features of shape ({self.turns}, B, C, P, P) from this model's "
                f"goal_features, got {tuple(goal_features.shape)}"
            )
        pixels = torch.as_tensor(picks).cpu().numpy()
        size = current.shape[-1]
        maps = []
        for features, g in zip(goal_features, self.elements, strict=True):
            moved_picks = torch.as_tensor(transform_pixels(pixels, g, size))
            moved_goal = None if goal is None else transform(goal, g)  # for a goal-masked GCTN
            moved = self.gctn.place_maps(transform(current, g), moved_goal, moved_picks, features)
            moved = untransform(moved, g)
            maps.append(moved[:, :, mirrored_channels(moved.shape[2])] if g[1] else moved)
        return torch.stack(maps).mean(dim=0)

    def loss(
        self, current: torch.Tensor, goal: torch.Tensor, pick_pixels: torch.Tensor,
        place_pixels: torch.Tensor, rot_bins: torch.Tensor,
    ) -> dict[str, torch.Tensor]:  # fmt: skip
        """:meth:`GCTN.loss` of the symmetrised maps (gradients reach the wrapped GCTN through every turn)."""
        return labelled_loss(self, current, goal, pick_pixels, place_pixels, rot_bins)


def symmetrized(gctn: GCTN, turns: int) -> GCTN | SymmetrizedGCTN:
    """``gctn`` itself for ``turns`` = 1, else its :class:`SymmetrizedGCTN`."""
    return gctn if check_turns(turns) == 1 else SymmetrizedGCTN(gctn, turns)
