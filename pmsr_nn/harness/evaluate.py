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
import zipfile
from pathlib import Path

import numpy as np

from ..environment import environment
from ..config import load_yaml
from ..errors import ConfigError
from ..outputs import atomic_folder, check_folder_target
from .report import reference_table, write_report
from .runner import DEFINITIONS, BlockSums, Setup, describe, finalise, prepare, run_blocks, shard_blocks
from .multitarget import (MT_DEFINITIONS, MultiTargetScenario, describe_multitarget, finalise_multitarget,
                          is_multitarget, multitarget_from_dict, prepare_multitarget, run_multitarget)
from .multitarget_report import write_multitarget_report
from .scenario import Scenario, load_scenario, scenario_from_dict

SHARD_FORMAT = "pmsr_nn.evaluation_shard/1"


RESULT_COMMANDS = ("evaluate", "merge")
"""Output folders an ``evaluate`` or ``merge --overwrite`` may replace."""


def atomic_dir(out: Path, overwrite: bool, command: str = "evaluate", inputs=()):
    """:func:`~pmsr_nn.outputs.atomic_folder` for a results folder."""
    return atomic_folder(out, command=command, overwrite=overwrite, inputs=inputs, allow=RESULT_COMMANDS)


def _inputs(scenario, sc) -> list[Path]:
    """Files a scenario run reads: its YAML and every checkpoint a method names."""
    paths = [] if isinstance(scenario, (Scenario, MultiTargetScenario)) else [Path(scenario)]
    for m in getattr(sc, "methods", ()):
        if getattr(m, "checkpoint", None):
            paths.append(sc.path(m.checkpoint))
    return paths


def _load(scenario: Scenario | str | Path, mc_runs: int | None, checkpoints: dict[str, str] | None) -> Scenario:
    sc = scenario if isinstance(scenario, Scenario) else load_scenario(scenario)
    return sc.with_mc_runs(mc_runs).with_checkpoints(checkpoints or {})


def _references(sc: Scenario) -> tuple[dict | None, dict | None, dict]:
    if sc.reference is None:
        return None, None, {}
    path = sc.path(sc.reference.file)
    table = reference_table(path, sc.reference.table)
    timing = reference_table(path, sc.reference.timing) if sc.reference.timing else None
    return table, timing, {"file": str(path), "table": sc.reference.table, "timing": sc.reference.timing,
                           "label": sc.reference.label}


def build_results(setup: Setup, bs: BlockSums, device: str) -> dict:
    sc = setup.scenario
    _, _, ref_info = _references(sc)
    return {"scenario": sc.name, "seed": sc.seed, "mc_runs": sc.mc_runs, "environment": environment(device),
            "description": sc.description, "settings": describe(setup), "definitions": DEFINITIONS,
            "reference": ref_info, "cases": finalise(setup, bs)}


def _examples(bs: BlockSums) -> dict:
    return {c: {m: np.asarray(a) for m, a in per.items()} for c, per in bs.example.items()}


def write_outputs(setup: Setup, bs: BlockSums, out: Path, device: str) -> dict:
    """``results.json``, ``report.md`` and figures into ``out`` (an existing, empty folder)."""
    sc = setup.scenario
    res = build_results(setup, bs, device)
    ref, timing, info = _references(sc)
    (out / "results.json").write_text(json.dumps(res, indent=1, allow_nan=True) + "\n")
    write_report(res, out, _examples(bs), setup.recipe.geometry.build(2), ref, timing, info.get("label", "paper"))
    return res


def evaluate(scenario: Scenario | str | Path, out: Path, *, mc_runs: int | None = None,
             checkpoints: dict[str, str] | None = None, shard: tuple[int, int] = (1, 1), device: str = "cpu",
             progress: bool = True, overwrite: bool = False) -> dict:
    """Run a scenario (or one shard) into ``out``; returns results.json's content (or shard.json's)."""
    check_folder_target(out, overwrite=overwrite, inputs=_inputs(scenario, None), allow=RESULT_COMMANDS)
    if not isinstance(scenario, Scenario):
        data = load_yaml(Path(scenario))
        if is_multitarget(data):
            if checkpoints:
                raise ConfigError("a multi-target scenario has no learned methods: --checkpoint does not apply")
            if shard != (1, 1):
                raise ConfigError("multi-target scenarios run whole (no --shard); use fewer --mc-runs for a quick look")
            sc = multitarget_from_dict(data, Path(scenario).parent, where=str(scenario))
            return evaluate_multitarget(sc, out, mc_runs=mc_runs, device=device, progress=progress,
                                        overwrite=overwrite, inputs=_inputs(scenario, sc))
    sc = _load(scenario, mc_runs, checkpoints)
    inputs = _inputs(scenario, sc)
    check_folder_target(out, overwrite=overwrite, inputs=inputs, allow=RESULT_COMMANDS)
    blocks = shard_blocks(sc.n_blocks, shard)
    setup = prepare(sc, device)
    _references(sc)  # a bad reference entry fails now, not after the run
    with atomic_dir(out, overwrite, inputs=inputs) as tmp:
        bs = run_blocks(setup, blocks, progress=progress)
        if shard == (1, 1):
            return write_outputs(setup, bs, tmp, device)
        meta = {"format": SHARD_FORMAT, "shard": list(shard), "blocks": list(blocks), "scenario": sc.to_dict(),
                "base_dir": sc.base_dir, "environment": environment(device)}
        np.savez_compressed(tmp / "blocks.npz", **bs.to_arrays())
        (tmp / "shard.json").write_text(json.dumps(meta, indent=1) + "\n")
        return meta


