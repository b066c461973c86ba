"""TVF's search with the simulator as its foresight: what a perfect foresight model would buy.

The tree is the one of :class:`~tvf.planning.search.TreeSearch` (the same GCTN proposals per node, the
same score ``gamma**(d-1) * (C - D(o, o_goal))``, the same choice of the executed action), but every
proposal is *executed* in the simulator from a snapshot of its parent's scene instead of imagined by the
VF, and its node is scored and expanded from the real observation that results. The search reads the
environment it will act in and puts it back exactly (:meth:`tvf.sim.env.TvfEnv.snapshot`), so it is an
upper bound for research (``tvf eval --foresight simulator``), not a method for a real robot. The tree
is expanded breadth-first, one node at a time (a simulator step is ~0.4 s on a laptop core, a TVF-L
decision 39 steps); a node whose action finishes the structure is not expanded further.

``simulator-first`` executes only the root's proposals and imagines the levels below with the VF from
those real outcomes (:meth:`TreeSearch.grow`): beside the VF's own search and the simulator's, it tells
whether depth fails on the VF's first imagined step (its errors compounding below) or on its later
ones (docs/results.md, "Where the VF caps depth").
"""

from __future__ import annotations

import numpy as np
import torch

from tvf.errors import TvfError
from tvf.models.images import to_rgbh
from tvf.planning.actions import refining_height
from tvf.planning.rigid import RIGID_FORESIGHTS
from tvf.planning.search import Node, Plan, TreeSearch, best_node, height_distance

FORESIGHTS = ("vf", "simulator", "simulator-first", *RIGID_FORESIGHTS)
"""What the search's nodes are scored from: the VF's imagined images (TVF), the simulator's outcomes,
the simulator's outcomes of the first actions and the VF's images below them, or the picked block moved
as a rigid body (:mod:`tvf.planning.rigid`, no network; ``rigid-falls``: tipping off where it would not
rest)."""
SIMULATED = {"simulator": None, "simulator-first": 1}
"""The foresights that execute proposals in the simulator, and how many levels they execute (None: all)."""


class SimulatedSearch:
    """The TVF search of ``proposer``'s GCTN and planner settings, with ``env`` (a simulator with
    ``snapshot``/``restore``/``forget``) in place of the VF for the first ``executed`` levels (None:
    all); deeper levels are imagined by ``proposer``'s VF from the simulator's outcomes."""

    def __init__(self, proposer: TreeSearch, env, refine_yaw: bool = False, executed: int | None = None
                 ) -> None:  # fmt: skip
        missing = [name for name in ("snapshot", "restore", "forget") if not hasattr(env, name)]
        if missing:
            raise TvfError(
                f"simulated foresight needs an environment that can save and restore its scene "
                f"(tvf.sim.env.TvfEnv); {type(env).__name__} has no {', '.join(missing)}"
            )
        depth = proposer.config.depth
        self.executed = depth if executed is None else min(executed, depth)
        if self.executed < depth and proposer.vf is None:
            raise TvfError("a search that imagines its deeper levels needs a VF: TreeSearch(gctn, vf, ...)")
        self.proposer, self.env, self.refine_yaw = proposer, env, refine_yaw
        self.config = proposer.config

    def _children(self, obs: dict, current: torch.Tensor, goal: dict, target: torch.Tensor, level: int
                  ) -> list[tuple[Node, np.ndarray]]:  # fmt: skip
        """The proposals of the scene ``obs`` (``current``: its RGB-H) towards ``goal`` (``target``) at
        ``level`` as (unscored node, world action) pairs."""
        goal_height = refining_height(goal, self.refine_yaw)
        props, bins, actions = self.proposer.propose_actions(current, target, obs["height"], goal_height,
                                                             level)  # fmt: skip
        return [
            (Node(-1, -1, level, pick, place, int(rot), 0.0, 0.0), action)
            for pick, place, rot, action in zip(props.picks, props.places, bins, actions, strict=True)
        ]

    @torch.no_grad()
    def search(self, obs: dict, goal: dict, keep_images: bool = False) -> tuple[Plan, list[np.ndarray]]:
        """Plan from the environment's current scene, whose observation is ``obs``, towards ``goal``
        (``{"color", "height"}`` each). Returns the plan and each node's world action; the environment is
        left as it was found."""
        cfg, env = self.config, self.env
        goal_rgbh = to_rgbh(goal["color"], goal["height"])
        plan = Plan([], -1, counts=dict(gctn_calls=0, vf_calls=0, gctn_states=0, vf_states=0, sim_steps=0))
        actions: list[np.ndarray] = []
        images: list[torch.Tensor] = []
        root = env.snapshot()
        held: dict[int, object] = {}  # the frontier's snapshots, freed as soon as their children exist
        leaves: list[tuple[torch.Tensor, int]] = []  # the deepest executed nodes the VF imagines below

        def hold():
            snapshot = env.snapshot()
            held[id(snapshot)] = snapshot
            return snapshot

        frontier = [(root, obs, to_rgbh(obs["color"], obs["height"]), -1)]
        try:
            for level in range(1, self.executed + 1):
                grown = []
                for snapshot, scene, scene_rgbh, parent in frontier:
                    plan.counts["gctn_calls"] += 1
                    plan.counts["gctn_states"] += 1
                    for node, action in self._children(scene, scene_rgbh, goal, goal_rgbh, level):
                        env.restore(snapshot, keep=True)
                        seen, _, finished, _, _ = env.step(action)
                        plan.counts["sim_steps"] += 1
                        rgbh = to_rgbh(seen["color"], seen["height"])
                        node.index, node.parent = len(plan.nodes), parent
                        node.distance = float(height_distance(rgbh, goal_rgbh)[0])
                        node.score = cfg.gamma ** (level - 1) * (cfg.bonus - node.distance)
                        plan.nodes.append(node)
                        actions.append(action)
                        if keep_images:
                            images.append(rgbh[0])
                        if level < self.executed and not finished:
                            grown.append((hold(), seen, rgbh, node.index))
                        elif level < cfg.depth and not finished:
                            leaves.append((rgbh, node.index))
                    if snapshot is not root:
                        env.forget(held.pop(id(snapshot)))
                frontier = grown
        finally:
            for snapshot in held.values():
                env.forget(snapshot)
            env.restore(root)
        if leaves:
            states = torch.cat([rgbh for rgbh, _ in leaves])
            imagined = self.proposer.grow(plan, states, [i for _, i in leaves], goal_rgbh, self.executed + 1)
            images += [image for level in imagined for image in level] if keep_images else []
        plan.best = best_node(plan.nodes, cfg.tie_band, cfg.first_step_band)
        plan.images = torch.stack(images) if keep_images and images else None
        return plan, actions
