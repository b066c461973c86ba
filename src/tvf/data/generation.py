"""Demonstration generation: parallel, resumable, deterministic whatever the number of workers.

Seeds: the train split uses the even seeds, the test split the odd seeds, from ``first_seed`` up.
For each task the seeds are tried in order and the episodes kept are the first ``episodes``
successes *by seed order*: a worker writes its episode to a hidden temporary file, and the parent
renames it into place only once every smaller seed of that task is settled. Successes past the
quota are discarded, so the kept set never depends on timing or on ``workers``.

A train-split episode runs ``n_blocks + 2`` steps, two of them random (``random_schedule`` from the
fourth stream of ``SeedSequence(seed)``, independent of the environment's three); a test-split
episode runs ``n_blocks`` oracle steps. Each episode gets a fresh simulator, so it depends on its
seed only. With the Ray backend (``backend="ray"``, maybe on a cluster without a shared disk) a worker
sends its episode's file bytes back instead, and the parent writes the temporary file itself; the files
are the same bytes. Failures go to ``failures.jsonl``; a re-run skips complete episodes and known failures,
and removes temporary files that an interrupted run left behind. A full disk stops the run with one
:class:`~tvf.errors.DiskFullError` saying how many episodes are kept; no temporary file stays.
"""

from __future__ import annotations

import json
import os
import shutil
import time
from collections import deque
from collections.abc import Callable, Sequence
from concurrent.futures import FIRST_COMPLETED, Future, wait
from dataclasses import asdict, dataclass, field
from functools import partial
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from tqdm import tqdm

from tvf.data.dataset import FAILURES, MOVES_FILE, episode_files, moves_of, scan, write_manifest
from tvf.data.format import SPLITS, DataError, Episode, episode_name, h5_bytes, read_info, write_h5
from tvf.errors import DiskFullError, TvfError
from tvf.io import (
    TMP_SUFFIX,
    append_jsonl,
    as_disk_full,
    atomic_write_json,
    commit,
    raise_if_disk_full,
    read_jsonl,
    temp_path,
)
from tvf.parallel import check_backend, make_pool, sigterm_raises
from tvf.sim.env import EnvConfig, TvfEnv
from tvf.sim.oracle import near_miss, random_schedule
from tvf.sim.sensors import get_sensor
from tvf.tasks import BUILTIN, Task, TaskTable

N_RANDOM = 2
"""Random actions per train-split episode (facts §4)."""
LOCK = ".tvf-demos.lock"
SENSOR_FILE = "sensor.json"
"""Names the sensor of a split folder recorded through one other than ``ideal`` (tvf.sim.sensors)."""
NEAR_MISS_FILE = "near-misses.json"
"""Names the near misses per episode of a split folder made with ``--near-misses`` (:func:`step_kinds`)."""
MOVES_PER_TARGET = 2
"""Steps of a ``--moves`` episode per target block: one to place it, one to repair a wrong move."""


class Mover(Protocol):
    """What executes a ``--moves`` episode's steps (:class:`tvf.policies.explore.ProposalExplorer`)."""

    def act(self, obs: dict, goal: dict) -> np.ndarray | None: ...


MoverFactory = Callable[[str, int], Mover]
"""Builds the mover of (method, episode seed), in the worker process: the layer above supplies it
(:func:`tvf.policies.explore.proposal_mover`), so this module reads no model itself."""


# ------------------------------------------------------------------------------------ one episode
def split_seeds(split: str, first_seed: int, count: int) -> list[int]:
    """The first ``count`` seeds of ``split`` at or above ``first_seed``: even for train, odd for test."""
    if split not in SPLITS:
        raise DataError(f"split {split!r} is not one of {', '.join(SPLITS)}")
    parity = 0 if split == "train" else 1
    start = first_seed + ((parity - first_seed) % 2)
    return [start + 2 * i for i in range(count)]


def action_schedule(task, split: str, seed: int) -> list[bool]:
    """Which steps of the episode are random: train = ``n_blocks + 2`` steps with two random ones."""
    if split == "test":
        return [False] * task.n_blocks
    rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(4)[3])
    return random_schedule(task.n_blocks + N_RANDOM, N_RANDOM, rng)