def evaluate_multitarget(sc: MultiTargetScenario, out: Path, *, mc_runs: int | None = None, device: str = "cpu",
                         progress: bool = True, overwrite: bool = False, inputs=()) -> dict:
    """Run a multi-target scenario (:mod:`.multitarget`) into ``out``: results.json, report.md, figures."""
    import dataclasses

    if mc_runs is not None:
        base = sc.base_dir
        sc = dataclasses.replace(sc, mc_runs=mc_runs)
        object.__setattr__(sc, "base_dir", base)
    if device != "cpu":
        raise ConfigError("the multi-target trackers run on the CPU (their assignment step is NumPy/SciPy)")
    setup = prepare_multitarget(sc)
    timing, ref_info = None, {}
    if sc.reference is not None:
        path = sc.path(sc.reference.file)
        timing = reference_table(path, sc.reference.timing)
        ref_info = {"file": str(path), "timing": sc.reference.timing, "label": sc.reference.label}
    with atomic_dir(out, overwrite, inputs=inputs) as tmp:
        raw = run_multitarget(setup, progress=progress)
        res = {"scenario": sc.name, "kind": "multitarget", "seed": sc.seed, "mc_runs": sc.mc_runs,
               "environment": environment(device), "description": sc.description,
               "settings": describe_multitarget(setup), "definitions": MT_DEFINITIONS, "reference": ref_info,
               "cases": finalise_multitarget(setup, raw)}
        (tmp / "results.json").write_text(json.dumps(res, indent=1, allow_nan=True) + "\n")
        examples = {c: raw[c]["example"] for c in raw}
        write_multitarget_report(res, tmp, examples, timing, ref_info.get("label", "paper"))
    return res


def merge(shards: list[Path], out: Path, *, device: str = "cpu", overwrite: bool = False) -> dict:
    """Combine shard folders of one scenario into the full results in ``out``."""
    shards = [Path(d) for d in shards]
    check_folder_target(out, overwrite=overwrite, inputs=shards, allow=RESULT_COMMANDS)
    seen: dict[str, Path] = {}
    for d in shards:
        real = str(d.resolve())
        if real in seen:
            raise ConfigError(f"shard folder {d} is given twice (as {seen[real]} and {d})")
        seen[real] = d
    metas, parts = [], []
    for d in shards:
        if not d.is_dir():
            raise ConfigError(f"{d} is not a folder; give the shard folders 'pmsr evaluate --shard' wrote")
        try:
            meta = json.loads((d / "shard.json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            raise ConfigError(f"{d} is not a shard folder of 'pmsr evaluate --shard' (no readable shard.json)") from None
        if not isinstance(meta, dict) or meta.get("format") != SHARD_FORMAT:
            raise ConfigError(f"{d}/shard.json is not a {SHARD_FORMAT} file")
        if not isinstance(meta.get("scenario"), dict) or not isinstance(meta.get("base_dir"), str):
            raise ConfigError(f"{d}/shard.json lacks its scenario (corrupted?)")
        try:
            with np.load(d / "blocks.npz", allow_pickle=False) as f:
                parts.append(BlockSums.from_arrays({k: f[k] for k in f.files}))
        except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, TypeError, IndexError) as exc:
            first_line = (str(exc).strip().splitlines() or [type(exc).__name__])[0][:120]
            raise ConfigError(f"{d}/blocks.npz is missing or corrupted ({first_line})") from None
        metas.append(meta)
    first = metas[0]
    for d, m in zip(shards, metas):
        if m["scenario"] != first["scenario"]:
            raise ConfigError(f"{d} comes from another scenario or settings than {shards[0]}")
    order = sorted(range(len(parts)), key=lambda i: parts[i].blocks[0] if parts[i].blocks else -1)
    merged = BlockSums([b for i in order for b in parts[i].blocks])
    sc = scenario_from_dict(first["scenario"], first["base_dir"])
    if merged.blocks != list(range(sc.n_blocks)):
        raise ConfigError(f"the shards cover blocks {merged.blocks}; the scenario has blocks 0..{sc.n_blocks - 1}, "
                          "each needed exactly once")
    for i in order:
        p = parts[i]
        for c in p.sums:
            for m in p.sums[c]:
                dst = merged.sums.setdefault(c, {}).setdefault(m, {})
                for q, a in p.sums[c][m].items():
                    dst[q] = a if q not in dst else np.concatenate([dst[q], a])
                for name in ("run_mse", "seconds"):
                    src, tgt = getattr(p, name)[c][m], getattr(merged, name).setdefault(c, {})
                    tgt[m] = src if m not in tgt else np.concatenate([tgt[m], src])
        for c, per in p.example.items():
            merged.example.setdefault(c, {}).update(per)
    setup = prepare(sc, device)
    with atomic_dir(out, overwrite, command="merge", inputs=shards) as tmp:
        res = write_outputs(setup, merged, tmp, device)
    return res
