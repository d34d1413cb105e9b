"""Data-parallel training under ``torchrun``: one process per device, each step's batch split by rank.

``torchrun --nproc_per_node=N`` starts N copies of ``jsrte train`` with ``WORLD_SIZE``, ``RANK``
and ``LOCAL_RANK`` set; :func:`init_from_env` joins them in a process group (NCCL and one GPU
per process where CUDA is available, else gloo on the CPU). Every rank draws the same global
batch from ``batch_indices`` (a function of (seed, step)), takes its contiguous block of the B
shapes (:meth:`DistContext.shard`) with their points, and the decoder runs inside
``DistributedDataParallel``. The latent-code table is whole on every rank; its gradient is
all-reduced like the decoder's (:func:`average_gradient`), so every rank applies the same update
and holds the same codes. Each rank's loss is its share of the global loss (sums divided by the
global counts), scaled by the world size before ``backward`` so that DDP's averaging yields the
gradient of the global loss: one step equals a single-process step on the same global batch.
"""

from __future__ import annotations

import gc
import os
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import timedelta

import torch
import torch.distributed as dist

from jsrte.errors import JsrteError

DATA_TIMEOUT = timedelta(hours=12)
"""Collective timeout: the other ranks wait at a barrier while rank 0 samples the training data
(hours for a whole ShapeNet class on a CPU). A rank that dies is caught by torchrun, not by this."""
DROPOUT_RANK_STRIDE = 1_000_003
"""Dropout seeds differ by this between ranks (rank 0 keeps the single-process seed)."""


@dataclass(frozen=True)
class DistContext:
    """This process's place in a torchrun job.

    Attributes
    ----------
    world_size : number of processes
    rank : this process's index (0 writes checkpoints and logs)
    local_rank : index on this node (selects the GPU)
    device : where the decoder, the codes and the batches live
    """

    world_size: int
    rank: int
    local_rank: int
    device: torch.device

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    def shard(self, n: int) -> slice:
        """This rank's contiguous block of ``n`` items (block sizes differ by at most one)."""
        base, extra = divmod(n, self.world_size)
        start = self.rank * base + min(self.rank, extra)
        return slice(start, start + base + (1 if self.rank < extra else 0))


def launched_by_torchrun() -> bool:
    """True when the environment holds torchrun's ``WORLD_SIZE`` and ``RANK``."""
    return "WORLD_SIZE" in os.environ and "RANK" in os.environ


def init_from_env() -> DistContext | None:
    """Join the process group torchrun describes; None when not launched by torchrun."""
    if not launched_by_torchrun():
        return None
    try:
        world, rank = int(os.environ["WORLD_SIZE"]), int(os.environ["RANK"])
        local_rank = int(os.environ.get("LOCAL_RANK", "0"))
    except ValueError:
        raise JsrteError("WORLD_SIZE, RANK and LOCAL_RANK must be integers (set by torchrun)") from None
    if torch.cuda.is_available():
        if local_rank >= torch.cuda.device_count():
            raise JsrteError(f"LOCAL_RANK {local_rank} but only {torch.cuda.device_count()} GPUs; "
                             f"use --nproc_per_node <= the GPU count")
        backend, device = "nccl", torch.device("cuda", local_rank)
        torch.cuda.set_device(device)
    else:
        backend, device = "gloo", torch.device("cpu")
    if not dist.is_initialized():
        dist.init_process_group(backend, timeout=DATA_TIMEOUT)
    return DistContext(world_size=world, rank=rank, local_rank=local_rank, device=device)


def shutdown(ctx: DistContext | None) -> None:
    """Leave the process group (after the last checkpoint).

    A trainer's DDP wrapper keeps the group alive until the trainer is freed: drop the trainers
    first. Their reference cycles are collected here, before the group is destroyed; a group still
    referenced at interpreter exit has gloo's worker threads torn down during finalization, which
    aborts the process ("terminate called without an active exception") in about one run in ten.
    """
    if ctx is not None and dist.is_initialized():
        gc.collect()
        dist.barrier()
        dist.destroy_process_group()


@contextmanager
def main_process_first(ctx: DistContext | None) -> Iterator[None]:
    """Rank 0 runs the block first (e.g. writes a data cache), the others after it (reading it)."""
    if ctx is not None and not ctx.is_main:
        dist.barrier()
    yield
    if ctx is not None and ctx.is_main:
        dist.barrier()


def average_gradient(param: torch.Tensor, ctx: DistContext) -> None:
    """Replace ``param.grad`` by its mean over ranks (a rank that did not touch it counts 0)."""
    if param.grad is None:
        param.grad = torch.zeros_like(param)
    dist.all_reduce(param.grad, op=dist.ReduceOp.SUM)
    param.grad.div_(ctx.world_size)


def sum_over_ranks(values: torch.Tensor) -> torch.Tensor:
    """Element-wise sum of ``values`` over ranks (a new tensor; the input is left alone)."""
    total = values.detach().clone()
    dist.all_reduce(total, op=dist.ReduceOp.SUM)
    return total
