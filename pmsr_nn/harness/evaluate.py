"""``pmsr evaluate`` and ``pmsr merge``: a scenario (or shard of one) into an output folder.

An unsharded run writes ``results.json`` (schema in DESIGN.md), ``report.md`` and PNG figures.
A shard ``I/N`` writes ``shard.json`` and ``blocks.npz`` (the raw per-block sums); ``merge``
checks that the shards come from one scenario and cover every block once, then writes what the
unsharded run would have (the same figures, bit for bit, timings aside). Output folders go
through :func:`pmsr_nn.outputs.atomic_folder`: checked before the run starts, built under a
temporary name and renamed when complete (a failure or a signal leaves nothing behind), and
``overwrite`` replaces only a folder an earlier ``evaluate`` or ``merge`` wrote, never an input.
"""

from __future__ import annotations

import json
from pathlib import Path

from ..config import load_yaml
from ..environment import environment
from ..errors import ConfigError
from ..outputs import atomic_folder, check_folder_target
from .report.document import write_report
from .results.finalise import finalise, result_kind
from .run.block_bank import bank_blocks, is_bank
from .run.block_sums import BlockSums, read_shard, shard_blocks, write_shard
from .run.blocks import run_blocks
from .run.runner import prepare
from .scenario.prepared import Setup
from .scenario.references import reference_table
from .scenario.schema import Scenario, scenario_from_dict


RESULT_COMMANDS = ("evaluate", "merge")
"""Output folders an ``evaluate`` or ``merge --overwrite`` may replace."""

AnyScenario = Scenario
"""What a scenario file holds (one schema: :class:`~.scenario.schema.Scenario`)."""


def atomic_dir(out: Path, overwrite: bool, command: str = "evaluate", inputs=()):
    """:func:`~pmsr_nn.outputs.atomic_folder` for a results folder."""
    return atomic_folder(out, command=command, overwrite=overwrite, inputs=inputs, allow=RESULT_COMMANDS)


def scenario_inputs(scenario, sc) -> list[Path]:
    """Files a scenario run reads: its YAML and every checkpoint a method names."""
    paths = [] if isinstance(scenario, Scenario) else [Path(scenario)]
    for m in getattr(sc, "methods", ()):
        if getattr(m, "checkpoint", None):
            paths.append(sc.path(m.checkpoint))
    return paths


def scenario_from_data(data, base_dir: str | Path, where: str = "scenario") -> AnyScenario:
    """A scenario from plain data (a retired ``kind`` refused in one line,
    :data:`~.scenario.schema.RETIRED_KINDS`)."""
    return scenario_from_dict(data, base_dir, where=where)


def load_any(scenario: AnyScenario | str | Path, mc_runs: int | None = None,
             checkpoints: dict[str, str] | None = None, seed: int | None = None) -> AnyScenario:
    """The scenario (loaded from its YAML file if a path), with ``--mc-runs``, ``--seed`` and
    ``--checkpoint`` applied."""
    if isinstance(scenario, Scenario):
        sc = scenario
    else:
        sc = scenario_from_data(load_yaml(Path(scenario)), Path(scenario).parent, where=str(scenario))
    sc = sc.with_mc_runs(mc_runs).with_seed(seed)
    return sc.with_checkpoints(checkpoints) if checkpoints else sc


def _references(sc: AnyScenario) -> tuple[dict | None, dict | None, dict]:
    """The paper's accuracy table and run-time table named by the scenario (each may be None)."""
    ref = sc.reference
    if ref is None:
        return None, None, {}
    path = sc.path(ref.file)
    name = getattr(ref, "table", None)
    table = reference_table(path, name) if name else None
    timing = reference_table(path, ref.timing) if ref.timing else None
    info = {"file": str(path), "table": name, "timing": ref.timing, "label": ref.label}
    per_target = {key: reference_table(path, getattr(ref, key)) for key in ("velocity_rmse", "anees")
                  if getattr(ref, key, None)}
    if per_target:  # the paper's per-target tables, shown beside ours
        info["per_target"] = {**per_target, "methods": dict(ref.methods),
                              **{f"{k}_key": getattr(ref, k) for k in per_target}}
    if getattr(ref, "setup", None):  # the paper's stated set-up, shown beside the scenario's
        info["setup"] = {"key": ref.setup, "table": reference_table(path, ref.setup)}
    if getattr(ref, "subarea_table", None):  # a track-before-detect sub-area study's (the Remote Sensing seed's Table 2)
        info["subarea"] = {"key": ref.subarea_table, "table": reference_table(path, ref.subarea_table)}
    return table, timing, info


