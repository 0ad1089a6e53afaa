"""Benchmark: S-MSJPDA and P-MSJPDA run time per 50-scan Monte Carlo run (issue 6's targets).

The scenario is evaluate/access2019_msjpda.yaml's nominal case (4 targets, 3 sensors, Pd 0.8, 50
clutter points per sensor per scan). Both trackers run on the same draws in this process, so
the P/S ratio is not disturbed by machine noise between runs. Two ways of timing:

* ``serial``: one run at a time (block of 1), what the paper's MATLAB figures measure;
* ``batched``: ``--block`` runs at once (the harness's way: S-MSJPDA batches everything over runs,
  its small clusters' events included; P-MSJPDA's (N+1)-D assignment loops over runs and
  clusters), divided by the runs; with ``--repeats`` the median of that many passes.

Every method of the scenario is timed: P-MSJPDA at m = 10 (as S-MSJPDA) and at m = 100, and the
true-assignment UKF (no association at all) as the floor of what a run costs.

    python benchmarks/bench_msjpda.py --runs 20 --json benchmarks/results/bench_msjpda.json
    python benchmarks/bench_msjpda.py --runs 100 --block 100 --serial-runs 10 --repeats 3 --methods S-MSJPDA
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
from pmsr_nn.harness.scenario.schema import scenario_from_dict  # noqa: E402
from pmsr_nn.harness.run.blocks import call_method, draw_block  # noqa: E402
from pmsr_nn.harness.run.runner import prepare  # noqa: E402

SCENARIO = Path(__file__).resolve().parents[1] / "evaluate" / "access2019_msjpda.yaml"
PAPER_S = {"S-MSJPDA": 2.45, "P-MSJPDA": 30.12}  # Table 1 of the paper at Pd 0.8, MATLAB, s per run


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", type=int, default=20, help="Monte Carlo runs timed (default 20)")
    ap.add_argument("--block", type=int, default=10, help="runs per batched call (default 10)")
    ap.add_argument("--serial-runs", type=int, help="runs timed one at a time (default: --runs)")
    ap.add_argument("--repeats", type=int, default=1, help="batched passes; the median is reported (default 1)")
    ap.add_argument("--methods", nargs="+", help="names of the methods to time (default: all of the scenario)")
    ap.add_argument("--json", type=Path, help="write the figures here")
    args = ap.parse_args()
    serial_runs = args.runs if args.serial_runs is None else args.serial_runs
    if not (1 <= serial_runs <= args.runs and args.repeats >= 1 and 1 <= args.block):
        ap.error("need 1 <= --serial-runs <= --runs, --repeats >= 1 and --block >= 1")
    data = load_yaml(SCENARIO)
    data.update(mc_runs=args.runs, block_runs=args.runs)
    sc = scenario_from_dict(data, SCENARIO.parent)
    setup = prepare(sc)
    case = setup.cases[0]
    det = draw_block(setup, 0, 0)[1]["detections"]  # the nominal case, all runs in one draw
    methods = {m.name: m for m in setup.methods}
    if args.methods:
        unknown = sorted(set(args.methods) - set(methods))
        if unknown:
            ap.error(f"unknown methods {unknown}; the scenario has {sorted(methods)}")
        methods = {k: v for k, v in methods.items() if k in args.methods}
    run = lambda m, i: call_method(setup, m, case, {"detections": det.runs(i)}, (sc.seed, 0, 0))
    for m in methods.values():  # untimed warm-up
        run(m, slice(0, 1))
    figures = {"scenario": str(SCENARIO.name), "case": sc.cases[0].name, "runs": args.runs, "block": args.block,
               "serial_runs": serial_runs, "repeats": args.repeats, "threads": torch.get_num_threads(), "methods": {}}
    for name, m in methods.items():
        serial = []
        for r in range(serial_runs):
            t0 = time.perf_counter()
            run(m, slice(r, r + 1))
            serial.append(time.perf_counter() - t0)
        passes = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            for start in range(0, args.runs, args.block):
                run(m, slice(start, start + args.block))
            passes.append((time.perf_counter() - t0) / args.runs)
        batched = statistics.median(passes)
        figures["methods"][name] = {"serial_s_per_run_mean": statistics.fmean(serial),
                                    "serial_s_per_run_median": statistics.median(serial),
                                    "batched_s_per_run": batched, "batched_s_per_run_passes": passes,
                                    "paper_s_per_run": PAPER_S.get(name)}
        print(f"{name:16s} serial {statistics.fmean(serial):.3f} s/run (median {statistics.median(serial):.3f})  "
              f"batched {batched:.3f} s/run  paper {PAPER_S.get(name, '-')}")
    f = figures["methods"]
    if "S-MSJPDA" in f:  # every P-MSJPDA variant (m = 10 as S-MSJPDA, m = 100) against S-MSJPDA
        figures["paper_p_over_s"] = PAPER_S["P-MSJPDA"] / PAPER_S["S-MSJPDA"]
        figures["p_over_s"] = {}
        for name in (m.name for m in methods.values() if m.kind == "p_msjpda"):
            ratio = {how: f[name][how] / f["S-MSJPDA"][how] for how in ("serial_s_per_run_mean", "batched_s_per_run")}
            figures["p_over_s"][name] = ratio
            print(f"{name} / S-MSJPDA time: serial {ratio['serial_s_per_run_mean']:.1f}x, batched "
                  f"{ratio['batched_s_per_run']:.1f}x (paper P/S {figures['paper_p_over_s']:.1f}x)")
    write_figures(figures, args.json)


if __name__ == "__main__":
    main()