def step_kinds(task, split: str, seed: int, near_misses: int = 0) -> list[str]:
    """The episode's steps in order: "oracle", "random" (:func:`action_schedule`) and, with
    ``near_misses``, that many "near" steps, each just before one of the oracle steps (drawn from the fifth
    stream of ``SeedSequence(seed)``), then two "oracle" steps per near miss to repair what it upset.
    Without near misses the episode is the plain one, bit for bit."""
    schedule = action_schedule(task, split, seed)
    kinds = ["random" if r else "oracle" for r in schedule]
    if not near_misses:
        return kinds
    if split != "train":
        raise DataError("--near-misses makes train-split data (for the foresight); drop it for --split test")
    oracle_steps = [i for i, r in enumerate(schedule) if not r]
    rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(5)[4])
    before = set(rng.choice(oracle_steps, size=min(near_misses, len(oracle_steps)), replace=False).tolist())
    out = [k for i, kind in enumerate(kinds) for k in (["near", kind] if i in before else [kind])]
    return out + ["oracle"] * (2 * near_misses)


def moves_budget(task) -> int:
    """The steps of a ``--moves`` episode: :data:`MOVES_PER_TARGET` per target block (it ends early when
    the structure is finished)."""
    return MOVES_PER_TARGET * task.n_blocks


def near_miss_rng(seed: int) -> np.random.Generator:
    """The stream that moves the near misses' places (the sixth of ``SeedSequence(seed)``)."""
    return np.random.default_rng(np.random.SeedSequence(seed).spawn(6)[5])


def _new_env(task: Task | str, split: str, sensor: str = "ideal", near_misses: int = 0, moves: bool = False):
    """A fresh environment (its own PyBullet client) for one episode; train allows the two extra steps
    (and three per near miss: itself and two repairs; ``moves``: :func:`moves_budget` steps).

    Fresh, not cached, so an episode cannot depend on what its worker ran before. (A simulator that
    only removed the last scene's bodies left 0.1 mm traces; ``World.clear`` now resets the simulation
    fully and a reused environment is bit-identical too, but a fresh one costs only about 0.1 s.)
    """
    slack = N_RANDOM + 3 * near_misses if split == "train" else 0
    if moves:
        resolved = task if isinstance(task, Task) else BUILTIN.get(task)
        slack = moves_budget(resolved) - resolved.horizon
    return TvfEnv(task, EnvConfig(step_slack=slack), sensor=sensor)


def _config_attrs(env) -> dict[str, Any]:
    obs = env.config.sim.observation
    rigs = (env.sensor.cameras, env.sensor.goal_rig)
    plain = env.sensor.ideal and rigs == ("three", "three") and env.sensor.hole_fill == "nearest"
    sensor = {} if plain else {"sensor": asdict(env.sensor)}
    return {
        **sensor,
        "observation": {**asdict(obs), "cameras": [asdict(c) for c in obs.cameras()]},
        "sim": {
            "hz": env.config.sim.hz,
            "solver_iterations": env.config.sim.solver_iterations,
            "settle_steps": env.config.sim.settle_steps,
        },
    }


@dataclass
class Outcome:
    """What a worker reports for one (task, seed)."""

    task: str
    seed: int
    ok: bool
    reason: str = ""
    steps: int = 0
    progress: float = 0.0
    tmp: str | None = None
    primitives: list[str] = field(default_factory=list)
    data: bytes | None = None
    """The episode's file, when the worker was given no folder (the parent writes it)."""


def _state(env) -> tuple[np.ndarray, float]:
    pos, yaw = env.world.block_poses()
    return np.concatenate([pos, yaw[:, None]], axis=1).astype(np.float32), float(env.progress().fraction)


