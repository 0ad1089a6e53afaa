"""Run a scenario: every method on the same Monte Carlo draws, in blocks, shardable.

One runner for every scenario, in three stages:

1. prepare (:func:`prepare`): a scenario file's study into a :class:`~.prepared.Setup`, every user
   error refused before anything is written, through :func:`~.prepare_designed.prepare_designed`
   (a recipe's sensors and designed flights, or the scenario's own world). A Setup holds cases (:class:`~.prepared.Case`:
   a truth source with the targets' births and deaths, how it is sensed, its bounds) and methods
   (a :class:`~.method_spec.MethodSpec` each, run through its registered kind, :mod:`pmsr_nn.methods`);
2. run (:func:`~.blocks.run_blocks`): per case and block of ``block_runs`` runs, draw the truth and
   the sensor products, call every method on the whole block, keep the block's sums
   (:class:`~.block_sums.BlockSums`; a shard runs a contiguous slice of the blocks);
3. finalise (:func:`~.finalise.finalise`): the figures of ``results.json`` from all blocks' sums.

This module is the entry of stage 1; the stages' modules import nothing from it, so the
dependencies point one way (runner -> preparation -> prepared).
"""

from __future__ import annotations

from .prepare_designed import prepare_designed
from .prepared import Setup
from .scenario import Scenario


def prepare(sc: Scenario, device: str = "cpu") -> Setup:
    """Resolve, design and check everything a scenario needs (every user error surfaces here,
    before any output is written)."""
    return prepare_designed(sc, device)
