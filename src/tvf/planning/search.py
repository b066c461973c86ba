"""TVF tree search: expand GCTN proposals through imagined (visual-foresight) images, level by level.

At every level all frontier states go through **one** batched GCTN call (pick logits, then the place
maps at each state's picks: its argmax, plus the next distinct picks with ``pick_branches`` > 1) and
all their children through **one** batched VF call; :meth:`TreeSearch.search_many` plans from N roots
(N environments, each with its own goal) at once, level by level over all their trees. A node at depth
``d`` (1-based) scores ``gamma**(d-1) * (C - D(o, o_goal))`` with

    D(o, o_goal) = sum over pixels |H_n(o) - H_n(o_goal)| / (160 * 160 * 4),

``H_n`` the normalised height channel (``(h - 0.00509) / 0.00904``). The divisor counts four channels
although only height is compared: the reference's constant, kept because it sets the trade-off against
the discount (one misplaced block moves D by ~0.015, the discount costs ~0.01 per level). The executed
action is the first one on the path to the best node (ties: the shallowest, then the earliest), and
the tree is rebuilt from the real observation after every step (receding horizon). With a ``tie_band``
> 0, root actions whose subtrees score within the band of the best are ties, and the GCTN's order of the
root proposals decides between them (:func:`best_node`). With ``place_search`` or ``turn_search`` > 0 the
executed action is that first action polished: moved to the nearby place and turn whose one-step
image is nearest the goal (:meth:`TreeSearch.polish`; ``Plan.chosen``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from tvf.device import mixes_environments
from tvf.models.gctn import argmax_pixels
from tvf.models.goal_mask import mask_of, place_allowed, restricted
from tvf.models.images import HEIGHT_CHANNEL, RGBH_CHANNELS, heights_of
from tvf.models.symmetry import SymmetrizedGCTN
from tvf.planning.actions import bin_action
from tvf.planning.levels import snap_heights
from tvf.planning.proposals import (
    BLOCK_PIXELS,
    RULES,
    Proposals,
    node_proposals,
    pick_peaks,
    with_extra_place,
)
from tvf.planning.support import FALL_PENALTY, rests

MAX_PLACE_SEARCH = int(2 * BLOCK_PIXELS)
"""The farthest :attr:`PlannerConfig.place_search` reaches: two blocks' widths."""
MAX_TURN_SEARCH = 18
"""The widest :attr:`PlannerConfig.turn_search`: half a turn either way in the 36 bins of a full turn."""
POLISH_STAGES = ("turn", "place", "turn")
"""The order :meth:`TreeSearch.polish` searches around the executed action: its turn at its place, its
place at the best turn, the turn again at the best place."""


def widest_node(k: int, root_k: int | None) -> int:
    """The most proposals any node of a search with ``k`` per node and ``root_k`` at the root has."""
    return max(k, root_k or 0)


