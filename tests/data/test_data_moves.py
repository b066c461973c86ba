"""A method's own moves as foresight data (`tvf demos --moves`): episodes whose every step is the mover's,
kept whether or not they finish, from the seed only; folders that refuse to mix them with demonstrations;
the explorer's seeded draw over a search's root proposals."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from tvf.data import GenerationPlan, generate, open_dataset
from tvf.data.dataset import MOVES_FILE, moves_of
from tvf.data.format import DataError
from tvf.data.generation import check_moves, collect_episode, moves_budget
from tvf.errors import TvfError
from tvf.geometry import world_to_pixel
from tvf.planning.actions import bin_action
from tvf.planning.search import TreeSearch
from tvf.policies.explore import ProposalExplorer, check_moves_method, moves_rng
from tvf.tasks import get_task

CALLS: list[tuple[str, int]] = []


class TopToCorner:
    """A scripted mover: the highest pixel carried to a free spot near the workspace's corner."""

    def __init__(self, seed: int) -> None:
        self.seed, self.goals = seed, []

    def act(self, obs: dict, goal: dict) -> np.ndarray:
        self.goals.append(goal)
        height = obs["height"]
        pick = np.unravel_index(np.argmax(height), height.shape)
        return bin_action(pick, (24 + 8 * len(self.goals), 24), 0, 36, height)


def scripted_mover(method: str, seed: int) -> TopToCorner:
    CALLS.append((method, seed))
    return TopToCorner(seed)


def test_a_moves_episode_holds_only_the_movers_steps_and_is_kept_unfinished():
    task = get_task("stack-stair")
    CALLS.clear()
    ep, out = collect_episode(task, "train", 100000, moves="tvf-large", mover=scripted_mover)
    assert CALLS == [("tvf-large", 100000)]
    assert out.ok and ep is not None and not ep.success  # moving blocks to a corner finishes nothing
    assert ep.n_steps == moves_budget(task) == 2 * task.n_blocks
    assert ep.random.all() and ep.attrs["moves"] == "tvf-large"  # never the expert's: the GCTN skips them
    picks = world_to_pixel(ep.pick[:, :2])
    first = np.unravel_index(np.argmax(ep.height[0]), ep.height[0].shape)
    assert np.abs(picks[0] - np.asarray(first)).max() <= 1  # the mover's pick, executed
    again, _ = collect_episode(task, "train", 100000, moves="tvf-large", mover=scripted_mover)
    for f in dataclasses.fields(ep):
        if f.name not in ("path", "checksum", "attrs"):
            assert np.array_equal(getattr(ep, f.name), getattr(again, f.name)), f.name


def test_a_moves_episode_needs_its_mover():
    with pytest.raises(TvfError, match="mover"):
        collect_episode("stack-stair", "train", 0, moves="tvf-large")
    with pytest.raises(TvfError, match="mover"):
        generate(GenerationPlan(("stack-stair",), "train", 1, Path("/nonexistent"), moves="tvf-large"))
    with pytest.raises(DataError, match="--near-misses"):
        GenerationPlan(("stack-stair",), "train", 1, Path("x"), near_misses=1, moves="tvf-large")


def test_generate_writes_a_moves_folder_that_names_its_method(tmp_path):
    plan = GenerationPlan(("stack-stair",), "train", 2, tmp_path, first_seed=100000, moves="tvf-large")
    report = generate(plan, progress=False, mover=scripted_mover)
    assert report.generated == 2 and moves_of(tmp_path / "train") == "tvf-large"
    ds = open_dataset(tmp_path / "train")
    assert [i.seed for i in ds.infos()] == [100000, 100002]
    with pytest.raises(DataError, match="--moves tvf-large"):
        generate(dataclasses.replace(plan, moves=None), progress=False)


def test_a_folder_holds_demonstrations_or_one_methods_moves(tmp_path):
    folder = tmp_path / "train"
    folder.mkdir()
    check_moves(folder, None)  # an empty folder of demonstrations records nothing
    assert not (folder / MOVES_FILE).exists() and moves_of(folder) is None
    check_moves(folder, "tvf-small")
    check_moves(folder, "tvf-small")  # resuming
    with pytest.raises(DataError, match="own moves of tvf-small; pass --moves tvf-small"):
        check_moves(folder, "tvf-large")
    with pytest.raises(DataError, match="drop --moves"):
        (folder / MOVES_FILE).unlink()
        (folder / "stack-stair").mkdir()
        (folder / "stack-stair" / "000000.h5").write_bytes(b"")
        check_moves(folder, "tvf-small")
    (folder / MOVES_FILE).write_text("{")
    with pytest.raises(DataError, match="unreadable"):
        moves_of(folder)


def test_only_a_searching_method_has_moves_to_explore():
    check_moves_method("tvf-large-no-image-rules")
    with pytest.raises(TvfError, match="--moves gctn: only a searching method"):
        check_moves_method("gctn")


class ThreeProposals:
    """A stand-in search whose root always proposes the same three actions."""

    n_rotations = 36
    gctn = SimpleNamespace(parameters=lambda: iter([torch.zeros(1)]))
    propose_actions = TreeSearch.propose_actions  # the real conversion of proposals to actions

    def propose(self, current, goal, level):
        assert level == 1 and current.shape == goal.shape == (1, 4, 160, 160)
        picks = [(40, 40), (80, 80), (120, 120)]
        places = [(40, 100), (80, 120), (120, 40)]
        return SimpleNamespace(picks=picks, places=places), np.array([0, 9, 18])


def test_the_explorer_draws_root_proposals_from_its_episodes_stream():
    obs = {"color": np.zeros((160, 160, 3), np.uint8), "height": np.zeros((160, 160), np.float32)}
    explorer = ProposalExplorer(ThreeProposals(), moves_rng(7))
    picks = [tuple(world_to_pixel(explorer.act(obs, obs)[0, :2][None])[0]) for _ in range(60)]
    assert set(picks) == {(40, 40), (80, 80), (120, 120)}  # every proposal drawn, none other
    replay = ProposalExplorer(ThreeProposals(), moves_rng(7))
    assert picks == [tuple(world_to_pixel(replay.act(obs, obs)[0, :2][None])[0]) for _ in range(60)]
    near_misses = np.random.default_rng(np.random.SeedSequence(7).spawn(6)[5])  # the near misses' stream
    assert not np.array_equal(moves_rng(7).integers(3, size=20), near_misses.integers(3, size=20))
