"""Benchmark: ``pmsr evaluate`` with worker processes against one process, on one scenario.

Runs ``pmsr evaluate SCENARIO --out DIR --workers 1`` and ``--workers N`` (fresh temporary
folders, removed afterwards) from the repository root, alternating ``--repeats`` times, and
records each command's wall-clock seconds, their ratio (N workers over one; the issue's target is
0.6 or less on 2 cores) and whether the two results.json agree bit for bit in every figure but
the run times and the environment:

    python benchmarks/bench_workers.py evaluate/one_sky_bp.yaml --mc-runs 4 --json benchmarks/results/bench_workers.json
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run_info import write_figures  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def figures(res: dict) -> dict:
    """Every value of results.json but the run times and the environment."""
    def strip(x):
        if isinstance(x, dict):
            return {k: strip(v) for k, v in x.items() if k not in ("seconds_per_run", "environment")}
        if isinstance(x, list):
            return [strip(v) for v in x]
        return x
    return strip(res)


def timed(scenario: Path, out: Path, workers: int, mc_runs: int | None) -> float:
    command = [sys.executable, "-c", "import sys; from pmsr_nn.cli import main; sys.exit(main())", "evaluate",
               str(scenario), "--out", str(out), "--workers", str(workers), "--quiet"]
    if mc_runs:
        command += ["--mc-runs", str(mc_runs)]
    env = {k: v for k, v in os.environ.items() if k != "PMSR_WORKERS"}
    t0 = time.perf_counter()
    subprocess.run(command, cwd=ROOT, env={**env, "OMP_NUM_THREADS": "1"}, check=True)
    return time.perf_counter() - t0


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenario", type=Path)
    ap.add_argument("--mc-runs", type=int)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--json", type=Path, help="write the figures here")
    args = ap.parse_args()
    seconds: dict[int, list[float]] = {1: [], args.workers: []}
    same = True
    with tempfile.TemporaryDirectory(prefix="pmsr_bench_workers_") as tmp:
        for r in range(args.repeats):
            order = (1, args.workers) if r % 2 == 0 else (args.workers, 1)
            for w in order:
                seconds[w].append(timed(args.scenario, Path(tmp) / f"w{w}_r{r}", w, args.mc_runs))
            one, many = (json.loads((Path(tmp) / f"w{w}_r{r}" / "results.json").read_text()) for w in (1, args.workers))
            same = same and figures(one) == figures(many)
    ratios = [m / o for m, o in zip(seconds[args.workers], seconds[1])]
    print(f"one process {statistics.median(seconds[1]):.1f} s, {args.workers} workers "
          f"{statistics.median(seconds[args.workers]):.1f} s: ratio {statistics.median(ratios):.2f} "
          f"(runs {', '.join(f'{r:.2f}' for r in ratios)}); figures the same bit for bit: {same}")
    write_figures({"scenario": str(args.scenario), "mc_runs": args.mc_runs, "workers": args.workers,
                   "seconds_one_process": seconds[1], "seconds_workers": seconds[args.workers],
                   "ratio_median": statistics.median(ratios), "ratios": ratios, "figures_identical": same,
                   "cores": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
                   "load_average_after": list(os.getloadavg())}, args.json)
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
