"""Tasks as data: every task is a base layout plus target cells and layers, read from one table.

The built-in table is ``tasks.yaml`` beside this file; ``load_task_file`` reads a user's YAML or JSON
file of the same schema (docs/tasks.md), so a new structure needs no code.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from functools import cache
from importlib import resources
from pathlib import Path

import numpy as np
import yaml

from tvf.errors import TvfError
from tvf.geometry import EDGE_MARGIN, REACH, WORKSPACE, Workspace

BLOCK_SIZE = 0.04
"""Edge of a block in metres."""
CELL_SIZE = 0.05
"""Edge of a base cell in metres."""
CELL_THICKNESS = 0.005
"""Thickness of a base cell in metres: the base top is this high above the table."""
BLOCK_SYMMETRY = math.pi / 2
"""Blocks look the same after a quarter turn."""
BLOCK_RADIUS = BLOCK_SIZE / math.sqrt(2)
"""Radius (m) of the circle around a block at any yaw."""
CELL_RADIUS = CELL_SIZE / math.sqrt(2)
"""Radius (m) of the circle around a base cell."""
SPLITS = ("train", "unseen")
PLACEMENT_YAWS = 72
"""Base yaws (every 5 degrees) tried when a task file is checked against the workspace and the reach."""
PLACEMENT_GRID = 11
"""Base positions per axis tried at each yaw (evenly over the positions the workspace allows)."""


class TaskError(TvfError):
    """An unknown task name or a malformed task file."""


@dataclass(frozen=True)
class BaseCell:
    x: float
    y: float
    colour: tuple[float, float, float]


@dataclass(frozen=True)
class Task:
    """One rearrangement task: a base and the targets the blocks must fill."""

    name: str
    split: str
    base_name: str
    cells: tuple[BaseCell, ...]
    targets: tuple[tuple[float, float, int], ...]
    """(x, y, layer) in the base frame, one per block."""
    orders: tuple[tuple[tuple[int, ...], ...], ...]
    """Alternative oracle orders; each is a sequence of subgoal groups of target indices."""

    @property
    def n_blocks(self) -> int:
        return len(self.targets)

    @property
    def horizon(self) -> int:
        """Real pick-and-place steps allowed at test time (one per block, as in the paper)."""
        return self.n_blocks

    def target_offsets(self) -> np.ndarray:
        """Target block centres ``(n, 3)`` in the base frame (z above the table, base at rest)."""
        t = np.asarray(self.targets, dtype=np.float64)
        z = CELL_THICKNESS + BLOCK_SIZE / 2 + BLOCK_SIZE * t[:, 2]
        return np.stack([t[:, 0], t[:, 1], z], axis=1)

    def cell_offsets(self) -> np.ndarray:
        """Cell centres ``(m, 2)`` in the base frame."""
        return np.asarray([(c.x, c.y) for c in self.cells], dtype=np.float64)

    def footprint_radius(self) -> float:
        """Distance from the base origin to the farthest point of any cell (the true footprint)."""
        half = CELL_SIZE / 2
        corners = np.array([[-half, -half], [-half, half], [half, -half], [half, half]])
        pts = self.cell_offsets()[:, None, :] + corners[None]
        return float(np.linalg.norm(pts, axis=-1).max())

    def supports(self) -> list[list[int]]:
        """For each target, the targets one layer below that it rests on (its footprint overlaps)."""
        t = np.asarray(self.targets, dtype=np.float64)
        out: list[list[int]] = []
        for i, (x, y, k) in enumerate(t):
            below = [
                j
                for j, (xj, yj, kj) in enumerate(t)
                if kj == k - 1 and abs(xj - x) < BLOCK_SIZE and abs(yj - y) < BLOCK_SIZE
            ]
            if k > 0 and not below:
                raise TaskError(f"task {self.name!r}: target {i} on layer {int(k)} rests on nothing")
            out.append(below)
        return out

    def discs(self) -> tuple[np.ndarray, np.ndarray]:
        """The base cells and then the targets as circles in the base frame: centres (m, 2) and radii (m,)."""
        targets = self.target_offsets()[:, :2]
        centres = np.concatenate([self.cell_offsets(), targets])
        radii = np.concatenate([np.full(len(self.cells), CELL_RADIUS), np.full(len(targets), BLOCK_RADIUS)])
        return centres, radii

    def summary(self) -> dict:
        return {
            "name": self.name,
            "split": self.split,
            "blocks": self.n_blocks,
            "horizon": self.horizon,
            "base": self.base_name,
            "layers": int(max(t[2] for t in self.targets)) + 1,
        }


def placement_problem(
    centres: np.ndarray, radii: np.ndarray, ws: Workspace = WORKSPACE, margin: float = EDGE_MARGIN,
    reach: tuple[float, float] = REACH,
) -> str | None:  # fmt: skip
    """Why no base pose lays out the circles ``centres (m, 2)``, ``radii (m,)`` (base frame): ``"workspace"``
    (they never fit inside the workspace less ``margin``), ``"reach"`` (they fit, but never inside the
    ``reach`` ring around the world origin as well) or None (some pose fits).

    Poses are tried on a grid: every ``360 / PLACEMENT_YAWS`` degrees and, at each yaw, ``PLACEMENT_GRID``
    positions per axis over the range where the rotated circles stay inside the workspace.
    """
    yaws = np.linspace(-math.pi, math.pi, PLACEMENT_YAWS, endpoint=False)[:, None]
    x, y = centres[:, 0][None], centres[:, 1][None]
    px, py = np.cos(yaws) * x - np.sin(yaws) * y, np.sin(yaws) * x + np.cos(yaws) * y  # (yaws, m)
    lo = np.stack([ws.x_min + margin + (radii - px).max(1), ws.y_min + margin + (radii - py).max(1)], 1)
    hi = np.stack([ws.x_max - margin - (px + radii).max(1), ws.y_max - margin - (py + radii).max(1)], 1)
    fits = (lo <= hi).all(1)  # (yaws,): the base origin has room at this yaw
    if not fits.any():
        return "workspace"
    t = np.linspace(0.0, 1.0, PLACEMENT_GRID)
    for k in np.flatnonzero(fits):  # a feasible structure usually stops at the first yaw
        ox = lo[k, 0] + t * (hi[k, 0] - lo[k, 0])
        oy = lo[k, 1] + t * (hi[k, 1] - lo[k, 1])
        r = np.hypot(ox[:, None, None] + px[k], oy[None, :, None] + py[k])  # (grid, grid, m)
        if ((r - radii >= reach[0]) & (r + radii <= reach[1])).all(-1).any():
            return None
    return "reach"


def check_limits(task: Task, where: str, ws: Workspace = WORKSPACE) -> None:
    """Refuse a task the robot cannot build: a target above the height range, or a base with targets that
    no base pose keeps inside the workspace and the arm's reach. The error names the target."""
    z_range = ws.z_max - ws.z_min
    for i, (x, y, layer) in enumerate(task.targets):
        top = CELL_THICKNESS + BLOCK_SIZE * (layer + 1)
        if top > z_range:
            highest = int((z_range - CELL_THICKNESS) // BLOCK_SIZE) - 1
            raise TaskError(
                f"{where}: target {i} {[x, y, layer]} would reach {100 * top:.1f} cm, above the "
                f"{100 * z_range:.0f} cm height range of the workspace (layers 0-{highest} fit)"
            )
    centres, radii = task.discs()
    n_cells = len(task.cells)
    problem = placement_problem(centres[:n_cells], radii[:n_cells], ws)
    if problem is not None:
        message = _limit_message(problem, "its cells", "use a smaller base")
        raise TaskError(f"{where}: base {task.base_name!r} {message}")
    if placement_problem(centres, radii, ws) is None:
        return
    for i in range(len(task.targets)):  # name the first target that makes the structure impossible
        problem = placement_problem(centres[: n_cells + i + 1], radii[: n_cells + i + 1], ws)
        if problem is not None:
            x, y, layer = task.targets[i]
            what = "it, the base and the targets before it" if i else "it and the base"
            message = _limit_message(problem, what, "move it nearer the base cells")
            raise TaskError(f"{where}: target {i} {[x, y, layer]} {message}")


def _limit_message(problem: str, what: str, fix: str) -> str:
    """Why ``what`` (the base's cells, or a target with the base) cannot be laid out, and ``fix``."""
    ws = WORKSPACE
    if problem == "workspace":
        return (
            f"lies outside the workspace: no base pose keeps {what} {100 * EDGE_MARGIN:.0f} cm inside the "
            f"{ws.x_max - ws.x_min:.2f} x {ws.y_max - ws.y_min:.2f} m workspace; {fix}"
        )
    return (
        f"is out of the arm's reach: no base pose keeps {what} {REACH[0]:.2f}-{REACH[1]:.2f} m from the "
        f"robot base inside the workspace; {fix}"
    )


def _colour(value, colours: dict, where: str) -> tuple[float, float, float]:
    if isinstance(value, str):
        if value not in colours:
            raise TaskError(f"{where}: unknown colour {value!r}; known: {', '.join(sorted(colours))}")
        value = colours[value]
    rgb = tuple(float(v) for v in value)
    if len(rgb) != 3 or not all(0.0 <= v <= 1.0 for v in rgb):
        raise TaskError(f"{where}: a colour must be a name or [r, g, b] in 0..1, got {value!r}")
    return rgb  # type: ignore[return-value]


def _parse_task(name: str, spec: dict, bases: dict, colours: dict, source: str) -> Task:
    where = f"{source}: task {name!r}"
    if not isinstance(spec, dict):
        raise TaskError(f"{where}: expected a mapping with split, base, targets")
    missing = [k for k in ("split", "base", "targets") if k not in spec]
    if missing:
        raise TaskError(f"{where}: missing field(s) {', '.join(missing)}")
    unknown = set(spec) - {"split", "base", "targets", "orders"}
    if unknown:
        raise TaskError(f"{where}: unknown field(s) {', '.join(sorted(unknown))}")
    if spec["split"] not in SPLITS:
        raise TaskError(f"{where}: split must be one of {', '.join(SPLITS)}, got {spec['split']!r}")
    if spec["base"] not in bases:
        raise TaskError(f"{where}: unknown base {spec['base']!r}; known: {', '.join(sorted(bases))}")
    cells = tuple(
        BaseCell(float(c[0]), float(c[1]), _colour(c[2], colours, where)) for c in bases[spec["base"]]
    )
    try:
        targets = tuple((float(t[0]), float(t[1]), int(t[2])) for t in spec["targets"])
    except (TypeError, ValueError, IndexError) as exc:
        raise TaskError(f"{where}: targets must be a list of [x, y, layer] ({exc})") from None
    if not targets:
        raise TaskError(f"{where}: needs at least one target")
    if any(t[2] < 0 for t in targets):
        raise TaskError(f"{where}: layers start at 0")
    n = len(targets)
    orders_spec = spec.get("orders") or [[list(range(n))]]
    orders = []
    for order in orders_spec:
        groups = tuple(tuple(int(i) for i in g) for g in order)
        flat = sorted(i for g in groups for i in g)
        if flat != list(range(n)):
            raise TaskError(f"{where}: each order must use every target index 0..{n - 1} exactly once")
        orders.append(groups)
    task = Task(name, spec["split"], spec["base"], cells, targets, tuple(orders))
    task.supports()  # validates that every raised target rests on something
    check_limits(task, where)
    return task


def parse_task_table(table: dict, source: str) -> dict[str, Task]:
    """Parse a task table (the schema of tasks.yaml) into tasks keyed by name."""
    if not isinstance(table, dict) or "tasks" not in table:
        raise TaskError(f"{source}: a task file needs a top-level 'tasks' mapping (see docs/tasks.md)")
    builtin = _builtin_raw()
    colours = {**builtin.get("colours", {}), **(table.get("colours") or {})}
    bases = {**builtin.get("bases", {}), **(table.get("bases") or {})}
    for bname, cells in bases.items():
        if (
            not isinstance(cells, list)
            or not cells
            or not all(isinstance(c, list) and len(c) == 3 for c in cells)
        ):
            raise TaskError(f"{source}: base {bname!r} must be a list of [x, y, colour] cells")
    tasks = table["tasks"]
    if not isinstance(tasks, dict) or not tasks:
        raise TaskError(f"{source}: 'tasks' must be a non-empty mapping of name -> task")
    return {name: _parse_task(name, spec, bases, colours, source) for name, spec in tasks.items()}


@cache
def _builtin_raw() -> dict:
    return yaml.safe_load(resources.files("tvf.tasks").joinpath("tasks.yaml").read_text())


def load_task_file(path: str | Path) -> dict[str, Task]:
    """Read a YAML or JSON task file. Errors name the file and the problem."""
    path = Path(path)
    if not path.is_file():
        raise TaskError(f"task file {path} does not exist")
    text = path.read_text()
    try:
        table = json.loads(text) if path.suffix == ".json" else yaml.safe_load(text)
    except (json.JSONDecodeError, yaml.YAMLError) as exc:
        first = str(exc).splitlines()[0]
        raise TaskError(
            f"task file {path} is not valid {path.suffix.lstrip('.') or 'YAML'}: {first}"
        ) from None
    return parse_task_table(table, str(path))


@cache
def builtin_tasks() -> dict[str, Task]:
    return parse_task_table(_builtin_raw(), "tasks.yaml")


@dataclass(frozen=True)
class TaskTable:
    """The tasks a command knows: the built-in table plus a user's task file, as one picklable value.

    Commands load it once (:func:`load_tasks`) and hand it, or the :class:`Task` values it resolves,
    to every function and worker that needs them; nothing is kept in module state.
    """

    tasks: tuple[Task, ...]
    source: str = "tasks.yaml"

    def by_name(self) -> dict[str, Task]:
        return {t.name: t for t in self.tasks}

    def names(self) -> list[str]:
        return [t.name for t in self.tasks]

    def get(self, name: str) -> Task:
        """The task called ``name``; an unknown name is a :class:`TaskError` listing the choices."""
        for task in self.tasks:
            if task.name == name:
                return task
        hint = " (tasks from a file need --task-file)" if self.source == "tasks.yaml" else ""
        raise TaskError(f"unknown task {name!r}{hint}; choose one of: {', '.join(self.names())}")

    def resolve(self, spec: str) -> list[Task]:
        """``train`` | ``unseen`` | ``all`` | ``NAME[,NAME...]`` -> tasks, in table order."""
        if spec == "all":
            return list(self.tasks)
        if spec in SPLITS:
            return [t for t in self.tasks if t.split == spec]
        names = [s.strip() for s in spec.split(",") if s.strip()]
        if not names:
            raise TaskError("no task given; use train, unseen, all or task names separated by commas")
        return [self.get(n) for n in names]


def load_tasks(task_file: str | Path | None = None) -> TaskTable:
    """The built-in tasks plus those of ``task_file`` (a file's task may replace a built-in one)."""
    tasks = dict(builtin_tasks())
    source = "tasks.yaml"
    if task_file is not None:
        tasks.update(load_task_file(task_file))
        source = f"tasks.yaml + {task_file}"
    return TaskTable(tuple(tasks.values()), source)


BUILTIN = TaskTable(tuple(builtin_tasks().values()))
"""The built-in table (a constant: user tasks never change it)."""


def all_tasks() -> dict[str, Task]:
    """The built-in tasks by name."""
    return BUILTIN.by_name()


def get_task(name: str) -> Task:
    """A built-in task by name (user tasks: ``load_tasks(file).get(name)``)."""
    return BUILTIN.get(name)


def resolve_tasks(spec: str) -> list[Task]:
    """Built-in tasks by spec (see :meth:`TaskTable.resolve`)."""
    return BUILTIN.resolve(spec)
