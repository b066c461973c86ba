"""Generation: seeds, schedules, the in-order commit (any worker count), resuming, and real episodes."""

from __future__ import annotations

import dataclasses
import json
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest
from data_factory import make_episode

from tvf.data import GenerationPlan, generate, open_dataset, read_episode, split_seeds
from tvf.data.dataset import FAILURES, MANIFEST
from tvf.data.format import DataError, episode_name, write_h5
from tvf.data.generation import (
    Outcome,
    action_schedule,
    check_near_misses,
    collect_episode,
    read_failures,
    step_kinds,
)
from tvf.geometry import WORKSPACE
from tvf.io import temp_path
from tvf.sim.oracle import NEAR_MISS_OFFSET, NEAR_MISS_TURN, near_miss
from tvf.tasks import BLOCK_SIZE, Task, get_task


def test_split_seeds_have_the_split_parity():
    assert split_seeds("train", 0, 4) == [0, 2, 4, 6]
    assert split_seeds("test", 0, 3) == [1, 3, 5]
    assert split_seeds("train", 7, 2) == [8, 10]
    assert split_seeds("test", 7, 2) == [7, 9]


def test_action_schedules():
    task = get_task("stack-palace")
    train = action_schedule(task, "train", 4)
    assert len(train) == task.n_blocks + 2 and sum(train) == 2 and not train[-1]
    assert train == action_schedule(task, "train", 4)
    assert not any(a and b for a, b in zip(train, train[1:], strict=False))
    assert action_schedule(task, "test", 5) == [False] * task.n_blocks
    assert len({tuple(action_schedule(task, "train", s)) for s in range(0, 40, 2)}) > 1


# --------------------------------------------------------------- the scheduler, with a fake episode job
FAILING = {2, 8, 10}


def fake_job(task: Task, split: str, seed: int, folder: str) -> Outcome:
    """Fails on FAILING seeds; finishes in a seed-dependent order; writes a small synthetic episode."""
    task = task.name
    time.sleep(((seed * 7919) % 13) / 400)
    if seed in FAILING:
        return Outcome(task, seed, False, reason="fake failure", steps=1)
    final = Path(folder) / task / episode_name(seed)
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_path(final).with_name(f".{final.name}.{seed}.tmp")
    ep = make_episode(task, seed, steps=2, split=split, rng_seed=seed)
    ep.color, ep.height = np.zeros_like(ep.color), np.zeros_like(ep.height)  # small files
    write_h5(tmp, ep)
    return Outcome(task, seed, True, steps=2, tmp=str(tmp))


def _run(out, episodes=3, threads=1, tasks=("stack-stair", "stack-tower"), max_tries=3):
    plan = GenerationPlan(tuple(tasks), "train", episodes, out, max_tries=max_tries)
    if threads <= 1:
        return generate(plan, 1, progress=False, job=fake_job, log=lambda s: None)
    with ThreadPoolExecutor(threads) as pool:
        return generate(plan, threads, progress=False, job=fake_job, executor=pool, log=lambda s: None)


def _kept(out) -> dict[str, list[int]]:
    ds = open_dataset(out / "train")
    return {t: [e.seed for e in eps] for t, eps in ds.episodes.items()}


def test_kept_episodes_do_not_depend_on_the_worker_count(tmp_path):
    serial = _run(tmp_path / "a", threads=1)
    parallel = _run(tmp_path / "b", threads=4)
    expected = {"stack-stair": [0, 4, 6], "stack-tower": [0, 4, 6]}
    assert _kept(tmp_path / "a") == _kept(tmp_path / "b") == expected
    assert serial.generated == parallel.generated == 6
    assert {(f["task"], f["seed"]) for f in serial.failures} == {("stack-stair", 2), ("stack-tower", 2)}
    for out in (tmp_path / "a", tmp_path / "b"):
        assert not list(out.rglob(".*.tmp"))  # extra successes past the quota were discarded
        manifest = json.loads((out / "train" / MANIFEST).read_text())
        assert manifest["episodes"] == 6 and manifest["failures"] == 2


def test_rerun_does_nothing_and_extends_on_demand(tmp_path):
    _run(tmp_path, episodes=2)
    again = _run(tmp_path, episodes=2)
    assert (again.generated, again.skipped, again.failures) == (0, 4, [])
    more = _run(tmp_path, episodes=4, threads=3)
    assert more.skipped == 4 and more.generated == 4
    assert _kept(tmp_path)["stack-stair"] == [0, 4, 6, 12]  # 8 and 10 are known failures
    lines = (tmp_path / "train" / FAILURES).read_text().splitlines()
    assert len(lines) == len(set(lines)) == 6  # failures are never retried, so never logged twice


def test_interrupted_run_leaves_only_whole_episodes(tmp_path):
    _run(tmp_path, episodes=1)
    folder = tmp_path / "train" / "stack-stair"
    stale = folder / ".000004.h5.999.tmp"
    stale.write_bytes(b"half an episode")
    (tmp_path / "train" / MANIFEST).unlink()
    report = _run(tmp_path, episodes=2)
    assert not stale.exists()
    assert report.generated == 2 and _kept(tmp_path)["stack-stair"] == [0, 4]


def test_known_failures_are_skipped(tmp_path):
    folder = tmp_path / "train"
    folder.mkdir(parents=True)
    (folder / FAILURES).write_text(json.dumps({"task": "stack-stair", "seed": 0, "reason": "x"}) + "\n")
    _run(tmp_path, episodes=1, tasks=("stack-stair",))
    assert _kept(tmp_path) == {"stack-stair": [4]}
    assert ("stack-stair", 0) in read_failures(folder)