@dataclass(frozen=True)
class PlannerConfig:
    """Tree-search settings; the method registry (tvf.policies) holds the TVF-Small and TVF-Large presets."""

    k: int = 3
    """Branching: proposals (children) per node."""
    depth: int = 3
    """Levels of imagined actions."""
    alpha: float = 0.01
    """Keep pixels whose place probability is at least alpha times the best."""
    root_alpha: float | None = None
    """``alpha`` for the root's proposals only (the first actions; deeper nodes keep ``alpha``, so the tree
    stays as pruned). None: ``alpha``, the paper's."""
    top_n: int = 100
    """At most this many candidate pixels go into K-means (``kmeans`` rule only)."""
    gamma: float = 0.99
    """Discount per level."""
    bonus: float = 1.0
    """The constant C in gamma^(d-1) (C - D)."""
    seed: int = 0
    """K-means seed (each clustering restarts from it, so a decision is a pure function of its images)."""
    batched: bool = True
    """One model call per level (False: one node at a time, for benchmarks; same results)."""
    proposals: str = "kmeans"
    """Place proposal rule: ``kmeans`` (the paper) or ``nms`` (non-maximum suppression)."""
    nms_radius: float = BLOCK_PIXELS
    """Pixels: NMS places (``nms``) and branched picks (``pick_branches`` > 1) are at least this far
    apart; the default is one block."""
    nms_rotation: float | None = None
    """Degrees: with ``nms``, a place nearer than ``nms_radius`` to an accepted one still counts as
    distinct when its turn differs by more than this (modulo the symmetry period); None: never."""
    pick_branches: int = 1
    """Distinct picks per node (1: the argmax pick only, the paper). Each of the P best picks gives its
    best place; the other ``k - P`` proposals are the rule's further places at the best pick."""
    turns_depth: int | None = None
    """With a symmetrised GCTN (``--turns``, :mod:`tvf.models.symmetry`): the levels, from the root, whose
    proposals come from the symmetrised maps; deeper levels use the plain GCTN (cheaper). None: all."""
    tie_band: float = 0.0
    """Root actions whose best node scores within this of the tree's best are ties, decided by the
    order of the root proposals (the GCTN's); 0: the best node's action, the paper's rule. One
    misplaced block moves a score by about 0.015; sub-millimetre sensor changes move it by about 1e-4."""
    order_branch: bool = False
    """With a goal-masked GCTN (:mod:`tvf.models.goal_mask`): one proposal of every node is the best place
    the mask's ``ordered`` rule keeps at the node's best pick (the middle of a region to fill, first where
    one block finishes it: a bridge waits for its columns), in place of the node's last proposal unless a
    proposal already lies within half a block of it. The greedy GCTN often ranks such a place under one
    a layer too low; the search then weighs both by their imagined outcomes (docs/planner.md)."""
    first_step_band: float | None = None
    """Only root actions whose own one-step score is within this of the best one's are compared by their
    subtrees' best scores; the others are not chosen, whatever their deeper nodes score. None: every root
    action (the paper's); 0: the one-step search's choice, deeper levels breaking exact ties only.
    Depth then reorders only first actions the one-step foresight cannot tell apart."""
    snap_heights: bool = False
    """Set every height the VF moved to the nearest level a surface rests at (:mod:`tvf.planning.levels`)
    before the node is scored and expanded; False: the VF's image as it is (the paper's)."""
    support_check: bool = False
    """A child whose placed block would not rest on its parent's height map (:mod:`tvf.planning.support`)
    has :data:`FALL_PENALTY` added to its distance, and so has every node below it: it ranks under
    every node that rests. False: every imagined place counts as landed (the paper's)."""
    root_k: int | None = None
    """Proposals of the real state (the root's children); deeper nodes have ``k``. None: ``k`` (the paper).
    A wider root over a narrower tree costs about the same and tries more first actions (for TVF-L it
    did worse on validation seeds: docs/results.md)."""
    place_search: int = 0
    """Pixels: after the search, the executed place may move this far along each image axis to where
    the foresight's one-step image is nearest the goal (:meth:`TreeSearch.polish`); 0: the proposal's
    pixel, the paper's."""
    turn_search: int = 0
    """Rotation bins: after the search, the executed turn may change by up to this many bins either way,
    chosen as the place (:attr:`place_search`); 0: the proposal's bin, the paper's."""

    def __post_init__(self) -> None:
        if self.k < 1 or self.depth < 1:
            raise ValueError(f"planner needs k >= 1 and depth >= 1, got k={self.k}, depth={self.depth}")
        if self.proposals not in RULES:
            raise ValueError(f"unknown proposal rule {self.proposals!r}; choose one of {', '.join(RULES)}")
        if self.root_k is not None and self.root_k < 1:
            raise ValueError(f"root_k must be None or at least 1, got {self.root_k}")
        if not 1 <= self.pick_branches <= self.widest:
            bound = "k" if self.widest == self.k else "root_k"
            raise ValueError(
                f"pick_branches must be between 1 and {bound} = {self.widest} (the picks share the K "
                f"proposals), got {self.pick_branches}"
            )
        if not (math.isfinite(self.nms_radius) and self.nms_radius > 0):
            raise ValueError(f"nms_radius must be a positive number of pixels, got {self.nms_radius}")
        if self.nms_rotation is not None and not 0 <= self.nms_rotation < 180:
            raise ValueError(f"nms_rotation must be None or degrees in [0, 180), got {self.nms_rotation}")
        if self.turns_depth is not None and self.turns_depth < 1:
            raise ValueError(f"turns_depth must be None or at least 1, got {self.turns_depth}")
        if not 0 < self.gamma <= 1:
            raise ValueError(f"gamma must be in (0, 1], got {self.gamma}")
        if not 0 < self.alpha <= 1:
            raise ValueError(f"alpha must be in (0, 1], got {self.alpha}")
        if self.root_alpha is not None and not 0 < self.root_alpha <= 1:
            raise ValueError(f"root_alpha must be None or in (0, 1], got {self.root_alpha}")
        if not (math.isfinite(self.tie_band) and self.tie_band >= 0):
            raise ValueError(f"tie_band must be a score difference >= 0, got {self.tie_band}")
        band = self.first_step_band
        if band is not None and not (math.isfinite(band) and band >= 0):
            raise ValueError(f"first_step_band must be None or a score difference >= 0, got {band}")
        if not 0 <= self.place_search <= MAX_PLACE_SEARCH:
            raise ValueError(f"place_search must be 0 to {MAX_PLACE_SEARCH} pixels, got {self.place_search}")
        if not 0 <= self.turn_search <= MAX_TURN_SEARCH:
            raise ValueError(
                f"turn_search must be 0 to {MAX_TURN_SEARCH} rotation bins, got {self.turn_search}"
            )

    @property
    def widest(self) -> int:
        """The most proposals any node has (``k``, or ``root_k`` when wider)."""
        return widest_node(self.k, self.root_k)

    def k_at(self, level: int) -> int:
        """Proposals per node at ``level`` (1: the root's children)."""
        return self.root_k if level == 1 and self.root_k is not None else self.k

    def alpha_at(self, level: int) -> float:
        """The probability share a candidate needs at ``level`` (1: the root's children)."""
        return self.root_alpha if level == 1 and self.root_alpha is not None else self.alpha

    def pick_branches_at(self, level: int) -> int:
        """Distinct picks per node at ``level``: ``pick_branches``, at most that level's K."""
        return min(self.pick_branches, self.k_at(level))