def build_results(setup: Setup, bs: BlockSums, device: str, merged: dict | None = None) -> dict:
    """``results.json``'s content: the scenario, its result kind (:func:`~.results.finalise.result_kind`),
    settings, definitions, the paper's reference and every case's figures; ``merged``: what a merge
    adds to the environment (the shards' commits, a preview's full run count)."""
    sc = setup.scenario
    _, _, ref_info = _references(sc)
    env = {**environment(device), **(merged or {})}
    return {"scenario": sc.name, "kind": result_kind(setup), "seed": sc.seed, "mc_runs": sc.mc_runs,
            "environment": env,
            "description": sc.description, "settings": setup.settings, "definitions": setup.definitions,
            "reference": ref_info, "cases": finalise(setup, bs)}


def write_outputs(setup: Setup, bs: BlockSums, out: Path, device: str, merged: dict | None = None) -> dict:
    """``results.json``, ``report.md`` and figures into ``out`` (an existing, empty folder)."""
    res = build_results(setup, bs, device, merged)
    ref, timing, info = _references(setup.scenario)
    (out / "results.json").write_text(json.dumps(res, indent=1, allow_nan=True) + "\n")
    write_report(res, out, bs.example, setup.geometry, ref, timing, info.get("label", "paper"))
    return res


def evaluate(scenario: AnyScenario | str | Path, out: Path, *, mc_runs: int | None = None,
             checkpoints: dict[str, str] | None = None, shard: tuple[int, int] = (1, 1), device: str = "cpu",
             progress: bool = True, overwrite: bool = False, seed: int | None = None) -> dict:
    """Run a scenario (or one shard) into ``out``; returns results.json's content (or shard.json's).
    ``seed`` replaces the scenario's seed (other draws of the same scenario)."""
    check_folder_target(out, overwrite=overwrite, inputs=scenario_inputs(scenario, None), allow=RESULT_COMMANDS)
    sc = load_any(scenario, mc_runs, checkpoints, seed)
    inputs = scenario_inputs(scenario, sc)
    check_folder_target(out, overwrite=overwrite, inputs=inputs, allow=RESULT_COMMANDS)
    blocks = shard_blocks(sc.n_blocks, shard)
    setup = prepare(sc, device)
    _references(sc)  # a bad reference entry fails now, not after the run
    with atomic_dir(out, overwrite, inputs=inputs) as tmp:
        bs = run_blocks(setup, blocks, progress=progress)
        if shard == (1, 1):
            return write_outputs(setup, bs, tmp, device)
        return write_shard(tmp, bs, shard, list(blocks), {"scenario": sc.to_dict(), "base_dir": sc.base_dir},
                           environment(device))


def merge(shards: list[Path], out: Path, *, device: str = "cpu", overwrite: bool = False,
          runs: int | None = None) -> dict:
    """Combine shard folders of one scenario into the full results in ``out``; a block bank
    (``evaluate --per-block``) stands for the block folders it holds. ``runs``: merge only the
    first ``runs`` runs (whole blocks; shards of later blocks are left out), a preview of a
    recording still running, marked as one in the results and report."""
    shards = [Path(d) for d in shards]
    check_folder_target(out, overwrite=overwrite, inputs=shards, allow=RESULT_COMMANDS)
    shards = [part for d in shards for part in (bank_blocks(d) if is_bank(d) else [d])]
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
    sc = scenario_from_data(first["scenario"], first["base_dir"])
    extra = {"shard_commits": sorted({str(m.get("environment", {}).get("commit")) for m in metas})}
    if runs is not None:
        parts = _first_runs(sc, runs, shards, parts)
        extra["preview_of_runs"] = sc.mc_runs
        sc = sc.with_mc_runs(runs)
    merged = BlockSums.concatenate(parts)
    if merged.blocks != list(range(sc.n_blocks)):
        missing = sorted(set(range(sc.n_blocks)) - set(merged.blocks))
        twice = sorted({b for b in merged.blocks if merged.blocks.count(b) > 1})
        raise ConfigError(f"the shards lack blocks {_ranges(missing) or 'none'} and repeat {_ranges(twice) or 'none'}; "
                          f"the scenario has blocks 0..{sc.n_blocks - 1}, each needed exactly once")
    setup = prepare(sc, device)
    with atomic_dir(out, overwrite, command="merge", inputs=shards) as tmp:
        res = write_outputs(setup, merged, tmp, device, extra)
    return res


def _first_runs(sc: AnyScenario, runs: int, shards: list[Path], parts: list[BlockSums]) -> list[BlockSums]:
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
