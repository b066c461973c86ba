"""Several training processes started by torchrun: who this process is, its share of each batch, the
gradient average, and rank 0's say over the run folder.

``torchrun --nproc-per-node N -m tvf train ...`` sets ``WORLD_SIZE``, ``RANK``, ``LOCAL_RANK``,
``MASTER_ADDR`` and ``MASTER_PORT``; without them (or with ``WORLD_SIZE`` 1) a run is one process, exactly
as before. The processes join one group (gloo on the CPU, NCCL on CUDA, one GPU per process). Every step
each process builds its slice of the same global batch (:meth:`World.share`), and the gradients are
averaged with one explicit all-reduce: the models' losses are methods (``model.loss``), not ``forward``,
so :class:`torch.nn.parallel.DistributedDataParallel`'s forward hooks would not see them. Each loss is a
mean over its slice, so the average over equal slices is the gradient of the global batch's mean loss.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from typing import TypeVar

import torch
import torch.distributed as dist

from tvf.errors import TvfError

T = TypeVar("T")


@dataclass(frozen=True)
class World:
    """This process's place among the training processes (rank 0 of 1 without torchrun)."""

    rank: int = 0
    size: int = 1
    local_rank: int = 0

    @property
    def main(self) -> bool:
        """Whether this process writes the run folder (rank 0)."""
        return self.rank == 0

    @property
    def several(self) -> bool:
        return self.size > 1

    def share(self, batch: int) -> slice | None:
        """This process's samples of a global batch of ``batch`` (None, all of them, for one process)."""
        if not self.several:
            return None
        per = batch // self.size
        return slice(self.rank * per, (self.rank + 1) * per)


def world_from_env(env: Mapping[str, str] = os.environ) -> World:
    """The world torchrun describes in ``env``; one process when it describes none."""
    if "WORLD_SIZE" not in env:
        return World()
    try:
        size, rank = int(env["WORLD_SIZE"]), int(env.get("RANK", "0"))
        local = int(env.get("LOCAL_RANK", str(rank)))
    except ValueError:
        raise TvfError(
            f"WORLD_SIZE={env.get('WORLD_SIZE')!r}, RANK={env.get('RANK')!r} are not whole numbers; "
            "start several processes with torchrun, which sets them"
        ) from None
    if not 0 <= rank < size:
        raise TvfError(f"RANK={rank} is outside WORLD_SIZE={size}; start several processes with torchrun")
    return World(rank, size, local)


def check_batch(batch: int, world: World) -> None:
    """Refuse a global batch that does not split evenly over the processes."""
    if batch % world.size:
        raise TvfError(
            f"--batch {batch} does not split over {world.size} processes; pass a --batch divisible by "
            f"{world.size} (it is the global batch; each process takes {world.size}th of it)"
        )


@contextmanager
def joined(world: World, device: torch.device) -> Iterator[torch.device]:
    """This process's device, inside the process group of a run of several processes (made here unless
    one exists, and then left again); one process needs no group."""
    if not world.several:
        yield device
        return
    if device.type == "cuda":
        device = torch.device("cuda", world.local_rank)
        torch.cuda.set_device(device)
    made = not dist.is_initialized()
    if made:
        dist.init_process_group("nccl" if device.type == "cuda" else "gloo", rank=world.rank,
                                world_size=world.size)  # fmt: skip
    elif dist.get_world_size() != world.size:
        raise TvfError(
            f"the process group has {dist.get_world_size()} processes, not WORLD_SIZE={world.size}"
        )
    try:
        yield device
    finally:
        if made:
            dist.destroy_process_group()


def decided_by_main(world: World, action: Callable[[], T]) -> T | None:
    """Run ``action`` on rank 0 alone; when it fails there, every process raises (rank 0 its error, the
    others a :class:`TvfError` of the same line), so no process waits on a rank that stopped."""
    if not world.several:
        return action()
    failure: Exception | None = None
    result = None
    if world.main:
        try:
            result = action()
        except Exception as exc:  # passed on to every rank, then raised here as it was
            failure = exc
    box = [None if failure is None else (isinstance(failure, TvfError), " ".join(str(failure).split()))]
    dist.broadcast_object_list(box, src=0)
    if failure is not None:
        raise failure
    if box[0] is not None:
        ours, line = box[0]
        raise TvfError(line if ours else f"rank 0 failed: {line}")
    return result


def from_main(world: World, value: T) -> T:
    """Rank 0's ``value`` on every process (a small picklable object)."""
    if not world.several:
        return value
    box = [value]
    dist.broadcast_object_list(box, src=0)
    return box[0]


def broadcast_module(world: World, module: torch.nn.Module) -> None:
    """Give every process rank 0's parameters and buffers."""
    if world.several:
        for tensor in [*module.parameters(), *module.buffers()]:
            dist.broadcast(tensor.data, src=0)


def mean_numbers(world: World, values: dict[str, float], device: torch.device) -> dict[str, float]:
    """Every process's ``values`` (the same keys everywhere) averaged over the processes."""
    if not world.several:
        return values
    keys = list(values)  # every process builds them in the same order
    total = torch.tensor([float(values[k]) for k in keys], dtype=torch.float64, device=device)
    dist.all_reduce(total)
    return {k: float(v) / world.size for k, v in zip(keys, total.tolist(), strict=True)}


def average_gradients(world: World, parameters: Iterable[torch.nn.Parameter]) -> None:
    """Replace each gradient with its mean over the processes (one all-reduce of them all, flattened).

    A parameter without a gradient on every process keeps none (the optimiser skips it, as one process
    would); one with a gradient somewhere gets zeros where it had none."""
    if not world.several:
        return
    params = [p for p in parameters if p.requires_grad]
    if not params:
        return
    device = params[0].device
    present = torch.tensor([p.grad is not None for p in params], dtype=torch.int32, device=device)
    dist.all_reduce(present)
    live = [p for p, n in zip(params, present.tolist(), strict=True) if n]
    for p in live:
        if p.grad is None:
            p.grad = torch.zeros_like(p)
    flat = torch.cat([p.grad.reshape(-1) for p in live])
    dist.all_reduce(flat)
    flat /= world.size
    offset = 0
    for p in live:
        n = p.grad.numel()
        p.grad.copy_(flat[offset : offset + n].view_as(p.grad))
        offset += n


def barrier(world: World) -> None:
    if world.several:
        dist.barrier()