def test_too_few_successes_are_reported(tmp_path):
    report = _run(tmp_path, episodes=1, tasks=("stack-stair",), max_tries=1)
    assert not report.short
    global FAILING
    saved, FAILING = FAILING, set(range(0, 100, 2))
    try:
        report = _run(tmp_path / "x", episodes=2, tasks=("stack-stair",), max_tries=1)
    finally:
        FAILING = saved
    assert report.short == {"stack-stair": 0} and len(report.failures) == 7  # max(1 * 2, 2 + 5) seeds


# --------------------------------------------------------------------------- real episodes (fixture)
def test_real_train_episodes(real_root):
    ds = open_dataset(real_root / "train")
    assert ds.split == "train" and ds.tasks == ["stack-stair"] and len(ds) == 2
    task = get_task("stack-stair")
    for info in ds.infos():
        ep = read_episode(info.path)
        assert ep.success and ep.progress[-1] == 1.0 and ep.seed % 2 == 0
        assert ep.n_steps <= task.n_blocks + 2 and ep.n_random <= 2
        assert np.all(ep.pick[:, 3] == 0)
        assert ep.attrs["observation"]["cameras"] and ep.attrs["n_blocks"] == task.n_blocks
        assert ep.blocks.shape == (ep.n_steps + 1, task.n_blocks, 4)
        assert ep.height.max() > 0.03  # blocks are visible in the height map
    assert (real_root / "train" / MANIFEST).is_file()


def test_real_rerun_generates_nothing(real_root):
    report = generate(GenerationPlan(("stack-stair",), "train", 2, real_root), progress=False)
    assert report.generated == 0 and report.skipped == 2


def _same_episode(a, b) -> bool:
    """Every field of two episodes (arrays, attributes) is equal; only the file path may differ."""
    for f in dataclasses.fields(a):
        x, y = getattr(a, f.name), getattr(b, f.name)
        if f.name != "path" and not (np.array_equal(x, y) if isinstance(x, np.ndarray) else x == y):
            return False
    return True


def test_real_two_workers_match_one_worker(real_root, tmp_path):
    """In the default run (kept small): the two stack-stair episodes of ``real_root`` (made in this
    process) made again by two worker processes."""
    generate(GenerationPlan(("stack-stair",), "train", 2, tmp_path), workers=2, progress=False)
    one, two = open_dataset(real_root / "train"), open_dataset(tmp_path / "train")
    assert len(one) == len(two) == 2
    for a, b in zip(one.infos(), two.infos(), strict=True):
        assert (a.task, a.seed) == (b.task, b.seed)
        assert _same_episode(read_episode(a.path), read_episode(b.path))


# --------------------------------------------------------------------------- near misses (--near-misses)
def test_step_kinds_put_near_misses_before_oracle_steps():
    task = get_task("stack-palace")
    plain = step_kinds(task, "train", 4)
    assert plain == ["random" if r else "oracle" for r in action_schedule(task, "train", 4)]
    kinds = step_kinds(task, "train", 4, near_misses=3)
    assert kinds == step_kinds(task, "train", 4, near_misses=3)  # from the seed only
    assert kinds.count("near") == 3 and kinds.count("random") == 2
    assert all(kinds[i + 1] == "oracle" for i, k in enumerate(kinds) if k == "near")
    assert [k for k in kinds if k != "near"] == plain + ["oracle"] * 6  # two repairs per near miss
    with pytest.raises(DataError, match="train-split"):
        step_kinds(task, "test", 5, near_misses=1)


def test_near_miss_moves_only_the_place_and_by_at_most_its_bounds():
    rng = np.random.default_rng(0)
    action = np.array([[0.4, 0.0, 0.04, 0.0], [0.5, 0.1, 0.04, 0.3]])
    offsets, turns = [], []
    for _ in range(500):
        moved = near_miss(action, rng)
        assert np.array_equal(moved[0], action[0]) and moved[1, 2] == action[1, 2]
        offsets.append(np.hypot(*(moved[1, :2] - action[1, :2])))
        turns.append(abs(moved[1, 3] - action[1, 3]))
    assert max(offsets) <= NEAR_MISS_OFFSET + 1e-12 and max(turns) <= NEAR_MISS_TURN + 1e-12
    assert np.median(offsets) > NEAR_MISS_OFFSET / 2  # uniform over the disc, not bunched at the centre
    edge = near_miss(np.array([[0.4, 0.0, 0.04, 0.0], [0.745, -0.245, 0.04, 0.0]]), rng)
    assert edge[1, 0] <= WORKSPACE.x_max - BLOCK_SIZE and edge[1, 1] >= WORKSPACE.y_min + BLOCK_SIZE


def test_a_near_miss_folder_refuses_other_settings(tmp_path):
    folder = tmp_path / "train"
    folder.mkdir()
    check_near_misses(folder, 2)
    check_near_misses(folder, 2)  # resuming with the same number
    with pytest.raises(DataError, match="--near-misses 2"):
        check_near_misses(folder, 0)
    with pytest.raises(DataError, match="0 or more"):
        check_near_misses(tmp_path, -1)


def test_real_near_miss_episode():
    """A real episode with two near misses: each is a random step before an expert step, the place moved
    a little off the expert's next place, and the structure still finished (this seed did not before the
    expert repaired the near-missed block first: it sat on its own target's spot)."""
    task = get_task("stack-stair")
    ep, out = collect_episode(task, "train", 0, near_misses=2)
    assert out.ok, out.reason
    near = ep.attrs["near_misses"]
    assert len(near) == 2 and all(ep.random[i] and not ep.random[i + 1] for i in near)
    assert ep.n_random == 4 and ep.progress[-1] == 1.0
    plain, _ = collect_episode(task, "train", 0)
    assert "near_misses" not in plain.attrs and plain.n_random == 2
