"""``pmsr evaluate`` and ``pmsr merge``: a scenario (or shard of one) into an output folder.

Every entry path builds one :class:`~.run.runner.Run` (:func:`~.run.runner.open_run`, or
:func:`~.run.merge.open_merge` from shard folders) and hands it to :func:`execute`, the one place
the stages meet: the run stage's blocks, the results stage's ``results.json`` and the report.

An unsharded run writes ``results.json`` (schema in DESIGN.md), ``report.md`` and PNG figures.
A shard ``I/N`` writes ``shard.json`` and ``blocks.npz`` (the raw per-block sums); ``merge``
checks that the shards come from one scenario and cover every block once, then writes what the
unsharded run would have (the same figures, bit for bit, timings aside). Output folders go
through :func:`pmsr_nn.outputs.atomic_folder`: checked before the run starts, built under a
temporary name and renamed when complete (a failure or a signal leaves nothing behind), and
``overwrite`` replaces only a folder an earlier ``evaluate`` or ``merge`` wrote, never an input.
A block bank (``--per-block``) writes each block as its own shard folder when done
(:mod:`.run.block_bank`).
"""

from __future__ import annotations

import json
from pathlib import Path

from ..environment import environment
from ..outputs import atomic_folder
from .report.document import write_report
from .results.record import build_results
from .run.block_bank import run_bank
from .run.block_sums import BlockSums, write_shard
from .run.blocks import run_blocks
from .run.merge import open_merge
from .run.runner import RESULT_COMMANDS, Run, open_run
from .scenario.prepared import Setup
from .scenario.references import scenario_references
from .scenario.schema import Scenario


def atomic_dir(out: Path, overwrite: bool, command: str = "evaluate", inputs=()):
    """:func:`~pmsr_nn.outputs.atomic_folder` for a results folder."""
    return atomic_folder(out, command=command, overwrite=overwrite, inputs=inputs, allow=RESULT_COMMANDS)


def write_outputs(setup: Setup, bs: BlockSums, out: Path, device: str, merged: dict | None = None) -> dict:
    """``results.json``, ``report.md`` and figures into ``out`` (an existing, empty folder)."""
    res = build_results(setup, bs, device, merged)
    ref, timing, info = scenario_references(setup.scenario)
    (out / "results.json").write_text(json.dumps(res, indent=1, allow_nan=True) + "\n")
    write_report(res, out, bs.example, setup.geometry, ref, timing, info.get("label", "paper"))
    return res


def execute(run: Run) -> dict:
    """Run ``run`` into its target: its blocks (none for a merge, whose sums are the shards'), then
    ``results.json``, ``report.md`` and figures, a shard folder, or one shard folder per block of a
    bank. Returns results.json's content (a shard: shard.json's; a bank: what it ran and holds)."""
    if run.target == "bank":
        return run_bank(run)
    command = "evaluate" if run.sums is None else "merge"
    with atomic_dir(run.out, run.overwrite, command=command, inputs=run.inputs) as tmp:
        bs = run.sums if run.sums is not None else run_blocks(run.setup, run.blocks, progress=run.progress,
                                                                     batch_runs=run.batch_runs)
        if run.target == "results":
            return write_outputs(run.setup, bs, tmp, run.device, run.merged)
        sc = run.scenario
        return write_shard(tmp, bs, run.shard, list(run.blocks), {"scenario": sc.to_dict(), "base_dir": sc.base_dir},
                           environment(run.device))


def evaluate(scenario: Scenario | str | Path, out: Path, *, mc_runs: int | None = None,
             checkpoints: dict[str, str] | None = None, shard: tuple[int, int] = (1, 1), device: str = "cpu",
             progress: bool = True, overwrite: bool = False, seed: int | None = None, batch_runs: int = 1) -> dict:
    """Run a scenario (or one shard) into ``out``; returns results.json's content (or shard.json's).
    ``seed`` replaces the scenario's seed (other draws of the same scenario); ``batch_runs``: runs
    per call of a batchable kind (:mod:`.run.batches`)."""
    target = "results" if tuple(shard) == (1, 1) else "shard"
    return execute(open_run(scenario, out, target=target, shard=shard, mc_runs=mc_runs, checkpoints=checkpoints,
                            seed=seed, device=device, progress=progress, overwrite=overwrite, batch_runs=batch_runs))


def merge(shards: list[Path], out: Path, *, device: str = "cpu", overwrite: bool = False,
          runs: int | None = None) -> dict:
    """Combine shard folders of one scenario into the full results in ``out``; a block bank
    (``evaluate --per-block``) stands for the block folders it holds. ``runs``: merge only the
    first ``runs`` runs (whole blocks; shards of later blocks are left out), a preview of a
    recording still running, marked as one in the results and report."""
    return execute(open_merge(shards, out, device=device, overwrite=overwrite, runs=runs))
