"""A goal-difference mask on the GCTN's maps: pick only where the scene stands above the goal, place only
where the goal stands above the scene (``--goal-mask``; the default of every learned method, with the
``cells`` places; ``--goal-mask False`` is the paper's unmasked GCTN).

Both images are top-down height maps of the same workspace, so a block that sits where the goal has it
already is not worth moving, and a place where the goal has nothing more than the scene is not worth
filling. :class:`GoalMaskedGCTN` wraps a GCTN and pushes its pick logits down where the current height
does not exceed the goal's by :data:`MARGIN_M`, and its place logits where the goal's does not exceed the
current one by as much. It needs no training and reads nothing but the two RGB-H images (the imagined
ones inside the search too). A state where the mask would forbid every pixel keeps its unmasked map.
``--mask-places`` narrows the places further (:data:`PLACE_RULES`): to the middles of the regions to fill,
and to the places one block finishes before those that need another block under them first (a bridge
waits for its two columns). Pixel-wise and with square and disc windows, the mask commutes with the
turns and mirrors of :mod:`tvf.models.symmetry`, which wraps it.
"""

from __future__ import annotations

import functools

import torch
import torch.nn.functional as F

from tvf.geometry import PIXEL_SIZE
from tvf.models.gctn import GCTN, GctnWrapper
from tvf.models.images import HEIGHT_STD, heights_of
from tvf.tasks import BLOCK_SIZE

MARGIN_M = 0.02
"""Half a block (4 cm): a height difference smaller than this is not a block to move or a hole to fill."""

FOOTPRINT_PX = round(BLOCK_SIZE / PIXEL_SIZE)
"""A block's footprint in pixels (13: 4 cm at 3.125 mm): the window a placed block covers and rests on."""

CENTRED_SHARE = 0.9
"""A centred place's footprint holds at least this share of the allowed pixels of the best-filled one
(``--centred-share``; about a pixel either way of a region's middle, as each pixel off it loses 1/13)."""

MASKED_LOGIT = -1.0e4
"""The logit of a masked pixel: far below any the GCTN produces, so its softmax share is zero."""


def _height_gap(upper: torch.Tensor, lower: torch.Tensor) -> torch.Tensor:
    """Metres by which ``upper``'s height exceeds ``lower``'s, (B, H, W); a batch-1 image is shared."""
    return (upper[:, 3] - lower[:, 3]) * HEIGHT_STD


def _allowed(gap: torch.Tensor, margin: float) -> torch.Tensor:
    """Pixels whose gap exceeds ``margin``; a state with none keeps every pixel (B, H, W)."""
    return _unless_empty(gap > margin, torch.ones_like(gap, dtype=torch.bool))


def _unless_empty(narrow: torch.Tensor, wide: torch.Tensor) -> torch.Tensor:
    """``narrow`` (B, H, W) in the states where it keeps a pixel, ``wide`` in the others."""
    return torch.where(narrow.flatten(1).any(dim=1).view(-1, 1, 1), narrow, wide)


def pick_allowed(current: torch.Tensor, goal: torch.Tensor, margin: float = MARGIN_M) -> torch.Tensor:
    """Where the scene stands more than ``margin`` above the goal: a block the goal does not have there."""
    return _allowed(_height_gap(current, goal), margin)


PLACE_RULES = ("gap", "centred", "bottom-up", "ordered", "layered", "cells")
"""Which places the mask keeps (``--mask-places``): ``gap`` every pixel where the goal stands half a block
above the scene; ``centred`` only those whose block footprint lies (almost) wholly in such a region
(:func:`centred_places`); ``bottom-up`` only the places one block finishes while there are any
(:func:`finishing_places`); ``ordered`` both, centred first; ``layered`` of the places a block fits
(:func:`fitting_places`) those where it lands lowest (:func:`lowest_places`: a layer is finished before
a block goes on it, as the expert builds), the middles among them (:func:`centred_places`), of those
the ones flush against the region's boundary (:func:`flush_places`: a layer filled from its corners
in), and of those first the ones one block finishes; ``layered`` reads the goal with its seams closed
(:func:`seams_closed`); ``cells`` is ``layered`` with the middles and the flush places read on the cells
still to fill (:func:`open_cells`: the region to fill less the seam beside each finished block) instead
of on the places a block fits, so a block beside a finished one lands on its own cell."""

