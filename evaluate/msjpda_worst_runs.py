"""Per-run errors of a multi-target scenario: which Monte Carlo runs make one tracker worse than another?

A converged RMSE over 100 runs can be moved by a handful of runs. This re-draws the first
``--blocks`` blocks of one case (the same draws as ``pmsr evaluate``), runs every method of the
scenario on them, and prints each method's RMSE over those runs, its median per-run RMSE, and the
runs where ``--worse`` exceeds ``--than`` most, with the per-target RMSE (scans
``warmup_steps`` onwards) of every method.

    python evaluate/msjpda_worst_runs.py evaluate/access2019_msjpda_pd.yaml --case pd_0.95 --blocks 3
    python evaluate/msjpda_worst_runs.py evaluate/access2019_msjpda_pd.yaml --case pd_0.95 --blocks 3 \\
        --relaxation-iterations 100
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
import torch

from pmsr_nn.errors import ConfigError
from pmsr_nn.harness.run.blocks import call_method, draw_block
from pmsr_nn.harness.run.runner import prepare
from pmsr_nn.harness.scenario.schema import load_scenario
from pmsr_nn.methods import method_kind
from pmsr_nn.metrics import squared_error


def per_run_errors(path: Path, case: str, blocks: int, iterations: int | None = None) -> dict[str, np.ndarray]:
    """Per method, the per-run, per-target converged position RMSE ``(runs, T)`` in m."""
    sc = load_scenario(path)
    if iterations is not None:  # every method with relaxation iterations runs that many
        sc = sc.replace(methods=tuple(dataclasses.replace(m, options={**m.options, "relaxation_iterations": iterations})
                                      if "relaxation_iterations" in method_kind(m.kind).options else m
                                      for m in sc.methods))
    names = [c.name for c in sc.cases]
    if case not in names:
        raise ConfigError(f"no case {case!r} in {path} (cases: {', '.join(names)})")
    if not 1 <= blocks <= sc.n_blocks:
        raise ConfigError(f"--blocks must be 1..{sc.n_blocks}, got {blocks}")
    setup = prepare(sc)
    ci, pos, k0 = names.index(case), list(setup.models.motion.pos_idx), sc.warmup_steps
    out: dict[str, list] = {m.name: [] for m in setup.methods}
    with torch.no_grad():
        for block in range(blocks):
            truth, products = draw_block(setup, ci, block)
            for m in setup.methods:
                est = call_method(setup, m, setup.cases[ci], products, (sc.seed, ci, block))
                out[m.name].append(squared_error(est.x, truth.x, pos)[:, k0:].mean(1).sqrt().numpy())
    return {k: np.concatenate(v) for k, v in out.items()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenario", type=Path)
    ap.add_argument("--case", required=True, help="case name of the scenario")
    ap.add_argument("--blocks", type=int, default=3, help="first blocks of the case to draw (default 3)")
    ap.add_argument("--worse", default="P-MSJPDA", help="method whose excess error ranks the runs")
    ap.add_argument("--than", default="S-MSJPDA", help="method it is compared with")
    ap.add_argument("--top", type=int, default=5, help="runs listed (default 5)")
    ap.add_argument("--relaxation-iterations", type=int, help="override the scenario's tracker setting")
    args = ap.parse_args()
    try:
        err = per_run_errors(args.scenario, args.case, args.blocks, args.relaxation_iterations)
        for name in (args.worse, args.than):
            if name not in err:
                raise ConfigError(f"no method {name!r} (methods: {', '.join(err)})")
    except ConfigError as e:
        raise SystemExit(f"error: {e}") from None
    runs = len(next(iter(err.values())))
    print(f"{args.scenario.name}, case {args.case}: {runs} runs; position RMSE from the converged scan (m)")
    for name, e in err.items():
        print(f"  {name:24s} RMSE over runs {np.sqrt((e**2).mean()):7.1f}   median run {np.median(e):7.1f}")
    excess = (err[args.worse] ** 2).mean(1) - (err[args.than] ** 2).mean(1)
    print(f"runs where {args.worse} exceeds {args.than} most (per-target RMSE, m):")
    for r in np.argsort(-excess)[: args.top]:
        print(f"  run {r:3d}: " + "; ".join(f"{n} " + " / ".join(f"{v:.0f}" for v in e[r]) for n, e in err.items()))


if __name__ == "__main__":
    main()
