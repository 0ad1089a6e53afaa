"""``pmsr merge``'s run: shard folders of one scenario (or block banks standing for theirs),
checked to come from one scenario and to cover every block once, as one :class:`~.runner.Run`
whose sums are the shards' (nothing left to run).

A merge of shards gives the unsharded run's figures bit for bit, timings aside: the sums are
concatenated in block order (:meth:`~.block_sums.BlockSums.concatenate`) and reduced like one run's.
Blocks scored over other scans than the case's set scans (made before issue 55's fix) have their
per-run figures re-derived, or are refused (:mod:`.set_window`); the record names them.
"""

from __future__ import annotations

from pathlib import Path

from ...errors import ConfigError
from ...outputs import check_folder_target
from ..scenario.schema import Scenario, scenario_from_dict
from .block_bank import bank_blocks, is_bank, made_per_block
from .block_sums import BlockSums, read_shard
from .runner import RESULT_COMMANDS, Run, prepare
from .set_window import rescore_runs


def open_merge(shards: list[Path], out: Path, *, device: str = "cpu", overwrite: bool = False,
               runs: int | None = None) -> Run:
    """The :class:`~.runner.Run` that writes the full results of shard folders ``shards`` into
    ``out``; a block bank (``evaluate --per-block``) stands for the block folders it holds.
    ``runs``: merge only the first ``runs`` runs (whole blocks; shards of later blocks are left
    out), a preview of a recording still running, marked as one in the results and report."""
    shards = [Path(d) for d in shards]
    check_folder_target(out, overwrite=overwrite, inputs=shards, allow=RESULT_COMMANDS)
    # a bank stands for its blocks, also one whose bank.json is gone (each block names its scenario)
    shards = [part for d in shards for part in (bank_blocks(d) if is_bank(d) or made_per_block(d) else [d])]
    if not shards:
        raise ConfigError("the block bank(s) given hold no block yet; run 'pmsr evaluate --per-block' first")
    seen: dict[str, Path] = {}
    for d in shards:
        real = str(d.resolve())
        if real in seen:
            raise ConfigError(f"shard folder {d} is given twice (as {seen[real]} and {d})")
        seen[real] = d
    metas, parts = [], []
    for d in shards:
        meta, bs = read_shard(d)
        metas.append(meta)
        parts.append(bs)
    first = metas[0]
    for d, m in zip(shards, metas):
        if m["scenario"] != first["scenario"]:
            raise ConfigError(f"{d} comes from another scenario or settings than {shards[0]}")
    sc = scenario_from_dict(first["scenario"], first["base_dir"])
    shard_env = lambda key: sorted({str(m.get("environment", {}).get(key)) for m in metas})
    extra = {"shard_commits": shard_env("commit"), "shard_machines": shard_env("machine")}
    if runs is not None:
        parts = _first_runs(sc, runs, shards, parts)
        extra["preview_of_runs"] = sc.mc_runs
        sc = sc.with_mc_runs(runs)
    blocks = [b for p in sorted(parts, key=lambda p: p.blocks[0] if p.blocks else -1) for b in p.blocks]  # merged order
    if blocks != list(range(sc.n_blocks)):
        missing = sorted(set(range(sc.n_blocks)) - set(blocks))
        twice = sorted({b for b in blocks if blocks.count(b) > 1})
        raise ConfigError(f"the shards lack blocks {_ranges(missing) or 'none'} and repeat {_ranges(twice) or 'none'}; "
                          f"the scenario has blocks 0..{sc.n_blocks - 1}, each needed exactly once")
    setup = prepare(sc, device)
    redone = rescore_runs(parts, {c.name: c.set_scans.numpy() for c in setup.cases},
                          lambda b: len(sc.block_runs_range(b)))
    if redone:
        extra["per_run_rescored_blocks"] = _ranges(redone)
    return Run(setup, range(0), Path(out), "results", inputs=tuple(shards), device=device, overwrite=overwrite,
               sums=BlockSums.concatenate(parts), merged=extra)


def _first_runs(sc: Scenario, runs: int, shards: list[Path], parts: list[BlockSums]) -> list[BlockSums]:
    """The sums of the shards that hold the blocks of the first ``runs`` runs of ``sc``."""
    if not 1 <= runs <= sc.mc_runs:
        raise ConfigError(f"--runs must be in 1..{sc.mc_runs} (the scenario's runs), got {runs}")
    if runs % sc.block_runs and runs != sc.mc_runs:
        raise ConfigError(f"--runs {runs}: a preview takes whole blocks of {sc.block_runs} runs")
    n = sc.with_mc_runs(runs).n_blocks
    keep = []
    for d, p in zip(shards, parts):
        inside = [b < n for b in p.blocks]
        if any(inside) and not all(inside):
            raise ConfigError(f"--runs {runs}: shard {d} holds blocks on both sides of run {runs}; give a number of "
                              "runs at a shard's edge")
        if all(inside):
            keep.append(p)
    return keep


def _ranges(blocks: list[int]) -> str:
    """``[0, 1, 2, 5]`` -> ``"0-2, 5"``."""
    out, start = [], None
    for i, b in enumerate(blocks):
        start = b if start is None else start
        if i + 1 == len(blocks) or blocks[i + 1] != b + 1:
            out.append(f"{start}" if start == b else f"{start}-{b}")
            start = None
    return ", ".join(out)
