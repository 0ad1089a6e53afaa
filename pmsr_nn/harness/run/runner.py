"""Run a scenario: every method on the same Monte Carlo draws, in blocks, shardable.

One runner for every scenario and every entry path (``pmsr evaluate``, ``--shard``,
``--per-block``, ``--executor`` and ``pmsr merge``), in three stages:

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

Every entry path builds one :class:`Run` (:func:`open_run`, or :func:`~.merge.open_merge` from
shard folders): the output checked, the scenario loaded, the output checked against the files it
reads, the scenario prepared. :func:`pmsr_nn.harness.evaluate.execute` runs it into its target.
The run stage imports the scenario stage only; what writes the results and the report composes
the stages above them (:mod:`pmsr_nn.harness.evaluate`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from ...outputs import check_folder_target, check_target
from ..scenario.loading import load_any, scenario_inputs
from ..scenario.prepare_designed import prepare_designed
from ..scenario.prepared import Setup
from ..scenario.references import scenario_references
from ..scenario.schema import Scenario
from .block_sums import BlockSums, shard_blocks

RESULT_COMMANDS = ("evaluate", "merge")
"""Output folders an ``evaluate`` or ``merge --overwrite`` may replace."""

TARGETS = ("results", "shard", "bank")
"""What a run writes to its folder: ``results``: ``results.json``, ``report.md`` and figures;
``shard``: ``shard.json`` and ``blocks.npz`` (``--shard I/N``); ``bank``: one shard folder per block
(``--per-block``, :mod:`.block_bank`)."""


def prepare(sc: Scenario, device: str = "cpu") -> Setup:
    """Resolve, design and check everything a scenario needs (every user error surfaces here,
    before any output is written)."""
    return prepare_designed(sc, device)


@dataclass(frozen=True)
class Run:
    """One run of the runner, as every entry path hands it on: a prepared scenario, the blocks to
    run and where their figures go.

    ``sums``: a merge's (the shards' sums of every block, in block order; nothing is left to run and
    ``blocks`` is empty); ``merged``: what the merge adds to ``results.json``'s environment (the
    shards' commits, a preview's full run count)."""

    setup: Setup
    blocks: range
    out: Path
    target: str = "results"
    shard: tuple[int, int] = (1, 1)
    inputs: tuple[Path, ...] = ()
    device: str = "cpu"
    progress: bool = True
    overwrite: bool = False
    sums: BlockSums | None = None
    merged: dict | None = None
    batch_runs: int = 1

    @property
    def scenario(self) -> Scenario:
        """The scenario, its options applied (``--mc-runs``, ``--seed``, ``--checkpoint``)."""
        return self.setup.scenario


def open_run(scenario: Scenario | str | Path, out: Path, *, target: str = "results", shard: tuple[int, int] = (1, 1),
             mc_runs: int | None = None, checkpoints: dict[str, str] | None = None, seed: int | None = None,
             device: str = "cpu", progress: bool = True, overwrite: bool = False,
             source: str | Path | None = None, check: Callable[[Scenario], None] | None = None,
             batch_runs: int = 1) -> Run:
    """The :class:`Run` of ``scenario`` (a YAML file, or a loaded scenario) into ``out``: the
    output checked (a results or shard folder before loading, as far as it can be), the scenario
    loaded with the options applied, ``check`` (an entry path's own checks of the loaded scenario),
    the output checked against every file the run reads, the shard's blocks, the preparation and
    the scenario's reference. ``source``: the scenario file when ``scenario`` is one loaded from it
    (an input too); ``batch_runs``: runs per call of a batchable kind (:mod:`.batches`)."""
    if target not in TARGETS:
        raise ValueError(f"target must be one of {TARGETS}, got {target!r}")
    if target != "bank":  # a bank is continued, never replaced: only what is never safe is refused
        check_folder_target(out, overwrite=overwrite, inputs=scenario_inputs(scenario, None), allow=RESULT_COMMANDS)
    sc = load_any(scenario, mc_runs, checkpoints, seed)
    if check is not None:
        check(sc)
    inputs = scenario_inputs(scenario if source is None else source, sc)
    if target == "bank":
        check_target(out, inputs=inputs)
    else:
        check_folder_target(out, overwrite=overwrite, inputs=inputs, allow=RESULT_COMMANDS)
    blocks = shard_blocks(sc.n_blocks, shard)
    setup = prepare(sc, device)
    scenario_references(sc)  # a bad reference entry fails now, not after the run
    return Run(setup, blocks, Path(out), target, tuple(shard), tuple(inputs), device, progress, overwrite,
               batch_runs=batch_runs)
