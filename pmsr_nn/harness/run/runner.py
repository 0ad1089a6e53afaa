"""Run a scenario: every method on the same Monte Carlo draws, in blocks, shardable.

One runner for every scenario, in three stages:

1. prepare (:func:`prepare`): a scenario file's study into a
   :class:`~pmsr_nn.harness.scenario.prepared.Setup`, every user error refused before anything is
   written, through :func:`~pmsr_nn.harness.scenario.prepare_designed.prepare_designed` (a recipe's
   sensors and designed flights, or the scenario's own world). A Setup holds cases (a truth source
   with the targets' births and deaths, how it is sensed, its bounds) and methods (a
   :class:`~pmsr_nn.harness.scenario.method_spec.MethodSpec` each, run through its registered kind,
   :mod:`pmsr_nn.methods`);
2. run (:func:`~.blocks.run_blocks`): per case and block of ``block_runs`` runs, draw the truth and
   the sensor products, call every method on the whole block, keep the block's sums
   (:class:`~.block_sums.BlockSums`; a shard runs a contiguous slice of the blocks);
3. finalise (:func:`~pmsr_nn.harness.results.finalise.finalise`, the results stage): the figures
   of ``results.json`` from all blocks' sums.

The run stage imports the scenario stage only; what writes the results and the report composes
the stages above them (:mod:`pmsr_nn.harness.evaluate`).
"""

from __future__ import annotations

from ..scenario.prepare_designed import prepare_designed
from ..scenario.prepared import Setup
from ..scenario.schema import Scenario


def prepare(sc: Scenario, device: str = "cpu") -> Setup:
    """Resolve, design and check everything a scenario needs (every user error surfaces here,
    before any output is written)."""
    return prepare_designed(sc, device)