@dataclass
class Node:
    """One imagined action and its outcome. ``parent`` is -1 for children of the real state."""

    index: int
    parent: int
    depth: int
    pick: np.ndarray
    place: np.ndarray
    rotation: int
    distance: float
    score: float


@dataclass
class Plan:
    """A searched tree: nodes in breadth-first order, the best node and the path to it."""

    nodes: list[Node]
    best: int
    images: torch.Tensor | None = None
    """Imagined normalised RGB-H of every node (N, 4, H, W), when kept."""
    pick_logits: torch.Tensor | None = None
    """The root's pick logits (H, W)."""
    place_logits: torch.Tensor | None = None
    """The root's place logits (R, H, W) at its best (argmax) pick."""
    root_proposals: Proposals | None = None
    """The root's proposals (with their picks), in the order of the depth-1 nodes."""
    counts: dict = field(default_factory=dict)
    """Model calls and evaluated states: gctn_calls, vf_calls, gctn_states, vf_states."""
    polished: Node | None = None
    """:attr:`first` with its place and turn moved to the best nearby ones by its one-step imagined
    distance to the goal (``place_search``, ``turn_search``); None: not searched."""

    @property
    def path(self) -> list[Node]:
        """Nodes from depth 1 down to the best node."""
        out = [self.nodes[self.best]]
        while out[-1].parent >= 0:
            out.append(self.nodes[out[-1].parent])
        return out[::-1]

    @property
    def first(self) -> Node:
        """The first action of the best path."""
        return self.path[0]

    @property
    def chosen(self) -> Node:
        """The action to execute now: :attr:`first`, or its :attr:`polished` version."""
        return self.polished if self.polished is not None else self.first


def root_values(nodes: list[Node]) -> tuple[np.ndarray, np.ndarray]:
    """For ``nodes`` in breadth-first order: the index of each node's root action (a depth-1 node), and
    per node index the best score in that root's subtree (-inf for nodes that are not roots)."""
    root = np.empty(len(nodes), dtype=int)
    for i, node in enumerate(nodes):
        root[i] = i if node.parent < 0 else root[node.parent]
    value = np.full(len(nodes), -np.inf)
    np.maximum.at(value, root, np.array([node.score for node in nodes]))
    return root, value