def collect_episode(
    task: Task | str, split: str, seed: int, sensor: str = "ideal", near_misses: int = 0,
    moves: str | None = None, mover: MoverFactory | None = None,
) -> tuple[Episode | None, Outcome]:  # fmt: skip
    """Run one episode in this process, its images seen through ``sensor`` (tvf.sim.sensors; the oracle
    acts on true poses), with ``near_misses`` of the expert's places moved a little off
    (:func:`step_kinds`), or, with ``moves``, every step that method's own move (``mover(moves, seed)``
    acts; :func:`moves_budget` steps); returns (episode, outcome) with episode None on failure."""
    if moves is not None and mover is None:
        raise TvfError("an episode of a method's own moves needs its mover (tvf.policies.explore)")
    env = _new_env(task, split, sensor, near_misses, moves is not None)
    try:
        if moves is not None:
            return _run_episode(env, split, seed, moves=moves, mover=mover(moves, seed))
        return _run_episode(env, split, seed, near_misses)
    finally:
        env.close()


def _next_action(env, kind: str, jitter: np.random.Generator, missed: int | None, mover: Mover | None,
                 obs: dict, goal: dict) -> np.ndarray | None:  # fmt: skip
    """The step's action; ``missed``: the block a near miss just moved, which the expert repairs first."""
    if kind == "moves":
        return mover.act(obs, goal)
    if kind == "random":
        return env.random_action()
    action = env.oracle_action(first=missed)
    return near_miss(action, jitter) if kind == "near" and action is not None else action


def _moved_block(before: np.ndarray, after: np.ndarray) -> int:
    """The block that moved farthest between two (n, 4) pose arrays: the one a step carried."""
    return int(np.argmax(np.linalg.norm(after[:, :3] - before[:, :3], axis=1)))


def _run_episode(env, split: str, seed: int, near_misses: int = 0, moves: str | None = None,
                 mover: Mover | None = None) -> tuple[Episode | None, Outcome]:  # fmt: skip
    """One episode in ``env``: the expert's (with its random steps and near misses), or with ``mover``
    every step the own move of the method ``moves``, kept whether or not it finishes the structure."""
    task = env.task.name
    out = Outcome(task, seed, False)
    try:
        obs, info = env.reset(seed=seed)
        goal = info["goal"]
    except TvfError as exc:
        out.reason = f"reset failed: {exc}"
        return None, out
    colors, heights, picks, places, randoms = [obs["color"]], [obs["height"]], [], [], []
    blocks, progress = [], []
    b, p = _state(env)
    blocks.append(b)
    progress.append(p)
    kinds = ["moves"] * moves_budget(env.task) if moves else step_kinds(env.task, split, seed, near_misses)
    jitter = near_miss_rng(seed)
    missed = None
    for step, kind in enumerate(kinds):
        action = _next_action(env, kind, jitter, missed, mover, obs, goal)
        if action is None:
            whys = {"random": "random action found no free pose", "moves": "the method had no action"}
            why = whys.get(kind, "oracle had no action")
            out.reason = f"{why} at step {step}"
            break
        obs, _, terminated, _, info = env.step(action)
        colors.append(obs["color"])
        heights.append(obs["height"])
        picks.append(action[0])
        places.append(action[1])
        randoms.append(kind != "oracle")
        out.primitives.append(str(info["primitive"]))
        b, p = _state(env)
        missed = _moved_block(blocks[-1], b) if kind == "near" else None
        blocks.append(b)
        progress.append(p)
        if terminated:
            break
    out.steps = len(picks)
    out.progress = progress[-1]
    success = bool(env.progress().success)
    if not success and not (moves and out.steps):
        out.reason = out.reason or f"structure not finished after {out.steps} steps"
        return None, out
    out.ok = True
    tpos, tyaw = env.world.target_poses()
    near_steps = [i for i, kind in enumerate(kinds[: len(picks)]) if kind == "near"]
    near = {"near_misses": near_steps} if near_misses else {}
    near |= {"moves": moves} if moves else {}
    episode = Episode(
        task=env.task.name,
        seed=seed,
        split=split,
        color=np.stack(colors).astype(np.uint8),
        height=np.stack(heights).astype(np.float32),
        pick=np.asarray(picks, np.float32),
        place=np.asarray(places, np.float32),
        random=np.asarray(randoms, bool),
        progress=np.asarray(progress, np.float32),
        blocks=np.stack(blocks),
        targets=np.concatenate([tpos, tyaw[:, None]], axis=1).astype(np.float32),
        success=success,
        attrs={"n_blocks": env.task.n_blocks, "primitives": out.primitives, **_config_attrs(env), **near},
    )
    return episode, out


