"""Several blocks of runs in one method call (``pmsr evaluate --batch-runs``).

A block is the unit of a study's random draws, banking and sharding; ``block_runs: 1`` makes a
study easy to shard, but then every tracker runs one run at a time and pays its Python overhead
per scan for one run only. The trackers are batch-first, so the runner may instead call a kind
on the runs of several blocks at once: each block's draws stay its own (drawn from its own
generator, exactly as without batching), their products are joined along the run axis
(``concat`` of each product class), the method is called once, and its estimates are split back
into the blocks, each scored and banked as before.

Only kinds registered ``batchable`` are joined: a run's estimates must not depend on the other
runs of its call, so they draw nothing from the block's random stream (a particle filter's
particles would). The joined call computes the same maths on padded tensors; float rounding may
differ in the last bits where a batched product groups its sums differently (recorded in
benchmarks/RESULTS.md). Blocks are grouped by ``block // blocks_per_call``, so that a group
never depends on which blocks a shard, a worker or a resumed bank happens to run.
"""

from __future__ import annotations

import dataclasses
from typing import Iterable

import torch

from ...trackers.base import Estimates


def blocks_per_call(batch_runs: int, block_runs: int) -> int:
    """Whole blocks per call for ``batch_runs`` runs (at least one)."""
    return max(1, batch_runs // block_runs)


def batch_groups(blocks: Iterable[int], per_call: int) -> list[list[int]]:
    """``blocks`` (ascending) grouped by ``block // per_call``: aligned groups of consecutive blocks."""
    groups: dict[int, list[int]] = {}
    for b in sorted(blocks):
        groups.setdefault(b // per_call, []).append(b)
    return list(groups.values())


def joinable(parts: list) -> bool:
    """Whether the products ``parts`` (one per block, of one kind) can be joined into one call."""
    first = parts[0]
    if not hasattr(type(first), "concat"):
        return False
    return getattr(first, "front_end", None) is None  # detections from signals keep one record per block


def join(parts: list):
    """One product holding the runs of ``parts`` one after another."""
    return type(parts[0]).concat(parts)


def split_estimates(est: Estimates, runs: list[int]) -> list[Estimates]:
    """The estimates of a joined call cut back into its blocks of ``runs[i]`` runs. Unpaired
    track slots that no run of a block uses are dropped (another block of the call needed them);
    an extra whose first axis is the runs is cut too, any other (a per-call figure) is handed to
    every block as it is."""
    B = est.x.shape[0]
    if sum(runs) != B:
        raise ValueError(f"{sum(runs)} runs in the blocks, {B} in the estimates")
    out, start = [], 0
    for r in runs:
        rows = slice(start, start + r)
        start += r
        slots = est.x.shape[2]
        if not est.paired:
            used = torch.nonzero(est.exists[rows].flatten(0, 1).any(0))
            slots = int(used[-1]) + 1 if len(used) else 0
        cut = lambda t: None if t is None else t[rows, :, :slots]  # noqa: E731
        extras = {k: v[rows] if isinstance(v, torch.Tensor) and v.dim() and v.shape[0] == B else v
                  for k, v in est.extras.items()}
        out.append(dataclasses.replace(est, x=cut(est.x), exists=cut(est.exists), P=cut(est.P), extras=extras,
                                       existence=cut(est.existence)))
    return out
