"""Test-time rotation symmetrisation of a GCTN: average its maps over quarter turns of the scene.

A pick-and-place scene turned by 90 degrees asks for the same action, turned: the pick and the place
pixel move with the scene and the object's turn stays the same (planar rotations commute), so a
place-map channel keeps its meaning. The GCTN learns this only from augmentation. Averaging its
logits over the ``turns`` quarter turns of the scene (``torch.rot90``, an exact permutation of the
pixels, :func:`tvf.geometry.quarter_turn_pixels`) makes the maps exactly equivariant to those turns
(the group average of Huang et al.'s C4 argument, done at inference instead of in the kernels). It
costs ``turns`` GCTN evaluations per state; the weights are unchanged.
"""

from __future__ import annotations

import torch
from torch import nn

from tvf.errors import TvfError
from tvf.geometry import quarter_turn_pixels
from tvf.models.gctn import GCTN, greedy_action, labelled_loss
from tvf.models.images import as_pixels

TURNS = (1, 2, 4)
"""Symmetrisations: none, the half turn (C2) and the four quarter turns (C4)."""


def check_turns(turns: int) -> int:
    """``turns`` if it is one of :data:`TURNS`; otherwise a one-line error naming the choices."""
    if turns not in TURNS:
        raise TvfError(f"--turns must be 1, 2 or 4 (quarter turns the GCTN is averaged over), got {turns}")
    return turns


def _turn(images: torch.Tensor, k: int) -> torch.Tensor:
    return torch.rot90(images, k, dims=(-2, -1)) if k % 4 else images


class SymmetrizedGCTN(nn.Module):
    """A GCTN whose pick and place logits are averaged over ``turns`` evenly spaced quarter turns."""

    checkpoint_kind = "gctn"

    def __init__(self, gctn: GCTN, turns: int) -> None:
        super().__init__()
        self.gctn = gctn
        self.turns = check_turns(turns)
        self.preset = gctn.preset
        self.quarter_turns = tuple(range(0, 4, 4 // turns))

    def config(self) -> dict:
        return self.gctn.config()

    def rotation_bins(self, channels: torch.Tensor) -> torch.Tensor:
        return self.gctn.rotation_bins(channels)

    def pick_logits(self, current: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """Pick logits (B, H, W), the mean over the turns of the GCTN's, turned back."""
        maps = [
            _turn(self.gctn.pick_logits(_turn(current, k), _turn(goal, k)), -k) for k in self.quarter_turns
        ]
        return torch.stack(maps).mean(dim=0)

    def goal_features(self, goal: torch.Tensor) -> torch.Tensor:
        """The transport's goal features of every turned goal, stacked: (turns, B, C, P, P)."""
        return torch.stack([self.gctn.goal_features(_turn(goal, k)) for k in self.quarter_turns])

    def plain_goal_features(self, stacked: torch.Tensor) -> torch.Tensor:
        """The plain GCTN's goal features from :meth:`goal_features`' stack (its unturned entry)."""
        return stacked[self.quarter_turns.index(0)]

    def place_map(
        self,
        current: torch.Tensor,
        goal: torch.Tensor | None,
        pick_pixels: torch.Tensor,
        goal_features: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Place logits (B, R, H, W) at one pick per state (see :meth:`GCTN.place_map`)."""
        b = current.shape[0]
        pick = as_pixels(pick_pixels, b, current.shape[-2:])
        return self.place_maps(current, goal, pick[:, None], goal_features)[:, 0]

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
        for features, k in zip(goal_features, self.quarter_turns, strict=True):
            turned_picks = torch.as_tensor(quarter_turn_pixels(pixels, k, size))
            turned = self.gctn.place_maps(_turn(current, k), None, turned_picks, features)
            maps.append(_turn(turned, -k))
        return torch.stack(maps).mean(dim=0)

    def loss(
        self, current: torch.Tensor, goal: torch.Tensor, pick_pixels: torch.Tensor,
        place_pixels: torch.Tensor, rot_bins: torch.Tensor,
    ) -> dict[str, torch.Tensor]:  # fmt: skip
        """:meth:`GCTN.loss` of the symmetrised maps (gradients reach the wrapped GCTN through every turn)."""
        return labelled_loss(self, current, goal, pick_pixels, place_pixels, rot_bins)

    @torch.no_grad()
    def act(self, current: torch.Tensor, goal: torch.Tensor):
        """Greedy action of the symmetrised maps (see :meth:`GCTN.act`)."""
        return greedy_action(self, current, goal)


def symmetrized(gctn: GCTN, turns: int) -> GCTN | SymmetrizedGCTN:
    """``gctn`` itself for ``turns`` = 1, else its :class:`SymmetrizedGCTN`."""
    return gctn if check_turns(turns) == 1 else SymmetrizedGCTN(gctn, turns)