def episode_job(
    task: Task, split: str, seed: int, folder: str | None, sensor: str = "ideal", near_misses: int = 0,
    moves: str | None = None, mover: MoverFactory | None = None,
) -> Outcome:  # fmt: skip
    """Worker entry point: run one episode and, if it succeeded, write it to a temporary file that the
    parent renames into place once every smaller seed of the task is settled (``folder`` None: return the
    file's bytes in ``Outcome.data`` for the parent to write)."""
    own_moves = {"moves": moves, "mover": mover} if moves is not None else {}
    episode, out = collect_episode(task, split, seed, sensor, near_misses, **own_moves)
    if episode is not None and folder is None:
        out.data = h5_bytes(episode)
    elif episode is not None:
        final = Path(folder) / task.name / episode_name(seed)
        final.parent.mkdir(parents=True, exist_ok=True)
        tmp = temp_path(final)
        try:
            write_h5(tmp, episode)
        except BaseException as exc:
            tmp.unlink(missing_ok=True)
            raise_if_disk_full(exc, final)
            raise
        out.tmp = str(tmp)
    return out


# ------------------------------------------------------------------------------------ a whole dataset
@dataclass(frozen=True)
class GenerationPlan:
    """What to generate: ``episodes`` successes for each task in one split, under ``out/split``."""

    tasks: tuple[str, ...]
    split: str
    episodes: int
    out: Path
    first_seed: int = 0
    max_tries: int = 3
    """Seeds tried per task, as a multiple of ``episodes`` (at least ``episodes + 5``)."""
    sensor: str = "ideal"
    """The cameras the images are recorded through (a name of tvf.sim.sensors.SENSORS)."""
    near_misses: int = 0
    """Train split: this many of each episode's expert places moved a little off (:func:`step_kinds`)."""
    moves: str | None = None
    """A searching method whose own moves every step executes instead of the expert's (foresight data,
    not demonstrations; :mod:`tvf.policies.explore`)."""

    def __post_init__(self) -> None:
        if self.near_misses < 0 or (self.near_misses and self.split != "train"):
            raise DataError(f"--near-misses {self.near_misses}: give 0 or more, with --split train "
                            "(foresight data; the test split is the pure expert)")  # fmt: skip
        if self.moves is not None and self.near_misses:
            raise DataError("--moves replaces every expert step; drop --near-misses")

    @property
    def folder(self) -> Path:
        return self.out / self.split

    def seeds(self) -> list[int]:
        count = max(self.max_tries * self.episodes, self.episodes + 5)
        return split_seeds(self.split, self.first_seed, count)


@dataclass
class GenerationReport:
    folder: Path
    generated: int = 0
    """Episodes written by this run."""
    skipped: int = 0
    """Episodes already on disk."""
    failures: list[dict] = field(default_factory=list)
    """Failures found by this run."""
    short: dict[str, int] = field(default_factory=dict)
    """Tasks with fewer than the requested episodes after all their seeds: task -> episodes found."""
    seconds: float = 0.0


@dataclass
class _TaskState:
    name: str
    seeds: list[int]
    want: int
    status: dict[int, str]  # seed -> "ok" | "fail" | "done" (finished, not yet committed)
    kept: int = 0
    cursor: int = 0  # index of the first seed not yet settled
    pending: deque = field(default_factory=deque)  # seeds not yet submitted
    in_flight: int = 0
    tmp: dict[int, str] = field(default_factory=dict)

    @property
    def finished(self) -> bool:
        return self.kept >= self.want or self.cursor >= len(self.seeds)


