"""Data-parallel training across processes: who renders which view, and what every rank must agree on.

``torchrun --nproc_per_node N -m mogaface train CAPTURE --out RUN`` starts N copies of the
trainer; :func:`communicator_from_environment` joins them into one gloo process group (CPU). Every
rank holds the whole avatar and draws the same frames (same seed), renders its share of the
step's views (:meth:`Communicator.share`), and sums gradients and loss values with one
``all_reduce`` per step (:meth:`Communicator.reduce_step`), so every rank takes the same optimiser
step. Densification statistics stay local between densify passes and are reduced just before a
decision or a checkpoint (:meth:`Communicator.reduce_statistics`), so every rank densifies and
prunes identically. Rank 0 alone writes the run folder.

A single process is a :class:`Communicator` of world size 1: the same code path without
collectives, so one process with ``train.batch = B`` takes the same steps as B ranks of one view.
"""

from __future__ import annotations

import datetime
import os

import torch

from ..errors import InputError

DEFAULT_TIMEOUT_S = 300.0
FINISH_TIMEOUT_S = 6 * 3600.0  # rank 0's end-of-run evaluation may take long on a big capture


class Communicator:
    """This process's place in the run: ``rank`` of ``world`` processes (world 1: no collectives)."""

    def __init__(self, rank: int = 0, world: int = 1):
        self.rank = rank
        self.world = world
        self.bytes_sent = 0  # payload of every collective so far (benchmarks read it)
        self.seconds = 0.0  # time spent in collectives so far

    @property
    def is_writer(self) -> bool:
        """Only rank 0 writes the run folder (settings, events, checkpoints, results)."""
        return self.rank == 0

    def share(self, count: int) -> list[int]:
        """This rank's indices among a step's ``count`` views (round robin over the ranks)."""
        return list(range(self.rank, count, self.world))

    # -- collectives (no-ops in one process) -----------------------------------------------------
    def _all_reduce(self, tensor: torch.Tensor, op: str = "sum") -> torch.Tensor:
        if self.world == 1:
            return tensor
        import time

        import torch.distributed as dist

        start = time.perf_counter()
        dist.all_reduce(tensor, op={"sum": dist.ReduceOp.SUM, "max": dist.ReduceOp.MAX}[op])
        self.seconds += time.perf_counter() - start
        self.bytes_sent += tensor.numel() * tensor.element_size()
        return tensor

    def agree(self, values: list[float]) -> list[float]:
        """The largest of each value over the ranks (stop requests, time limits)."""
        return self._all_reduce(torch.tensor(values, dtype=torch.float64), "max").tolist()

    def reduce_step(self, params: list[torch.Tensor], extra: torch.Tensor) -> torch.Tensor:
        """Sum every parameter's gradient and ``extra`` (loss values) over the ranks, in one message.

        A parameter no rank produced a gradient for keeps ``grad = None`` (Adam skips it, as it
        would in one process); one that some rank did not touch counts as zeros there.
        """
        if self.world == 1:
            return extra
        has = torch.tensor([p.grad is not None for p in params], dtype=torch.float32)
        parts = [p.grad.reshape(-1) if p.grad is not None else p.new_zeros(p.numel()) for p in params]
        flat = self._all_reduce(torch.cat([*parts, extra.float(), has]))
        offset = 0
        for p, count in zip(params, flat[-len(params):].tolist() if params else []):
            n = p.numel()
            if count > 0:
                p.grad = flat[offset:offset + n].view_as(p).clone()
            offset += n
        return flat[offset:offset + extra.numel()].to(extra.dtype)

    def reduce_rows(self, rows: torch.Tensor) -> torch.Tensor:
        """Sum of per-view records that each rank filled for its own views (zeros elsewhere)."""
        return self._all_reduce(rows)

    def reduce_statistics(self, strategy) -> None:
        """Give every rank the totals of the densification statistics gathered by all ranks.

        Afterwards only rank 0 keeps the summed accumulators (the others restart from zero), so
        the next reduction counts each observation once; the maximum radii are kept everywhere.
        """
        if self.world == 1:
            return
        n = len(strategy.grad_accum)
        sums = self._all_reduce(torch.cat([strategy.grad_accum, strategy.grad_count]))
        strategy.grad_accum, strategy.grad_count = sums[:n].clone(), sums[n:].clone()
        strategy.max_radii = self._all_reduce(strategy.max_radii.clone(), "max")

    def keep_statistics_once(self, strategy) -> None:
        """After a checkpoint: the summed accumulators stay on rank 0 only."""
        if self.world > 1 and not self.is_writer:
            strategy.grad_accum.zero_()
            strategy.grad_count.zero_()

    def barrier(self) -> None:
        if self.world > 1:
            import torch.distributed as dist

            dist.barrier()

    def wait_for_writer(self, timeout_s: float = FINISH_TIMEOUT_S) -> None:
        """Hold every rank until rank 0 has written the results, so the ranks leave together
        (a rank that left early could make the launcher end the group while rank 0 still writes)."""
        if self.world > 1:
            import torch.distributed as dist

            dist.monitored_barrier(timeout=datetime.timedelta(seconds=timeout_s))

    def close(self) -> None:
        """Leave the process group; a peer that already left is no error at this point."""
        if self.world > 1:
            import torch.distributed as dist

            if dist.is_initialized():
                try:
                    dist.destroy_process_group()
                except RuntimeError:
                    pass


def communicator_from_environment(timeout_s: float = DEFAULT_TIMEOUT_S) -> Communicator:
    """Join the process group torchrun describes (``RANK``, ``WORLD_SIZE``, ``MASTER_ADDR``…).

    Without ``WORLD_SIZE`` (or with 1) this is a single process. A collective that waits longer
    than ``timeout_s`` for a peer raises instead of hanging.
    """
    world = int(os.environ.get("WORLD_SIZE", "1") or 1)
    if world <= 1:
        return Communicator()
    try:
        int(os.environ["RANK"])  # checked here: torch.distributed reads it
    except (KeyError, ValueError):
        raise InputError(None, "RANK", "WORLD_SIZE is set but RANK is not an integer (start with torchrun)") from None
    import torch.distributed as dist

    if not dist.is_available():
        raise InputError(None, "WORLD_SIZE", "this torch build has no torch.distributed")
    dist.init_process_group("gloo", timeout=datetime.timedelta(seconds=timeout_s))
    return Communicator(dist.get_rank(), dist.get_world_size())