def best_node(nodes: list[Node], tie_band: float = 0.0, first_step_band: float | None = None) -> int:
    """The node whose path is executed (``nodes`` in breadth-first order, so the root actions come first,
    in proposal order). Only root actions whose own score is within ``first_step_band`` of the best root
    action's compete (None: all). With ``tie_band`` 0: the first maximum among them (the shallowest,
    then the earliest); otherwise the first root action whose subtree's best score is within
    ``tie_band`` of the best, and its best node."""
    scores = np.array([node.score for node in nodes])
    root, value = root_values(nodes)
    if first_step_band is not None:
        competing = near_best_first_steps(nodes, first_step_band)
        scores = np.where(competing[root], scores, -np.inf)
        value = np.where(competing, value, -np.inf)
    if tie_band <= 0:
        return int(np.argmax(scores))
    chosen = int(np.flatnonzero(value >= scores.max() - tie_band)[0])
    return int(np.flatnonzero(root == chosen)[np.argmax(scores[root == chosen])])


def near_best_first_steps(nodes: list[Node], band: float) -> np.ndarray:
    """Per node index: a root action (depth 1) whose own score is within ``band`` of the best root's."""
    first = np.array([node.score if node.parent < 0 else -np.inf for node in nodes])
    return first >= first.max() - band