CENTRING_RULES = ("centred", "ordered", "layered", "cells")
"""The place rules that centre their places (:func:`centred_places`, ``--centred-share``)."""


def check_centred_share(share: float) -> float:
    """``share`` if it is a fraction in (0, 1], else a one-line error."""
    if not 0 < share <= 1:
        raise ValueError(f"the centred share must be in (0, 1], got {share}")
    return share


def check_place_rule(rule: str) -> str:
    """``rule`` if it is one of :data:`PLACE_RULES`, else a one-line error naming them."""
    if rule not in PLACE_RULES:
        raise ValueError(f"unknown place rule {rule!r}; choose one of {', '.join(PLACE_RULES)}")
    return rule


def place_allowed(
    current: torch.Tensor,
    goal: torch.Tensor,
    margin: float = MARGIN_M,
    rule: str = "gap",
    share: float = CENTRED_SHARE,
) -> torch.Tensor:
    """Where the goal stands more than ``margin`` above the scene: a block the scene still lacks (B, H, W);
    ``rule`` (:data:`PLACE_RULES`) narrows it to the centres of such regions (``share``:
    :func:`centred_places`), to the places that need no block under them first, both, or (``layered``,
    ``cells``) to the middles of the lowest layer still to fill and then the places that need no block
    under them."""
    allowed = _allowed(_height_gap(goal, current), margin)
    if check_place_rule(rule) in ("layered", "cells"):  # the lowest landing places first, then their middles
        goal = seams_closed(goal)
        fitting = _unless_empty(allowed & fitting_places(current, goal, margin), allowed)
        fill = fitting  # layered: the places a block fits; cells: the cells still to fill
        if rule == "cells":
            fill = _unless_empty(open_cells(current, goal, allowed, margin), allowed)
        centred = centred_places(fill, share, lowest_places(current, fitting, margin), disc=True)
        allowed = flush_places(centred, fill)
    elif rule in CENTRING_RULES:
        allowed = centred_places(allowed, share)
    if rule in ("bottom-up", "ordered", "layered", "cells"):
        allowed = _unless_empty(allowed & finishing_places(current, goal, margin), allowed)
    return allowed


SEAM_PX = 5
"""The window (pixels) of :func:`seams_closed`: wider than the 1 cm (3 px) gap between neighbouring
cells' blocks, narrower than a block."""


def seams_closed(image: torch.Tensor) -> torch.Tensor:
    """``image`` (B, 4, H, W) with the height channel's narrow dips closed (a grey closing over
    :data:`SEAM_PX`): the fused height map shows the 1 cm seam between two goal blocks as a lower height,
    which read pixel by pixel is a place one block finishes."""
    closed = -_square_max(-_square_max(image[:, 3:4], SEAM_PX), SEAM_PX)
    return torch.cat([image[:, :3], closed], dim=1)


SEAM_GAP_PX = 3
"""The seam between two neighbouring cells' blocks in pixels (1 cm at 3.125 mm): :func:`open_cells` keeps
this far off a finished block."""

CORE_PX = 7
"""The disc (pixels) a finished patch must hold to be a block's top in :func:`open_cells`: narrower than a
block (13), wider than the rims (a few pixels) where a blurred goal edge meets a lower layer."""


