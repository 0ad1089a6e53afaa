"""Run a scenario: every method on the same Monte Carlo draws, in blocks, shardable.

One runner for every scenario, in three stages:

1. prepare (:func:`prepare`): a scenario file's study into a :class:`~.prepared.Setup`, every user
   error refused before anything is written: a designed scenario through
   :func:`~.prepare_designed.prepare_designed`, a multi-target study through
   :func:`~.prepare_multitarget.prepare_multitarget`. A Setup holds cases (:class:`~.prepared.Case`:
   a truth source with the targets' births and deaths, how it is sensed, its bounds) and methods
   (a :class:`~.method_spec.MethodSpec` each, run through its registered kind, :mod:`pmsr_nn.methods`);
2. run (:func:`~.blocks.run_blocks`): per case and block of ``block_runs`` runs, draw the truth and
   the sensor products, call every method on the whole block, keep the block's sums
   (:class:`~.block_sums.BlockSums`; a shard runs a contiguous slice of the blocks);
3. finalise (:func:`~.finalise.finalise`): the figures of ``results.json`` from all blocks' sums.

This module is the entry of stage 1, the one place that knows every study kind; the stages'
modules import nothing from it, so the dependencies point one way (runner -> preparations ->
prepared).
"""

from __future__ import annotations

from .multitarget import MultiTargetScenario
from .prepare_designed import prepare_designed
from .prepare_multitarget import prepare_multitarget
from .prepared import Setup
from .scenario import Scenario


def prepare(sc: Scenario | MultiTargetScenario, device: str = "cpu") -> Setup:
    """Resolve, design and check everything a scenario needs (every user error surfaces here,
    before any output is written): a designed :class:`~.scenario.Scenario` or a multi-target
    study (:class:`~.multitarget.MultiTargetScenario`)."""
    if isinstance(sc, Scenario):
        return prepare_designed(sc, device)
    return prepare_multitarget(sc, device)
