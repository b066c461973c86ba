"""Commands about demonstration data: generate it (`tvf demos`), inspect it (`tvf data info|show`)."""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import tyro

from tvf.cli.common import at_least_one, check_output_dir
from tvf.errors import TvfError


@dataclass(frozen=True)
class DemosCmd:
    """Generate expert demonstrations into OUT/SPLIT/TASK/SEED.h5 (format: docs/data.md); re-run to resume.

    Only successful episodes are kept: the first EPISODES successes by seed, whatever --workers is.
    """

    tasks: str = "train"
    """train | unseen | all, or task names separated by commas."""
    split: str = "train"
    """train: the oracle with two random actions mixed in (data for the visual foresight), even seeds;
    test: the pure oracle, odd seeds. Failed seeds are listed in OUT/SPLIT/failures.jsonl."""
    episodes: int = 10
    """Successful episodes wanted per task."""
    out: Path = Path("data/demos")
    """Dataset root; this split goes to OUT/SPLIT."""
    workers: int = 1
    """Parallel processes (one PyBullet client each); with --backend ray, Ray tasks at once."""
    backend: Literal["local", "ray"] = "local"
    """Where the episodes run: local (a process pool on this host) | ray (Ray tasks on a local Ray
    instance of --workers CPUs, or on the cluster at --address; pip install 'tvf[ray]'; docs/parallel.md).
    The results are the same bytes either way."""
    address: str | None = None
    """With --backend ray: the running Ray cluster to use, HOST:6379 (default: start a local instance)."""
    first_seed: int = 0
    """Seeds start here (the first even one for train, the first odd one for test)."""
    max_tries: int = 3
    """Give up on a task after this many times EPISODES seeds (at least EPISODES + 5)."""
    task_file: Path | None = None
    """A YAML or JSON file of extra tasks (docs/tasks.md) that --tasks may name."""
    sensor: str = "ideal"
    """Record the images through these cameras (tvf.sim.sensors; docs/real-robot.md), e.g. d415-one:
    training data for a planner that must work under noise. One sensor per split folder."""
    near_misses: int = 0
    """Train split: before this many of each episode's expert steps, a *near miss*: the expert's action
    with its place moved by up to 8 pixels and turned by up to 10 degrees, executed and stored as a
    random step (the GCTN skips it), then up to two expert steps per near miss to repair it. Data for
    a foresight that must tell which of the GCTN's near-duplicate places land, slide or topple
    (docs/data.md); use its own --out. 0: the reference's episodes."""
    moves: str | None = None
    """Record a searching method's own moves instead of the expert's (foresight data, not
    demonstrations): every step executes one of the method's K root proposals, drawn uniformly from the
    episode's seed, for 2 steps per block or until the structure is finished; kept whether or not it
    is. E.g. --moves tvf-large-no-image-rules; train the VF on them with `tvf train vf --extra-data`
    (docs/data.md, "The planner's own moves"). Use its own --out; seeds of the demonstration range."""

    def run(self) -> None:
        from tvf.data.format import SPLITS
        from tvf.data.generation import GenerationPlan, generate
        from tvf.sim.sensors import get_sensor
        from tvf.tasks import load_tasks

        get_sensor(self.sensor)

        table = load_tasks(self.task_file)
        if self.split not in SPLITS:
            raise TvfError(f"--split must be one of {', '.join(SPLITS)}, got {self.split!r}")
        at_least_one(episodes=self.episodes, workers=self.workers, max_tries=self.max_tries)
        tasks = tuple(t.name for t in table.resolve(self.tasks))
        mover = None
        if self.moves is not None:
            from tvf.policies.explore import check_moves_method, proposal_mover

            check_moves_method(self.moves)
            mover = proposal_mover
        plan = GenerationPlan(tasks, self.split, self.episodes, self.out, self.first_seed, self.max_tries,
                              self.sensor, self.near_misses, self.moves)  # fmt: skip
        check_output_dir(self.out / self.split)
        report = generate(plan, self.workers, progress=True, tasks=table, backend=self.backend,
                          address=self.address, mover=mover)  # fmt: skip
        print(
            f"{plan.folder}: {report.generated} episodes written, {report.skipped} already there, "
            f"{len(report.failures)} failed seeds; {report.seconds:.0f} s"
        )
        if report.short:
            short = ", ".join(f"{t} ({n}/{self.episodes})" for t, n in report.short.items())
            print(f"tvf: warning: too few successful episodes after all seeds: {short}", file=sys.stderr)
            raise SystemExit(1)