def height_distance(images: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
    """D(o, o_goal) per image: summed |normalised height difference| / (H * W * 4)."""
    h, w = images.shape[-2:]
    diff = (images[:, HEIGHT_CHANNEL] - goal[:, HEIGHT_CHANNEL]).abs()
    return diff.sum(dim=(-2, -1)) / (h * w * RGBH_CHANNELS)


def _goal_rows(features: torch.Tensor, rows: slice | torch.Tensor) -> torch.Tensor:
    """The goal features of some roots: batch dim 0 of a plain GCTN's (B, C, P, P), dim 1 of a
    symmetrised one's stack (turns, B, C, P, P)."""
    return features[:, rows] if features.dim() == 5 else features[rows]


def _padded(sets: list[np.ndarray]) -> np.ndarray:
    """Each state's picks (n_i, 2) stacked (N, max n_i, 2): states with fewer repeat their best one."""
    width = max(len(s) for s in sets)
    return np.stack([np.concatenate([s, np.repeat(s[:1], width - len(s), axis=0)]) for s in sets])


def _distinct_rows(picks: np.ndarray) -> np.ndarray:
    """``picks`` (n, 2) without the repeats of an earlier row (two picks moved to one block's centre)."""
    _, first = np.unique(picks, axis=0, return_index=True)
    return picks[np.sort(first)]


@dataclass
class _Level:
    """One level's frontier over all the roots of a search: the states (rows grouped by root, in root
    order), each row's root and node index in its root's plan (-1: the real state)."""

    states: torch.Tensor
    roots: np.ndarray
    ids: list[int]
    falls: np.ndarray | None = None
    """With the support check: whether the node's path holds a place that would not rest."""


class TreeSearch:
    """The TVF planner over a GCTN (proposals) and a VF model (imagination).

    :meth:`search_many` plans from N roots at once (N environments, each with its own goal): every
    level of all N trees goes through the models together. With ``mix_roots`` False (the default on the
    CPU) each model call holds the rows of one root only, exactly the calls of a single search, so every
    plan is bit-identical to :meth:`search` of its root alone (CPU convolutions round differently with
    the batch). With ``mix_roots`` True (the default on other devices) a level is one call over all
    roots, which a GPU runs as one large batch; plans then agree up to float rounding.
    """

    def __init__(self, gctn, vf, config: PlannerConfig, mix_roots: bool | None = None) -> None:
        self.gctn, self.vf, self.config = gctn, vf, config
        self.n_rotations = gctn.preset.n_rotations
        self.mix_roots = mix_roots

    def _mixes(self, device: torch.device) -> bool:
        return self.mix_roots if self.mix_roots is not None else mixes_environments(device)

    def _parts(self, roots: np.ndarray, mix: bool) -> list[slice]:
        """Row ranges of one model call each: one node at a time (``batched`` False), all rows (``mix``)
        or one range per root (rows are grouped by root)."""
        n = len(roots)
        if not self.config.batched:
            return [slice(i, i + 1) for i in range(n)]
        if mix:
            return [slice(0, n)]
        starts = [0, *np.flatnonzero(np.diff(roots) != 0) + 1, n]
        return [slice(int(a), int(b)) for a, b in zip(starts[:-1], starts[1:], strict=True)]

    @staticmethod
    def _root_rows(roots: np.ndarray, part: slice) -> slice | torch.Tensor:
        """Index of the goal rows of ``part``: one root's batch-1 slice (shared, as a single search's
        goal), else one row per state."""
        first, last = int(roots[part.start]), int(roots[part.stop - 1])
        return slice(first, first + 1) if first == last else torch.as_tensor(roots[part])

    def _gctn_at(self, level: int, goal_features: torch.Tensor):
        """The GCTN that proposes at ``level`` and its goal features: the plain one below ``turns_depth``."""
        limit = self.config.turns_depth
        if isinstance(self.gctn, SymmetrizedGCTN) and limit is not None and level > limit:
            return self.gctn.gctn, self.gctn.plain_goal_features(goal_features)
        return self.gctn, goal_features

    def _picks(self, pick_logits: torch.Tensor, level: int) -> list[np.ndarray]:
        """Each state's picks (n_i, 2), best first: the argmax, then further distinct picks."""
        cfg = self.config
        branches = cfg.pick_branches_at(level)
        if branches == 1:
            return [p[None] for p in argmax_pixels(pick_logits).cpu().numpy()]
        return [pick_peaks(x, branches, cfg.alpha_at(level), cfg.nms_radius) for x in pick_logits]

    @torch.no_grad()
    def _propose(self, frontier: _Level, goals: torch.Tensor, goal_features: torch.Tensor, level: int,
                 mix: bool):  # fmt: skip
        """GCTN on every state: its picks (list of (n_i, 2)), its place logits at them (list of
        (n_i, R, H, W)), the pick logits (N, H, W) and, with ``order_branch``, each state's place logits at
        its best pick restricted to the ordered places (list of (R, H, W); else Nones)."""
        gctn, goal_features = self._gctn_at(level, goal_features)
        states, roots = frontier.states, frontier.roots
        picks, places, pick_logits, ordered = [], [], [], []
        for part in self._parts(roots, mix):
            rows = self._root_rows(roots, part)
            logits = gctn.pick_logits(states[part], goals[rows])
            sets = self._picks(logits, level)
            moved = gctn.pick_pixels(states[part], torch.as_tensor(_padded(sets))).cpu().numpy()
            sets = [_distinct_rows(m[: len(s)]) for m, s in zip(moved, sets, strict=True)]
            padded = _padded(sets)
            features = _goal_rows(goal_features, rows)
            maps = gctn.place_maps(states[part], goals[rows], torch.as_tensor(padded), features)
            places += [m[: len(s)] for m, s in zip(maps, sets, strict=True)]
            picks += sets
            pick_logits.append(logits)
            if self.config.order_branch:
                keep = self._ordered_places(states[part], goals[rows])
                ordered += list(restricted(maps[:, 0], keep))
            else:
                ordered += [None] * len(sets)
        return picks, places, torch.cat(pick_logits), ordered

    def _ordered_places(self, states: torch.Tensor, goals: torch.Tensor) -> torch.Tensor:
        """The ``ordered`` places of ``states`` (B, H, W), with the GCTN's goal mask's margin and centring
        (the module's defaults for an unmasked GCTN)."""
        mask = mask_of(self.gctn)
        if mask is None:
            return place_allowed(states, goals, rule="ordered")
        return mask.allowed_places(states, goals, rule="ordered")

    def _proposals(self, picks: np.ndarray, place_logits: torch.Tensor, level: int,
                   ordered: torch.Tensor | None = None) -> Proposals:  # fmt: skip
        cfg = self.config
        period = place_logits.shape[1] * 360.0 / self.n_rotations  # degrees the channels cover
        props = node_proposals(
            place_logits, picks, cfg.k_at(level), rule=cfg.proposals, alpha=cfg.alpha_at(level),
            top_n=cfg.top_n, seed=cfg.seed, radius=cfg.nms_radius, rotation_tolerance=cfg.nms_rotation,
            period=period,
        )  # fmt: skip
        if ordered is None:
            return props
        return with_extra_place(props, ordered, picks[0], cfg.k_at(level), BLOCK_PIXELS / 2)

    @torch.no_grad()
    def propose(
        self, current: torch.Tensor, goal: torch.Tensor, level: int = 1
    ) -> tuple[Proposals, np.ndarray]:
        """The proposals of one state (normalised RGB-H, (1, 4, H, W)) as a node at ``level`` of this
        search would have them (1: the root's), and their rotation bins of a full turn."""
        frontier = _Level(current, np.zeros(1, dtype=int), [-1])
        features = self._goal_features(goal, mix=False)
        picks, places, _, ordered = self._propose(frontier, goal, features, level, mix=False)
        props = self._proposals(picks[0], places[0], level, ordered[0])
        return props, self.gctn.rotation_bins(torch.as_tensor(props.rotations)).cpu().numpy()

    @torch.no_grad()
    def _imagine(self, states: torch.Tensor, roots: np.ndarray, goals: torch.Tensor, picks, places, yaws,
                 mix: bool) -> tuple[torch.Tensor, torch.Tensor]:  # fmt: skip
        """The VF's children of ``states`` and their distances D to their roots' goals."""
        children, distances = [], []
        for p in self._parts(roots, mix):
            images = self.vf.predict_rgbh(states[p], picks[p], places[p], yaws[p])
            if self.config.snap_heights:
                images = snap_heights(images, states[p])
            children.append(images)
            distances.append(height_distance(images, goals[self._root_rows(roots, p)]))
        return torch.cat(children), torch.cat(distances)

    def propose_actions(self, current: torch.Tensor, goal: torch.Tensor, height: np.ndarray,
                        goal_height: np.ndarray | None = None, level: int = 1
                        ) -> tuple[Proposals, np.ndarray, list[np.ndarray]]:  # fmt: skip
        """:meth:`propose` and each proposal's world action (2, 4) on the scene's height map ``height``
        (:func:`~tvf.planning.actions.bin_action`; with ``goal_height`` the turn refined)."""
        props, bins = self.propose(current, goal, level)
        actions = [bin_action(pick, place, int(rot), self.n_rotations, height, goal_height)
                   for pick, place, rot in zip(props.picks, props.places, bins, strict=True)]  # fmt: skip
        return props, bins, actions

    @torch.no_grad()
    def search(self, current: torch.Tensor, goal: torch.Tensor, keep_images: bool = False) -> Plan:
        """Plan from the real state ``current`` towards ``goal`` (normalised RGB-H, (1, 4, H, W) each)."""
        return self.search_many(current, goal, keep_images)[0]

    @torch.no_grad()
    def search_many(
        self, currents: torch.Tensor, goals: torch.Tensor, keep_images: bool = False
    ) -> list[Plan]:
        """One plan per root: from ``currents[i]`` towards ``goals[i]`` (normalised RGB-H, (N, 4, H, W))."""
        cfg = self.config
        if not (torch.isfinite(currents).all() and torch.isfinite(goals).all()):
            raise ValueError("planner input contains NaN or infinity")
        if currents.shape[0] != goals.shape[0]:
            raise ValueError(
                f"{currents.shape[0]} states but {goals.shape[0]} goals: pass one goal per state"
            )
        n = currents.shape[0]
        mix = self._mixes(currents.device)
        goal_features = self._goal_features(goals, mix)
        frontier = _Level(currents, np.arange(n), [-1] * n)
        plans = [
            Plan([], -1, counts=dict(gctn_calls=0, vf_calls=0, gctn_states=0, vf_states=0)) for _ in range(n)
        ]
        images: list[list[torch.Tensor]] = [[] for _ in range(n)]
        for level in range(1, cfg.depth + 1):
            frontier = self._expand(plans, frontier, goals, goal_features, level, mix)
            if keep_images:
                for r in range(n):
                    images[r].append(frontier.states[torch.as_tensor(frontier.roots == r)])
        for plan, kept in zip(plans, images, strict=True):
            plan.best = best_node(plan.nodes, cfg.tie_band, cfg.first_step_band)
            plan.images = torch.cat(kept) if keep_images else None
        if cfg.place_search or cfg.turn_search:
            for r, plan in enumerate(plans):
                plan.polished = self.polish(plan.first, currents[r : r + 1], goals[r : r + 1], plan.counts)
        return plans

    @torch.no_grad()
    def polish(self, node: Node, current: torch.Tensor, goal: torch.Tensor, counts: dict | None = None
               ) -> Node:  # fmt: skip
        """``node`` (an action on the real state ``current``, (1, 4, H, W)) with its turn and place moved to
        where the foresight's image of it is nearest ``goal`` (the distance D the search scores): turns
        within ``turn_search`` bins of its own and places within ``place_search`` pixels of its own along
        each axis, searched one after the other (:data:`POLISH_STAGES`), each stage at the best of the
        stage before. The action held so far wins ties, so a foresight that cannot tell them apart
        leaves the proposal as it is. ``counts`` (a plan's) gets the foresight calls and images it costs."""
        cfg = self.config
        place, rotation, distance = node.place, node.rotation, None
        for stage in POLISH_STAGES:
            reach = cfg.turn_search if stage == "turn" else cfg.place_search
            if reach == 0:
                continue
            places, rotations = self._around(node, place, rotation, stage, reach, tuple(current.shape[-2:]))
            distances = self._one_step(current, goal, node.pick, places, rotations)
            if counts is not None:
                counts["vf_calls"] += 1 if cfg.batched else len(places)
                counts["vf_states"] += len(places)
            best = int(torch.argmin(distances))  # the first of equal minima: index 0, the action held
            place, rotation, distance = places[best], int(rotations[best]), float(distances[best])
        score = cfg.bonus - distance
        return Node(node.index, node.parent, node.depth, node.pick, place, rotation, distance, score)

    def _around(self, node: Node, place: np.ndarray, rotation: int, stage: str, reach: int,
                shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:  # fmt: skip
        """The candidates of one :meth:`polish` stage: the action held (``place``, ``rotation``) first, then
        ``node``'s own turn (stage ``turn``) or place (``place``) and those within ``reach`` of it, the
        other part held; (n, 2) places inside the image and (n,) rotation bins of a full turn."""
        steps = np.array([0, *(s for d in range(1, reach + 1) for s in (-d, d))])
        if stage == "turn":
            rotations = np.concatenate([[rotation], (node.rotation + steps) % self.n_rotations])
            return np.repeat(place[None], len(rotations), axis=0), rotations
        offsets = np.stack(np.meshgrid(steps, steps, indexing="ij"), axis=-1).reshape(-1, 2)
        places = np.concatenate([place[None], node.place[None] + offsets])
        inside = (places >= 0).all(axis=1) & (places[:, 0] < shape[0]) & (places[:, 1] < shape[1])
        places = places[inside]
        return places, np.full(len(places), rotation)

    def _one_step(self, current: torch.Tensor, goal: torch.Tensor, pick: np.ndarray, places: np.ndarray,
                  rotations: np.ndarray) -> torch.Tensor:  # fmt: skip
        """D of the foresight's image of each action (``pick``, ``places[i]``, ``rotations[i]``) on
        ``current``, towards ``goal`` (n,); with the support check, a place that would not rest carries
        :data:`FALL_PENALTY`, as in the search."""
        n = len(places)
        picks = torch.as_tensor(np.repeat(np.asarray(pick)[None], n, axis=0))
        yaws = torch.as_tensor(rotations * (2 * math.pi / self.n_rotations), dtype=torch.float32)
        states = current.expand(n, -1, -1, -1)
        places = torch.as_tensor(places)
        _, distances = self._imagine(states, np.zeros(n, dtype=int), goal, picks, places, yaws, mix=False)
        if self.config.support_check:  # as the search ranks its children
            falls = ~rests(heights_of(states), picks, places)
            distances = distances + FALL_PENALTY * falls.to(distances)
        return distances

    @torch.no_grad()
    def grow(self, plan: Plan, states: torch.Tensor, parents: list[int], goal: torch.Tensor, level: int
             ) -> list[torch.Tensor]:  # fmt: skip
        """Add to ``plan`` (one root's, towards ``goal`` (1, 4, H, W)) the imagined subtrees of ``states``
        (normalised RGB-H (N, 4, H, W): the scenes of its nodes ``parents``, at ``level`` - 1), from
        ``level`` down to the configured depth; returns each new level's images, in node order. A search
        whose upper levels come from elsewhere (the simulator: :mod:`tvf.planning.simulated`) imagines
        the rest with this one's models."""
        features = self._goal_features(goal, mix=False)
        frontier = _Level(states, np.zeros(len(parents), dtype=int), list(parents))
        imagined = []
        for depth in range(level, self.config.depth + 1):
            frontier = self._expand([plan], frontier, goal, features, depth, mix=False)
            imagined.append(frontier.states)
        return imagined

    def _expand(self, plans: list[Plan], frontier: _Level, goals: torch.Tensor, goal_features: torch.Tensor,
                level: int, mix: bool) -> _Level:  # fmt: skip
        """Propose, imagine and score the children of every frontier state; add them to their roots' plans
        and return them, the next frontier."""
        cfg = self.config
        picks, place_logits, pick_logits, ordered = self._propose(frontier, goals, goal_features, level, mix)
        proposals = [
            self._proposals(p, m, level, o) for p, m, o in zip(picks, place_logits, ordered, strict=True)
        ]
        if level == 1:  # one row per root
            for plan, logits, maps, props in zip(plans, pick_logits, place_logits, proposals, strict=True):
                plan.pick_logits, plan.place_logits, plan.root_proposals = logits, maps[0], props
        parent_rows = [i for i, p in enumerate(proposals) for _ in range(len(p))]
        child_roots = frontier.roots[parent_rows]
        child_picks = torch.as_tensor(np.concatenate([p.picks for p in proposals]))
        child_places = torch.as_tensor(np.concatenate([p.places for p in proposals]))
        channels = torch.as_tensor(np.concatenate([p.rotations for p in proposals]))
        rotations = self.gctn.rotation_bins(channels).cpu().numpy()  # bins of a full turn
        yaws = torch.as_tensor(rotations * (2 * math.pi / self.n_rotations), dtype=torch.float32)
        parents = frontier.states[parent_rows]
        children, distances = self._imagine(parents, child_roots, goals, child_picks, child_places, yaws, mix)
        falls = None
        if cfg.support_check:
            falls = ~rests(heights_of(parents), child_picks, child_places).cpu().numpy()
            falls |= frontier.falls[parent_rows] if frontier.falls is not None else False
            distances = distances + FALL_PENALTY * torch.as_tensor(falls, dtype=distances.dtype).to(distances)
        scores = cfg.gamma ** (level - 1) * (cfg.bonus - distances)
        ids = []
        for j, (row, root) in enumerate(zip(parent_rows, child_roots, strict=True)):
            nodes = plans[root].nodes
            ids.append(len(nodes))
            nodes.append(Node(len(nodes), frontier.ids[row], level, child_picks[j].numpy(),
                              child_places[j].numpy(), int(rotations[j]), float(distances[j]),
                              float(scores[j])))  # fmt: skip
        for r, plan in enumerate(plans):
            self._count(plan, int((frontier.roots == r).sum()), int((child_roots == r).sum()))
        return _Level(children, child_roots, ids, falls)

    def _goal_features(self, goals: torch.Tensor, mix: bool) -> torch.Tensor:
        """The GCTN's goal features of every root: one call for all (``mix``), else one per root."""
        if mix or goals.shape[0] == 1:
            return self.gctn.goal_features(goals)
        per_root = [self.gctn.goal_features(goals[i : i + 1]) for i in range(goals.shape[0])]
        return torch.cat(per_root, dim=1 if per_root[0].dim() == 5 else 0)

    def _count(self, plan: Plan, gctn_states: int, vf_states: int) -> None:
        """Model calls of one level: one per level when batched, one per state otherwise."""
        batched = self.config.batched
        plan.counts["gctn_states"] += gctn_states
        plan.counts["vf_states"] += vf_states
        plan.counts["gctn_calls"] += 1 if batched else gctn_states
        plan.counts["vf_calls"] += 1 if batched else vf_states