class _Lock:
    """One generator per dataset folder: a lock file holding the owner's pid."""

    def __init__(self, folder: Path) -> None:
        self.path = folder / LOCK

    def __enter__(self) -> _Lock:
        try:
            fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        except FileExistsError:
            pid = self.path.read_text().strip()
            if pid.isdigit() and _alive(int(pid)):
                raise DataError(
                    f"{self.path.parent}: another `tvf demos` (pid {pid}) is writing here"
                ) from None
            self.path.unlink(missing_ok=True)
            fd = os.open(self.path, os.O_CREAT | os.O_EXCL | os.O_WRONLY)
        try:
            with os.fdopen(fd, "w") as f:
                f.write(str(os.getpid()))
        except BaseException as exc:
            self.path.unlink(missing_ok=True)
            raise_if_disk_full(exc, self.path)
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.path.unlink(missing_ok=True)


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_stale_tmp(folder: Path) -> int:
    """Delete temporary episode files left by an interrupted run; returns how many."""
    stale = list(folder.glob(f"*/.*{TMP_SUFFIX}"))
    for p in stale:
        p.unlink(missing_ok=True)
    return len(stale)


def read_failures(folder: Path) -> dict[tuple[str, int], dict]:
    """Known failures ``(task, seed) -> record`` from ``failures.jsonl`` (a torn last line, as a kill or a
    full disk may leave, and records without a task and seed are ignored: their seeds are run again)."""
    known: dict[tuple[str, int], dict] = {}
    for rec in read_jsonl(folder / FAILURES):
        try:
            known[(str(rec["task"]), int(rec["seed"]))] = rec
        except (KeyError, TypeError, ValueError):
            continue
    return known


def _initial_states(plan: GenerationPlan, report: GenerationReport) -> list[_TaskState]:
    known_fail = read_failures(plan.folder)
    states = []
    for task in plan.tasks:
        status: dict[int, str] = {}
        seeds = plan.seeds()
        for seed in seeds:
            path = plan.folder / task / episode_name(seed)
            if path.is_file():
                info = read_info(path)  # a damaged file stops the run with its name; it is never deleted
                if (info.task, info.seed, info.split) != (task, seed, plan.split):
                    raise DataError(
                        f"{path}: holds {info.task} seed {info.seed} ({info.split}), not {task} {seed}"
                    )
                status[seed] = "ok"
            elif (task, seed) in known_fail:
                status[seed] = "fail"
        st = _TaskState(task, seeds, plan.episodes, status)
        _advance(st, plan, report)
        report.skipped += st.kept
        st.pending = deque(s for s in seeds[st.cursor :] if s not in status)
        states.append(st)
    return states


def _advance(st: _TaskState, plan: GenerationPlan, report: GenerationReport) -> int:
    """Settle seeds in order as far as outcomes are known; returns episodes committed now."""
    committed = 0
    while st.cursor < len(st.seeds) and st.kept < st.want:
        seed = st.seeds[st.cursor]
        state = st.status.get(seed)
        if state is None:
            break
        if state == "done":  # finished by a worker in this run: move it into place
            commit(st.tmp.pop(seed), plan.folder / st.name / episode_name(seed))
            st.status[seed] = "ok"
            report.generated += 1
            committed += 1
        if st.status[seed] == "ok":
            st.kept += 1
        st.cursor += 1
    if st.kept >= st.want:
        for tmp in st.tmp.values():  # successes past the quota
            Path(tmp).unlink(missing_ok=True)
        st.tmp.clear()
        st.pending.clear()
    return committed


class _InlinePool:
    """The executor interface, running each job at once in this process (``workers=1``)."""

    def submit(self, fn: Callable, *args) -> Future:
        fut: Future = Future()
        try:
            fut.set_result(fn(*args))
        except BaseException as exc:  # noqa: BLE001 - handed to the caller through the future
            fut.set_exception(exc)
        return fut

    def shutdown(self, cancel_futures: bool = False) -> None:
        pass