def open_cells(
    current: torch.Tensor, goal: torch.Tensor, fill: torch.Tensor, margin: float = MARGIN_M
) -> torch.Tensor:
    """The pixels of ``fill`` (B, H, W) more than :data:`SEAM_GAP_PX` from a finished block's top (a patch
    that stands more than ``margin`` above the table and within ``margin`` of the goal's height, at least
    :data:`CORE_PX` wide): the cells still to fill without the seam beside their finished neighbours. The
    fused goal shows that seam barely, so the region to fill reaches the neighbour's edge, a seam past its
    cell; centred and flush on that region, a block lands on its cell (:data:`PLACE_RULES`, ``cells``).
    The width test leaves out the thin rims where the goal's blurred edge meets a lower layer's top."""
    height = heights_of(current)
    finished = (height > margin) & (_height_gap(goal, current) <= margin)
    core = _disc_max((~finished).to(height.dtype), CORE_PX) <= 0  # wholly finished discs: block tops
    near = _disc_max(core.to(height.dtype), 2 * (CORE_PX // 2 + SEAM_GAP_PX) + 1) > 0
    return fill & ~near


def _square_max(height: torch.Tensor, size: int) -> torch.Tensor:
    """The largest value of ``height`` (B, 1, H, W) in the ``size`` square around each pixel: a max-pool
    down the columns, then along the rows (exact, cheaper than one square max-pool)."""
    pad = size // 2
    down = F.max_pool2d(height, (size, 1), stride=1, padding=(pad, 0))
    return F.max_pool2d(down, (1, size), stride=1, padding=(0, pad))


@functools.cache
def _disc_half_widths(diameter: int) -> tuple[int, ...]:
    """Half the width (pixels either side of the middle) of each row of the disc of :func:`_disc`, top to
    bottom (derived once per diameter: the landing height reads them at every call of the mask)."""
    inside = _disc(diameter)[0, 0] > 0
    return tuple(int(width) // 2 for width in inside.sum(dim=1))


def _disc_max(height: torch.Tensor, diameter: int) -> torch.Tensor:
    """The largest value (B, H, W) of ``height`` (B, H, W) in the disc of ``diameter`` around each pixel
    (-inf outside the image): running maxima along each row, widened one pixel either side at a time, then
    the largest over the disc's rows of the maximum of that row's width (exact; a few elementwise maxima
    instead of one max-pool per rectangle)."""
    reach = diameter // 2
    halves = _disc_half_widths(diameter)
    width = height.shape[-1]
    padded = F.pad(height, (reach, reach), value=-torch.inf)
    along = {0: height}
    running = height
    for half in range(1, max(halves) + 1):
        sides = torch.maximum(
            padded[..., reach - half : reach - half + width], padded[..., reach + half : reach + half + width]
        )
        running = torch.maximum(running, sides)
        along[half] = running
    return _over_disc_rows(along, halves, torch.maximum, -torch.inf)


def _over_disc_rows(along: dict, halves: tuple[int, ...], combine, outside: float) -> torch.Tensor:
    """``combine`` (max or sum), over the rows of a disc with half widths ``halves``, of the row results
    ``along[half]`` (B, H, W: each pixel's value over ``half`` pixels either side), each shifted to its
    row; rows beyond the image read ``outside``."""
    reach, rows = len(halves) // 2, along[halves[0]].shape[-2]
    result = None
    for row, half in enumerate(halves):
        shifted = F.pad(along[half], (0, 0, reach, reach), value=outside)[..., row : row + rows, :]
        result = shifted if result is None else combine(result, shifted)
    return result


def _disc_count(mask: torch.Tensor, diameter: int) -> torch.Tensor:
    """How many pixels of ``mask`` (B, H, W) the disc of ``diameter`` around each pixel holds (B, H, W,
    int32; zero outside the image): row sums from prefix sums, added over the disc's rows (exact)."""
    reach = diameter // 2
    halves = _disc_half_widths(diameter)
    width = mask.shape[-1]
    prefix = F.pad(mask.to(torch.int32).cumsum(dim=-1, dtype=torch.int32), (reach + 1, 0))
    total = prefix[..., -1:].expand(*prefix.shape[:-1], reach)  # past the right edge: the row's total
    prefix = torch.cat([prefix, total], dim=-1)
    along = {
        half: prefix[..., reach + half + 1 : reach + half + 1 + width]
        - prefix[..., reach - half : reach - half + width]
        for half in set(halves)
    }
    return _over_disc_rows(along, halves, torch.add, 0)


def _box_count(mask: torch.Tensor, size: int) -> torch.Tensor:
    """How many pixels of ``mask`` (B, H, W) the ``size`` × ``size`` square around each pixel holds (B, H,
    W, int32; zero outside the image), from a summed-area table (exact)."""
    reach = size // 2
    rows, width = mask.shape[-2:]
    table = F.pad(mask.to(torch.int32), (reach + 1, reach, reach + 1, reach))
    table = table.cumsum(-1, dtype=torch.int32).cumsum(-2, dtype=torch.int32)
    return (
        table[..., size : size + rows, size : size + width]
        - table[..., :rows, size : size + width]
        - table[..., size : size + rows, :width]
        + table[..., :rows, :width]
    )


FLUSH_SHARE = 0.9
"""A flush place's disc holds at least this share of the best flush place's share of the fill pixels
around it (:func:`flush_places`; about two pixels from a region's end, as each pixel inward adds a
column of the region to the window)."""


def flush_places(places: torch.Tensor, fill: torch.Tensor, share: float = FLUSH_SHARE) -> torch.Tensor:
    """The pixels of ``places`` (B, H, W) pushed furthest against the boundary of the fill region
    ``fill`` (B, H, W): whose footprint's disc holds at least ``share`` of the best one's share of the
    fill pixels in the window twice a footprint wide around it. A layer is filled from its corners and
    ends in, so each block lands on the goal's cell grid: a row's blocks on their cells, not across the
    seam of two; a pyramid's second layer across two blocks of the first, as the goal has it; a
    pallet's first block in a corner, not between its four cells."""
    inside = _disc_count(fill, FOOTPRINT_PX).float()
    area = float((2 * FOOTPRINT_PX - 1) ** 2)
    around = _box_count(fill, 2 * FOOTPRINT_PX - 1).float() / area * area  # a mean pool's rounding: as before
    held = inside / around.clamp(min=1.0)
    best = torch.where(places, held, torch.zeros_like(held)).flatten(1).max(dim=1).values
    return places & (held >= share * best.view(-1, 1, 1))


def _resting_height(current: torch.Tensor) -> torch.Tensor:
    """Normalised height (B, H, W) a block placed at each pixel lands on: the highest of its footprint,
    read over the disc inscribed in it (the same at any yaw: a square's corners reach the neighbours of a
    turned row of cells)."""
    return _disc_max(current[:, 3], FOOTPRINT_PX)


def finishing_places(current: torch.Tensor, goal: torch.Tensor, margin: float = MARGIN_M) -> torch.Tensor:
    """Places where one block, landing on the highest point of its footprint, brings the scene up to the
    goal's height within ``margin`` (B, H, W): the tops of columns one block short, where a place needs no
    other block under it first. A block bridging two columns is not finishing until both stand."""
    return (goal[:, 3] - _resting_height(current)) * HEIGHT_STD <= BLOCK_SIZE + margin


def fitting_places(current: torch.Tensor, goal: torch.Tensor, margin: float = MARGIN_M) -> torch.Tensor:
    """Places where a block, landing on the highest point of its footprint, tops out no more than
    ``margin`` over the goal's height (B, H, W): not on a finished block beside a sliver of its cell that
    a slightly misplaced block left uncovered."""
    return (goal[:, 3] - _resting_height(current)) * HEIGHT_STD >= BLOCK_SIZE - margin


def lowest_places(current: torch.Tensor, allowed: torch.Tensor, margin: float = MARGIN_M) -> torch.Tensor:
    """The pixels of ``allowed`` (B, H, W) where a block lands within ``margin`` of the lowest landing
    height among them: the lowest unfinished layer, so no column rises ahead of its neighbours."""
    rest = _resting_height(current) * HEIGHT_STD
    lowest = torch.where(allowed, rest, torch.full_like(rest, torch.inf)).flatten(1).min(dim=1).values
    return allowed & (rest <= lowest.view(-1, 1, 1) + margin)


def _disc(diameter: int = FOOTPRINT_PX) -> torch.Tensor:
    """A (1, 1, D, D) kernel: the pixels of a disc of ``diameter`` pixels, summing to 1."""
    offsets = torch.arange(diameter, dtype=torch.float32) - diameter // 2
    inside = (offsets[:, None] ** 2 + offsets[None] ** 2 <= (diameter / 2) ** 2).float()
    return (inside / inside.sum()).view(1, 1, diameter, diameter)


def centred_places(
    allowed: torch.Tensor, share: float = CENTRED_SHARE, among: torch.Tensor | None = None,
    disc: bool = False,
) -> torch.Tensor:  # fmt: skip
    """Pixels of ``among`` (B, H, W; default ``allowed``) whose block footprint (a :data:`FOOTPRINT_PX`
    square, or with ``disc`` the disc inscribed in it, the same at any yaw of the goal) holds at least
    ``share`` of the ``allowed`` pixels of the best-filled footprint among them in its state: the middles
    of the regions to fill rather than their rims (a block placed at a rim half misses its cell)."""
    among = allowed if among is None else among
    count = _disc_count if disc else _box_count
    fit = count(allowed, FOOTPRINT_PX).float()  # whole pixels: a share of the best exactly, ties kept
    best = torch.where(among, fit, torch.zeros_like(fit)).flatten(1).max(dim=1).values.view(-1, 1, 1)
    return among & (fit >= share * best)


def restricted(logits: torch.Tensor, allowed: torch.Tensor) -> torch.Tensor:
    """``logits`` (B, ..., H, W) with the pixels outside ``allowed`` (B, H, W) at :data:`MASKED_LOGIT`."""
    view = allowed.view(allowed.shape[0], *([1] * (logits.dim() - 3)), *allowed.shape[-2:])
    return torch.where(view, logits, torch.full_like(logits, MASKED_LOGIT))


def _require_goal(goal: torch.Tensor | None) -> torch.Tensor:
    if goal is None:
        raise ValueError("the goal-masked GCTN needs the goal image, not only its features")
    return goal


class GoalMaskedGCTN(GctnWrapper):
    """A GCTN whose pick and place logits are masked by the height difference to the goal."""

    def __init__(
        self, gctn: GCTN, margin: float = MARGIN_M, places: str = "gap", share: float = CENTRED_SHARE
    ) -> None:
        super().__init__(gctn)
        self.margin = margin
        self.places = check_place_rule(places)
        """The place rule (:data:`PLACE_RULES`)."""
        self.share = check_centred_share(share)
        """The centring rules' share (:data:`CENTRING_RULES`, :func:`centred_places`)."""

    def allowed_places(
        self, current: torch.Tensor, goal: torch.Tensor, rule: str | None = None
    ) -> torch.Tensor:
        """:func:`place_allowed` with this mask's margin and share, by ``rule`` (None: its own)."""
        return place_allowed(current, goal, self.margin, rule or self.places, self.share)

    def pick_logits(self, current: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """The GCTN's pick logits (B, H, W), masked outside :func:`pick_allowed`."""
        return restricted(self.gctn.pick_logits(current, goal), pick_allowed(current, goal, self.margin))

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
        return restricted(maps, self.allowed_places(current, goal))


def goal_masked(
    gctn: GCTN, mask: bool, places: str = "gap", share: float = CENTRED_SHARE
) -> GCTN | GoalMaskedGCTN:
    """``gctn`` wrapped in :class:`GoalMaskedGCTN` (keeping places by ``places``, centred by ``share``) when
    ``mask``, else itself."""
    return GoalMaskedGCTN(gctn, places=places, share=share) if mask else gctn


def mask_of(gctn: GCTN) -> GoalMaskedGCTN | None:
    """The goal mask among ``gctn``'s wrappers (e.g. under a symmetrising one), or None."""
    while isinstance(gctn, GctnWrapper):
        if isinstance(gctn, GoalMaskedGCTN):
            return gctn
        gctn = gctn.gctn
    return None
