"""Benchmark: the belief-propagation tracker's time per run against S-MSJPDA's, both starting
their own tracks, on the same one_sky draws in one process (issue 55's speed target: BP per run
on one_sky at most S-MSJPDA's per run, in the same run).

The scenario is evaluate/one_sky_bp.yaml (one_sky's eight drones, six pairs, the draws of the
recorded study; one run per block, as the study runs them). For each of the first ``--runs``
runs both rows run on that run's detections, in the order A B for even runs and B A for odd ones,
so a drift of the machine's speed falls on both. Each call is timed by wall clock and by this
process's CPU time (``time.process_time``: what the process itself used, less disturbed by other
jobs on the machine). The record gives each run's seconds, the ratio BP / S-MSJPDA of each run and
its mean with the standard error over the runs, and the ratio of the summed times.

    python benchmarks/bench_bp.py --runs 6 --json benchmarks/results/bench_bp.json
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run_info import write_figures  # noqa: E402

from pmsr_nn.config import load_yaml  # noqa: E402
from pmsr_nn.harness.run.blocks import call_method, draw_block  # noqa: E402
from pmsr_nn.harness.run.runner import prepare  # noqa: E402
from pmsr_nn.harness.scenario.schema import scenario_from_dict  # noqa: E402

SCENARIO = Path(__file__).resolve().parents[1] / "evaluate" / "one_sky_bp.yaml"
ROWS = ("S-MSJPDA", "BP")
"""The two rows timed: the reference (S-MSJPDA starting its own tracks) and BP."""


def _mean_se(values: list[float]) -> tuple[float, float | None]:
    mean = statistics.fmean(values)
    return mean, (statistics.stdev(values) / len(values) ** 0.5 if len(values) > 1 else None)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=6, help="the first RUNS runs of the study (default 6)")
    ap.add_argument("--scenario", type=Path, default=SCENARIO,
                    help=f"a scenario with rows {' and '.join(ROWS)}, one run per block (default {SCENARIO.name})")
    ap.add_argument("--json", type=Path, help="write the figures here")
    args = ap.parse_args(argv)
    data = load_yaml(args.scenario)
    if not 1 <= args.runs <= int(data["mc_runs"]):
        ap.error(f"--runs must be in [1, {data['mc_runs']}] (the study's runs), got {args.runs}")
    sc = scenario_from_dict(data, args.scenario.resolve().parent)
    if sc.block_runs != 1:
        ap.error(f"{args.scenario.name} must run one run per block (block_runs: 1), as the study does")
    setup = prepare(sc)
    case = setup.cases[0]
    methods = {m.name: m for m in setup.methods}
    missing = [r for r in ROWS if r not in methods]
    if missing:
        ap.error(f"{args.scenario.name} has no row {missing}; it has {sorted(methods)}")
    wall = {r: [] for r in ROWS}
    cpu = {r: [] for r in ROWS}
    with torch.no_grad():
        for run in range(args.runs):
            _, products = draw_block(setup, 0, run)
            for name in (ROWS if run % 2 == 0 else ROWS[::-1]):
                t0, c0 = time.perf_counter(), time.process_time()
                call_method(setup, methods[name], case, products, (sc.seed, 0, run))
                wall[name].append(time.perf_counter() - t0)
                cpu[name].append(time.process_time() - c0)
            print(f"run {run}: " + ", ".join(f"{r} {wall[r][-1]:.1f} s" for r in ROWS), flush=True)
    figures = {"scenario": args.scenario.name, "case": case.name, "runs": args.runs, "threads": torch.get_num_threads(),
               "reference": ROWS[0], "rows": {}}
    for clock, times in (("wall", wall), ("cpu", cpu)):
        ratios = [b / a for a, b in zip(times[ROWS[0]], times[ROWS[1]])]
        mean, se = _mean_se(ratios)
        figures["rows"][clock] = {
            "seconds_per_run": {r: times[r] for r in ROWS},
            "mean_seconds_per_run": {r: statistics.fmean(times[r]) for r in ROWS},
            "ratio_per_run": ratios, "ratio_mean": mean, "ratio_se": se,
            "ratio_of_sums": sum(times[ROWS[1]]) / sum(times[ROWS[0]])}
        print(f"{clock}: {ROWS[1]} / {ROWS[0]} per run {mean:.3f}" + (f" +- {se:.3f}" if se is not None else "")
              + f", of the sums {figures['rows'][clock]['ratio_of_sums']:.3f}")
    write_figures(figures, args.json)


if __name__ == "__main__":
    main()