def generate(
    plan: GenerationPlan,
    workers: int = 1,
    progress: bool = True,
    tasks: TaskTable | None = None,
    log: Callable[[str], None] | None = None,
    job: Callable[[Task, str, int, str | None], Outcome] | None = None,
    executor: Any = None,
    backend: str = "local",
    address: str | None = None,
    mover: MoverFactory | None = None,
) -> GenerationReport:
    """Generate (or complete) the dataset described by ``plan``; see the module docstring.

    ``tasks`` resolves the plan's task names (default: the built-in table; pass the one loaded with a
    user's task file). ``backend`` and ``address`` choose where the episodes run (:mod:`tvf.parallel`;
    ``workers`` episodes at once). ``job`` (default :func:`episode_job`) and ``executor`` (an object with
    ``submit``) exist for tests; an executor passed in is not shut down here. ``mover`` builds the
    movers of a plan with ``moves`` (:func:`tvf.policies.explore.proposal_mover`).
    """
    check_backend(backend, address)
    if plan.moves is not None and mover is None and job is None:
        raise TvfError("a plan of a method's own moves needs generate(..., mover=proposal_mover)")
    table = tasks or BUILTIN
    resolved = {name: table.get(name) for name in plan.tasks}
    folder = plan.folder
    folder.mkdir(parents=True, exist_ok=True)
    report = GenerationReport(folder)
    start = time.perf_counter()
    with _Lock(folder), sigterm_raises():
        check_sensor(folder, plan.sensor)
        check_near_misses(folder, plan.near_misses)
        check_moves(folder, plan.moves)
        if job is None and (plan.sensor != "ideal" or plan.near_misses or plan.moves):
            job = partial(episode_job, sensor=plan.sensor, near_misses=plan.near_misses, moves=plan.moves,
                          mover=mover)  # fmt: skip
        remove_stale_tmp(folder)
        states = _initial_states(plan, report)
        total = sum(min(s.want, len(s.seeds)) - s.kept for s in states)
        bar = tqdm(
            total=total, desc=f"demos {plan.split}", unit="ep", disable=not progress, dynamic_ncols=True
        )
        say = log or bar.write
        pool: Any
        if executor is not None:
            pool = executor
        elif workers <= 1 and backend == "local":
            pool = _InlinePool()
        else:
            pool = make_pool(workers, backend, address)
        futures: dict[Future, _TaskState] = {}
        window = max(1, workers if backend == "ray" else 2 * workers)  # Ray: at most workers at once
        target = None if backend == "ray" else str(plan.folder)  # Ray: the bytes come back here
        full: DiskFullError | None = None
        try:
            while True:
                _submit(states, futures, pool, plan, window, job or episode_job, resolved, target)
                if not futures:
                    break
                done, _ = wait(list(futures), return_when=FIRST_COMPLETED)
                for fut in [f for f in futures if f in done]:  # in submission order: one worker's
                    # failures.jsonl then has the same lines in the same order on every run
                    st = futures.pop(fut)
                    st.in_flight -= 1
                    out: Outcome = fut.result()
                    _record(st, out, plan, report, say)
                    bar.update(_advance(st, plan, report))
                    rate = 60 * bar.n / max(time.perf_counter() - start, 1e-9)
                    bar.set_postfix_str(f"{rate:.1f} ep/min, {len(report.failures)} failed", refresh=False)
        except Exception as exc:
            full = as_disk_full(exc, folder)
            if full is None:
                raise
        finally:
            if executor is None:
                pool.shutdown(cancel_futures=True)
            bar.close()
            remove_stale_tmp(folder)  # we hold the lock: every temporary file here is ours
            dataset = scan(folder, plan.split, use_manifest=False)
            try:
                write_manifest(dataset, failures=len(read_failures(folder)))
            except DiskFullError as exc:  # the files are the truth; the next run writes the manifest
                full = full or exc
        if full is not None:
            raise full.keeping(f"{len(dataset)} episodes kept in {folder}") from None
    report.short = {s.name: s.kept for s in states if s.kept < s.want}
    report.seconds = time.perf_counter() - start
    return report


def _hold_one_recipe(folder: Path, path: Path, recorded, wanted, refusal: str, record: dict | None) -> None:
    """Raise ``refusal`` when ``folder`` holds episodes (or a recipe file ``path``) made with ``recorded``,
    not ``wanted``; else write ``record`` (None: nothing) to ``path`` if the folder names no recipe yet."""
    if recorded != wanted and (path.exists() or episode_files(folder)):
        raise DataError(refusal)
    if record and not path.exists():
        atomic_write_json(path, record)