def _human(n: float) -> str:
    for unit in ("B", "KB", "MB", "GB"):
        if n < 1000 or unit == "GB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return str(n)


@dataclass(frozen=True)
class DataInfo:
    """Summarise a dataset: episodes, transitions and size on disk per task.

    DIR is a split folder (OUT/train) or a root holding train/ and test/ (both are listed).
    """

    dir: tyro.conf.Positional[Path]
    """Dataset folder."""
    verify: bool = False
    """Also read every file in full and check every array and attribute against its SHA-256 (and the
    manifest's record); every damaged file is named, and the command fails if there is one."""
    json: bool = False
    """Print JSON instead of a table."""

    def run(self) -> None:
        import json

        from tvf.data.dataset import scan, split_dirs, verify

        docs, failures, unverified = [], {}, 0
        for folder in split_dirs(self.dir):
            if self.verify:
                check = verify(folder)
                ds, unverified = check.dataset, unverified + check.unverified
                failures.update(check.failures)
            else:
                ds = scan(folder)
            docs.append({"dir": str(folder), **ds.summary()})
        if self.json:
            print(json.dumps(docs, indent=1))
        else:
            self._print(docs)
        if self.verify:
            _verdict(failures, unverified, self.json)

    def _print(self, docs: list[dict]) -> None:
        for doc in docs:
            print(f"{doc['dir']}  (split {doc['split']})")
            print(f"  {'task':<20} {'episodes':>8} {'transitions':>11} {'random':>6} {'size':>10}")
            for task, row in doc["tasks"].items():
                print(
                    f"  {task:<20} {row['episodes']:>8} {row['transitions']:>11} "
                    f"{row['random_transitions']:>6} {_human(row['bytes']):>10}"
                )
            print(
                f"  {'all':<20} {doc['episodes']:>8} {doc['transitions']:>11} {'':>6} "
                f"{_human(doc['bytes']):>10}  ({_human(doc['bytes_per_transition'])} per transition)"
            )


def _verdict(failures: dict[Path, str], unverified: int, quiet: bool) -> None:
    """Name every damaged file (stdout) and fail with one line; else say what was checked. (Format 1
    files were announced when read: one warning per folder.)"""
    if failures:
        if not quiet:
            for message in failures.values():
                print(f"  damaged: {message}")
        names = ", ".join(str(p) for p in list(failures)[:5]) + (", ..." if len(failures) > 5 else "")
        raise TvfError(
            f"{len(failures)} damaged episode files: {names}; delete them and re-run `tvf demos` "
            "with the same flags to regenerate them"
        )
    if not quiet:
        legacy = f" ({unverified} of format version 1, without checksums, read unverified)" * bool(unverified)
        print(f"  verified: every file matches its checksums{legacy}")


@dataclass(frozen=True)
class DataShow:
    """Render one episode: colour and height side by side per frame, picks (x) and places (o, with a
    tick for the block's turn) drawn; oracle steps green/blue, random steps orange/magenta."""

    file: tyro.conf.Positional[Path]
    """An episode file (OUT/SPLIT/TASK/SEED.h5)."""
    out: Path
    """Picture to write: .gif (one frame per step) or .png (all frames stacked)."""
    fps: float = 1.0
    """GIF frames per second."""

    def run(self) -> None:
        from tvf.data.format import read_episode
        from tvf.viz.episode import save_episode_view

        if self.out.suffix.lower() not in (".gif", ".png"):
            raise TvfError(f"--out must end in .gif or .png, got {self.out}")
        episode = read_episode(self.file)
        check_output_dir(self.out.parent if str(self.out.parent) else Path("."))
        save_episode_view(episode, self.out, self.fps)
        print(f"wrote {self.out} ({episode.task} seed {episode.seed}, {episode.n_steps} steps)")


@dataclass(frozen=True)
class DataCmd:
    """Inspect demonstration datasets: `tvf data info DIR`, `tvf data show FILE --out X.gif`."""

    command: tyro.conf.OmitArgPrefixes[
        Annotated[DataInfo, tyro.conf.subcommand("info")] | Annotated[DataShow, tyro.conf.subcommand("show")]
    ]
    """What to do with the dataset."""

    def run(self) -> None:
        self.command.run()
