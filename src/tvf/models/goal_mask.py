"""A goal-difference mask on the GCTN's maps: pick only where the scene stands above the goal, place only
where the goal stands above the scene (``--goal-mask``; the default of ``gctn`` and ``tvf-small``;
``--goal-mask False`` is the paper's unmasked GCTN).

Both images are top-down height maps of the same workspace, so a block that sits where the goal has it
already is not worth moving, and a place where the goal has nothing more than the scene is not worth
filling. :class:`GoalMaskedGCTN` wraps a GCTN and pushes its pick logits down where the current height
does not exceed the goal's by :data:`MARGIN_M`, and its place logits where the goal's does not exceed the
current one by as much. It needs no training and reads nothing but the two RGB-H images (the imagined
ones inside the search too). A state where the mask would forbid every pixel keeps its unmasked map.
Pixel-wise, the mask commutes with the turns and mirrors of :mod:`tvf.models.symmetry`, which wraps it.
"""

from __future__ import annotations

import torch

from tvf.models.gctn import GCTN, GctnWrapper
from tvf.models.images import HEIGHT_STD

MARGIN_M = 0.02
"""Half a block (4 cm): a height difference smaller than this is not a block to move or a hole to fill."""

MASKED_LOGIT = -1.0e4
"""The logit of a masked pixel: far below any the GCTN produces, so its softmax share is zero."""


def _height_gap(upper: torch.Tensor, lower: torch.Tensor) -> torch.Tensor:
    """Metres by which ``upper``'s height exceeds ``lower``'s, (B, H, W); a batch-1 image is shared."""
    return (upper[:, 3] - lower[:, 3]) * HEIGHT_STD


def _allowed(gap: torch.Tensor, margin: float) -> torch.Tensor:
    """Pixels whose gap exceeds ``margin``; a state with none keeps every pixel (B, H, W)."""
    allowed = gap > margin
    return allowed | ~allowed.flatten(1).any(dim=1).view(-1, 1, 1)


def pick_allowed(current: torch.Tensor, goal: torch.Tensor, margin: float = MARGIN_M) -> torch.Tensor:
    """Where the scene stands more than ``margin`` above the goal: a block the goal does not have there."""
    return _allowed(_height_gap(current, goal), margin)


def place_allowed(current: torch.Tensor, goal: torch.Tensor, margin: float = MARGIN_M) -> torch.Tensor:
    """Where the goal stands more than ``margin`` above the scene: a block the scene still lacks."""
    return _allowed(_height_gap(goal, current), margin)


def _masked(logits: torch.Tensor, allowed: torch.Tensor) -> torch.Tensor:
    """``logits`` (B, ..., H, W) with the pixels outside ``allowed`` (B, H, W) at :data:`MASKED_LOGIT`."""
    view = allowed.view(allowed.shape[0], *([1] * (logits.dim() - 3)), *allowed.shape[-2:])
    return torch.where(view, logits, torch.full_like(logits, MASKED_LOGIT))


def _require_goal(goal: torch.Tensor | None) -> torch.Tensor:
    if goal is None:
        raise ValueError("the goal-masked GCTN needs the goal image, not only its features")
    return goal


class GoalMaskedGCTN(GctnWrapper):
    """A GCTN whose pick and place logits are masked by the height difference to the goal."""

    def __init__(self, gctn: GCTN, margin: float = MARGIN_M) -> None:
        super().__init__(gctn)
        self.margin = margin

    def pick_logits(self, current: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """The GCTN's pick logits (B, H, W), masked outside :func:`pick_allowed`."""
        return _masked(self.gctn.pick_logits(current, goal), pick_allowed(current, goal, self.margin))

    def place_maps(
        self,
        current: torch.Tensor,
        goal: torch.Tensor | None,
        picks: torch.Tensor,
        goal_features: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """Place logits (B, P, R, H, W) at P picks per state, masked outside :func:`place_allowed`; the
        goal image is needed even when ``goal_features`` are given."""
        goal = _require_goal(goal)
        maps = self.gctn.place_maps(current, goal, picks, goal_features)
        return _masked(maps, place_allowed(current, goal, self.margin))


def goal_masked(gctn: GCTN, mask: bool) -> GCTN | GoalMaskedGCTN:
    """``gctn`` wrapped in :class:`GoalMaskedGCTN` when ``mask``, else itself."""
    return GoalMaskedGCTN(gctn) if mask else gctn