def check_sensor(folder: Path, sensor: str) -> None:
    """Refuse to add episodes of one sensor (or one hole filling) to a split folder of another; name a new
    folder's sensor."""
    fill = get_sensor(sensor).hole_fill
    record = _sensor_record(folder)
    recorded, recorded_fill = record["sensor"], record["hole_fill"]
    refusal = (f"{folder} holds demonstrations recorded through the {recorded!r} sensor; pass --sensor "
               f"{recorded} to resume it, or choose another --out for {sensor!r}")  # fmt: skip
    _hold_one_recipe(folder, folder / SENSOR_FILE, recorded, sensor, refusal, None)
    refusal = (f"{folder} holds {sensor!r} demonstrations whose holes were filled {recorded_fill!r} (an "
               f"older tvf); this version fills them {fill!r}: choose another --out, or delete the folder"
               )  # fmt: skip
    named = {"sensor": sensor} if fill == "nearest" else {"sensor": sensor, "hole_fill": fill}
    _hold_one_recipe(
        folder, folder / SENSOR_FILE, recorded_fill, fill, refusal, named if sensor != "ideal" else None
    )


def check_near_misses(folder: Path, near_misses: int) -> None:
    """Refuse to add episodes with another number of near misses to a split folder; name a new folder's."""
    if near_misses < 0:
        raise DataError(f"--near-misses must be 0 or more, not {near_misses}")
    path = folder / NEAR_MISS_FILE
    try:
        recorded = int(json.loads(path.read_text())["near_misses"]) if path.exists() else 0
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise DataError(
            f"{path}: unreadable ({exc!r}); it names the folder's near misses per episode"
        ) from None
    refusal = (f"{folder} holds demonstrations with {recorded} near misses each; pass --near-misses "
               f"{recorded} to resume it, or choose another --out")  # fmt: skip
    _hold_one_recipe(
        folder, path, recorded, near_misses, refusal, {"near_misses": near_misses} if near_misses else None
    )


def check_moves(folder: Path, moves: str | None) -> None:
    """Refuse to mix the expert's episodes and a method's own moves (or two methods') in a split folder;
    name a new folder's method."""
    recorded = moves_of(folder)
    held = f"the own moves of {recorded}" if recorded else "the expert's demonstrations"
    fix = f"pass --moves {recorded}" if recorded else "drop --moves"
    refusal = f"{folder} holds {held}; {fix} to resume it, or choose another --out"
    _hold_one_recipe(
        folder, folder / MOVES_FILE, recorded, moves, refusal, {"moves": moves} if moves else None
    )


def _sensor_record(folder: Path) -> dict[str, str]:
    """What a split folder was recorded through, from its ``sensor.json``: {"sensor", "hole_fill"};
    ``ideal`` without one, ``nearest`` when it names no filling (the older folders)."""
    path = Path(folder) / SENSOR_FILE
    if not path.exists():
        return {"sensor": "ideal", "hole_fill": "nearest"}
    try:
        doc = json.loads(path.read_text())
        return {"sensor": str(doc["sensor"]), "hole_fill": str(doc.get("hole_fill", "nearest"))}
    except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
        raise DataError(f"{path}: unreadable ({exc!r}); it names the sensor of the folder's demos") from None


def _submit(
    states: list[_TaskState], futures: dict, pool, plan: GenerationPlan, window: int, job, tasks: dict,
    folder: str | None,
) -> None:  # fmt: skip
    """Fill the pool, round-robin over tasks, never running more seeds of a task than it may still need."""
    progressed = True
    while len(futures) < window and progressed:
        progressed = False
        for st in states:
            if len(futures) >= window:
                break
            unsettled = sum(1 for s in st.seeds[st.cursor :] if st.status.get(s) == "done")
            if st.finished or not st.pending or st.kept + unsettled + st.in_flight >= st.want:
                continue
            seed = st.pending.popleft()
            futures[pool.submit(job, tasks[st.name], plan.split, seed, folder)] = st
            st.in_flight += 1
            progressed = True


