"""`tvf viz plan`'s tree: one parent -> child edge per node, a layout with parents between their children,
every node drawn with its colour and height images and its score."""

from __future__ import annotations

import io

import numpy as np
import pytest
import torch
from matplotlib.figure import Figure
from PIL import Image

from tvf.models.gctn import GCTN
from tvf.models.images import from_rgbh
from tvf.models.presets import get_preset
from tvf.models.vf import VisualForesight
from tvf.planning.search import Node, PlannerConfig, TreeSearch
from tvf.viz.plan import ROOT, decision_figure, draw_tree, node_caption, tree_edges, tree_layout


@pytest.fixture(scope="module")
def searched():
    """A K=2, depth-2 search of the smoke models on random images, with the images kept."""
    preset = get_preset("smoke")
    gctn, vf = GCTN(preset, seed=1).eval(), VisualForesight(preset, seed=2).eval()
    gen = torch.Generator().manual_seed(0)
    current, goal = torch.randn(1, 4, 160, 160, generator=gen), torch.randn(1, 4, 160, 160, generator=gen)
    plan = TreeSearch(gctn, vf, PlannerConfig(k=2, depth=2)).search(current, goal, keep_images=True)
    color, height = from_rgbh(current)
    obs = {"color": color[0].clamp(0, 255).to(torch.uint8).numpy(), "height": height[0].clamp(min=0).numpy()}
    return plan, obs, gctn.preset.n_rotations


def node(i: int, parent: int, depth: int) -> Node:
    return Node(i, parent, depth, np.zeros(2, int), np.zeros(2, int), 0, 0.1, 0.9)


def test_one_edge_per_non_root_node(searched):
    plan, _, _ = searched
    edges = tree_edges(plan.nodes)
    assert len(edges) == len(plan.nodes) and len(plan.nodes) > 2
    assert sorted(child for _, child in edges) == [n.index for n in plan.nodes]  # each node once, as a child
    depth = {n.index: n.depth for n in plan.nodes} | {ROOT: 0}
    assert all(depth[child] == depth[parent] + 1 for parent, child in edges)
    assert {p for p, c in edges if depth[c] == 1} == {ROOT}


def test_layout_puts_parents_between_their_children():
    # root -> 0, 1; 0 -> 2, 3; 1 has no children (a node whose proposals ran out)
    nodes = [node(0, ROOT, 1), node(1, ROOT, 1), node(2, 0, 2), node(3, 0, 2)]
    layout = tree_layout(nodes)
    assert layout[2] == (2.0, 0.0) and layout[3] == (2.0, 1.0) and layout[1] == (1.0, 2.0)
    assert layout[0] == (1.0, 0.5) and layout[ROOT] == (0.0, 1.25)


def test_the_tree_is_drawn_with_its_edges_images_and_scores(searched):
    plan, obs, rotations = searched
    ax = Figure().add_subplot()
    edges = draw_tree(ax, obs, plan, rotations)
    assert len(ax.lines) == len(edges) == len(plan.nodes)  # one line per edge
    assert len(ax.images) == 2 * (len(plan.nodes) + 1)  # colour and height of the root and every node
    texts = [t.get_text() for t in ax.texts]
    best = plan.nodes[plan.best]
    assert f"#{best.index} d{best.depth} s={best.score:.4f} *" in "\n".join(texts)
    assert len(texts) == len(plan.nodes) + 1
    blue = [line for line in ax.lines if line.get_color() == "royalblue"]
    assert len(blue) == len(plan.path)  # the best path's edges stand out


def test_node_caption_names_score_distance_and_turn():
    n = Node(4, 1, 2, np.zeros(2, int), np.zeros(2, int), 9, 0.0385, 0.9615)
    assert node_caption(n, 36, best=4) == "#4 d2 s=0.9615 *\nD=0.0385, turn +90°"
    assert node_caption(n, 36, best=0).startswith("#4 d2 s=0.9615\n")


def test_decision_figure_grows_with_the_tree(searched):
    plan, obs, rotations = searched
    png = decision_figure(obs, obs, plan, rotations)
    small = Image.open(io.BytesIO(png))
    assert png[:4] == b"\x89PNG" and small.height > small.width / 2
    one_level = type(plan)([n for n in plan.nodes if n.depth == 1], best=0, images=plan.images,
                           place_logits=plan.place_logits, root_proposals=plan.root_proposals)  # fmt: skip
    assert Image.open(io.BytesIO(decision_figure(obs, obs, one_level, rotations))).height < small.height
