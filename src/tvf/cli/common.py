"""What every command shares: the output checks (from tvf.io) and the flag checks.

Commands import their pipeline inside ``run()``: torch, PyBullet and matplotlib take seconds to import,
and `tvf --help` (or a typo) should not pay for them.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from tvf.errors import TvfError
from tvf.io import check_output_dir, check_output_file, output_dir

if TYPE_CHECKING:
    from tvf.policies import PolicySpec

__all__ = ["PlannerFlags", "at_least_one", "check_output_dir", "check_output_file", "output_dir"]


@dataclass(frozen=True)
class PlannerFlags:
    """The models and planner settings of a method (`tvf eval`, `tvf ablate`, `tvf viz plan`); each flag
    left out keeps the method's default (docs/planner.md)."""

    gctn: Path | None = None
    """GCTN run folder (its checkpoints/last.pt), a .pt or .safetensors file; default: the shipped weights."""
    vf: Path | None = None
    """VF run folder or checkpoint file (TVF methods); default: the shipped weights."""
    proposals: str | None = None
    """TVF: proposal rule, kmeans (the paper's) | nms (places a block apart)."""
    pick_branches: int | None = None
    """TVF: distinct picks each node branches over (1: the argmax pick only, the paper's)."""
    alpha: float | None = None
    """TVF: keep place pixels whose probability is at least ALPHA times the best (default 0.01, the
    paper's)."""
    nms_radius: float | None = None
    """TVF with nms or several picks: pixels between proposals (default 13, about one block)."""
    turns: int | None = None
    """GCTN and TVF: average the GCTN's maps over 1, 2 or 4 quarter turns of the scene (exact C4
    equivariance at 4x the GCTN's cost; 1: the paper's), or 8: the four turns and their mirror images
    (D4, 8x)."""
    turns_depth: int | None = None
    """TVF with --turns: the search levels, from the root, that use the symmetrised GCTN; deeper ones use
    the plain GCTN (1 = the root's proposals only)."""
    tie_band: float | None = None
    """TVF: root actions whose best imagined outcome scores within TIE_BAND of the best are ties, and the
    GCTN's order decides (default: the method's, tvf-small 0.002, tvf-large 0; 0: the best score wins,
    the paper's). 0.001 is about a fifteenth of a misplaced block (docs/planner.md; measured in
    docs/real-robot.md)."""
    root_k: int | None = None
    """TVF: proposals of the real state, the first actions the search tries (default: K, as every node,
    the paper's). A wide root over a narrow tree, e.g. --root-k 6 --k 2, costs about as much as K 3."""
    goal_mask: bool | None = None
    """GCTN and TVF: True picks only where the scene stands half a block above the goal and places only
    where the goal stands half a block above the scene (the two height maps compared; no training;
    docs/planner.md); False: the paper's unmasked GCTN; default: the method's."""
    mask_places: str | None = None
    """With the goal mask: gap (every place the goal stands above the scene) | centred (only the middles
    of those regions) | bottom-up (first the places one block finishes: a bridge waits for its columns) |
    ordered (centred, then bottom-up) | layered (centred, on the lowest layer still to fill, filled
    from its ends and corners in, then bottom-up; best with --centre-picks True) | cells (layered,
    with a block beside a finished one put on its own cell, not a seam's width off it); default: the
    method's, cells for gctn, tvf-small and tvf-large (docs/planner.md)."""
    centred_share: float | None = None
    """With --mask-places centred, ordered, layered or cells: a place's block footprint must hold this share
    of the allowed pixels of the best-filled one (default 0.9: about a pixel either way of a region's middle;
    lower keeps more of each region; docs/planner.md)."""
    refine_yaw: bool | None = None
    """GCTN and TVF: True sets the place's turn to the yaws of the picked block and of the goal's block at
    the place, read from the two height maps, where both readings are clear (no training;
    docs/planner.md); False: the GCTN's rotation bin as it is (the paper's); default: the method's."""
    centre_picks: bool | None = None
    """GCTN and TVF: True moves each pick the GCTN chooses to the centre of the block's top face under it,
    read from the height map, so the place it predicts is where the block's middle goes (no training;
    docs/planner.md); False: the GCTN's pick pixel (the paper's); default: the method's, True for gctn,
    tvf-small and tvf-large."""

    order_branch: bool | None = None
    """TVF with the goal mask: True makes one proposal of every node the best place of the mask's ordered
    rule (the middle of a region to fill, first where one block finishes it: a bridge waits for its
    columns), so the search weighs it against the GCTN's own places (docs/planner.md); default: the
    method's (False: the paper's proposals)."""

    gamma: float | None = None
    """TVF: the discount per search level in the score gamma^(d-1) (1 - D) (default 0.99, the paper's).
    Closer to 1 ranks deeper imagined progress higher: an imagined block lowers D by about 0.01, what the
    paper's discount costs a level (docs/planner.md)."""

    root_alpha: float | None = None
    """TVF: --alpha for the root's proposals only, the first actions (deeper nodes keep --alpha, so the
    tree stays as pruned); default: the method's (tvf-large 0.001; --alpha alone sets every node's, the
    root's too)."""

    first_step_band: float | None = None
    """TVF: only first actions whose one-step imagined score is within FIRST_STEP_BAND of the best one's
    are compared by their deeper nodes; the others are not chosen (default: the method's, every first
    action, the paper's; 0: the one-step choice, depth breaking exact ties only). One misplaced block
    moves a score by about 0.015."""
    snap_heights: bool | None = None
    """TVF: True sets every height the VF imagines moved to the nearest level a surface rests at (the
    table, a base cell's top, the top of a stack of blocks on either) before the node is scored and
    expanded, so blur does not pile up over the levels (docs/planner.md); False: the VF's image as it
    is (the paper's); default: the method's."""
    support_check: bool | None = None
    """TVF: True ranks a node whose path places a block that would not rest where it is put (its centre
    not inside the support the parent's height map gives it, read under the block's footprint) under
    every node that rests: the VF draws such a block where it is put, the simulator drops it
    (docs/planner.md); False: every imagined place counts as landed (the paper's); default: the
    method's."""
    place_search: int | None = None
    """TVF: after the search, the executed place may move up to PLACE_SEARCH pixels along each axis to
    where the foresight's one-step image is nearest the goal, searched after --turn-search's turns and
    before them again (default: the method's, 0: the GCTN's pixel, the paper's; docs/planner.md)."""
    turn_search: int | None = None
    """TVF: after the search, the executed turn may change by up to TURN_SEARCH rotation bins (10 degrees
    each) either way, chosen likewise (default: the method's, 0: the paper's)."""
    foresight: str | None = None
    """TVF: what scores the search's nodes, vf (the VF's imagined images, the default) | simulator (each
    proposal executed in the episode's simulator and undone: a perfect foresight, an upper bound for
    research, about 0.4 s a node on a laptop core; `tvf eval` and `tvf ablate` only; docs/planner.md) |
    simulator-first (the first actions executed, the levels below imagined by the VF from their real
    outcomes: which of the VF's imagined steps caps depth) | rigid (no network: the picked block moved
    as a rigid body on the height map, landing on what is under it; falls are not drawn;
    docs/planner.md) | rigid-falls (rigid, and a block whose centre is not over its support tips off
    it)."""

    def spec(self, method: str, k: int | None = None, depth: int | None = None, device: str = "auto"
             ) -> PolicySpec:  # fmt: skip
        """The policy these flags choose for ``method``."""
        from tvf.policies import PolicySpec

        return PolicySpec(
            method, _path(self.gctn), _path(self.vf), k, depth, device, self.proposals, self.pick_branches,
            self.turns, self.turns_depth, self.alpha, self.nms_radius, self.tie_band, self.root_k,
            self.goal_mask, self.mask_places, self.refine_yaw, self.order_branch, self.gamma,
            self.root_alpha, self.centred_share, self.centre_picks, self.foresight, self.first_step_band,
            self.snap_heights, self.support_check, self.place_search, self.turn_search,
        )  # fmt: skip


def _path(p: Path | None) -> str | None:
    return str(p) if p else None


def at_least_one(**flags: int) -> None:
    """Refuse counts below 1, naming every such flag of the command (``max_tries`` -> ``--max-tries``)."""
    if any(value < 1 for value in flags.values()):
        names = [f"--{n.replace('_', '-')}" for n in flags]
        listed = names[0] if len(names) == 1 else f"{', '.join(names[:-1])} and {names[-1]}"
        raise TvfError(f"{listed} must be at least 1")