def _record(st: _TaskState, out: Outcome, plan: GenerationPlan, report: GenerationReport, say) -> None:
    if out.ok:
        if st.kept >= st.want:  # the quota was filled by smaller seeds meanwhile
            if out.tmp:
                Path(out.tmp).unlink(missing_ok=True)
            return
        if out.tmp is None and out.data is not None:
            final = plan.folder / out.task / episode_name(out.seed)
            out.tmp, out.data = str(_write_tmp(final, out.data)), None
        st.status[out.seed] = "done"
        st.tmp[out.seed] = str(out.tmp)
        return
    st.status[out.seed] = "fail"
    rec = {
        "task": out.task,
        "seed": out.seed,
        "split": plan.split,
        "reason": out.reason,
        "steps": out.steps,
        "progress": round(out.progress, 3),
        "primitives": out.primitives,
    }
    append_jsonl(plan.folder / FAILURES, rec)
    report.failures.append(rec)
    say(f"failed: {out.task} seed {out.seed}: {out.reason}")


def _write_tmp(final: Path, data: bytes) -> Path:
    """Write an episode's bytes (from a Ray worker) to the temporary file that :func:`_advance` commits."""
    final.parent.mkdir(parents=True, exist_ok=True)
    tmp = temp_path(final)
    try:
        tmp.write_bytes(data)
    except BaseException as exc:
        tmp.unlink(missing_ok=True)
        raise_if_disk_full(exc, final)
        raise
    return tmp


# ------------------------------------------------------------------------------------ reusing another set
def reuse_episodes(source: Path, plan: GenerationPlan) -> int:
    """Start ``plan``'s folder from the episodes of ``source``, another folder of the same split made from
    the same first seed (another demo count): the episodes a run of ``plan`` would keep are hard-linked
    (copied where links fail), the failures it would meet are recorded; returns the episodes added.

    Generation keeps the first successes by seed order and an episode depends on its seed only, so such
    a folder holds a prefix of what ``plan`` keeps (a smaller count) or all of it (a larger one). Per task
    the plan's seeds are walked in order while ``source`` settles them (an episode, or a recorded failure),
    up to ``plan.episodes`` episodes; :func:`generate` then runs only the seeds that are left. Episode
    files are never changed after their rename, so two folders can share one safely.
    """
    source = Path(source)
    folder = plan.folder
    if not source.is_dir() or (folder.is_dir() and os.path.samefile(source, folder)):
        return 0
    have = {(e.task, e.seed) for e in scan(source, plan.split).infos()}
    failed = read_failures(source)
    folder.mkdir(parents=True, exist_ok=True)
    added = 0
    with _Lock(folder):
        known = read_failures(folder)
        for task in plan.tasks:
            kept = 0
            for seed in plan.seeds():
                if kept >= plan.episodes:
                    break
                if (task, seed) in have:
                    added += _share(source / task / episode_name(seed), folder / task / episode_name(seed))
                    kept += 1
                elif (task, seed) in failed:
                    if (task, seed) not in known:
                        append_jsonl(folder / FAILURES, failed[(task, seed)])
                else:
                    break
    return added


def _share(source: Path, target: Path) -> int:
    """Hard-link ``source`` at ``target`` (a copy, renamed into place, where links fail); 1 if added."""
    if target.exists():
        return 0
    target.parent.mkdir(parents=True, exist_ok=True)
    try:
        os.link(source, target)
    except FileExistsError:
        return 0
    except OSError:  # another file system, or one without links
        tmp = temp_path(target)
        try:
            shutil.copyfile(source, tmp)
            commit(tmp, target)
        except BaseException as exc:
            tmp.unlink(missing_ok=True)
            raise_if_disk_full(exc, target)
            raise
    return 1


def generate_tasks(
    tasks: Sequence[str],
    split: str,
    episodes: int,
    out: Path,
    workers: int = 1,
    first_seed: int = 0,
    max_tries: int = 3,
    progress: bool = True,
    table: TaskTable | None = None,
    backend: str = "local",
    address: str | None = None,
) -> GenerationReport:
    """Convenience wrapper: build the plan and run :func:`generate`."""
    plan = GenerationPlan(tuple(tasks), split, episodes, Path(out), first_seed, max_tries)
    return generate(plan, workers, progress, table, backend=backend, address=address)
