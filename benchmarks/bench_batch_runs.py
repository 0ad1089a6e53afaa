"""Benchmark: ``pmsr evaluate --batch-runs N`` against block by block, on one study's batchable rows.

Runs ``pmsr evaluate SCENARIO --methods ROWS --mc-runs R --workers 1`` twice in one process
each (fresh temporary folders, removed afterwards): ``--batch-runs 1`` and ``--batch-runs N``.
Records each row's seconds per run both ways and their ratio (joined over block by block), and
the largest relative difference of any figure of results.json between the two (float rounding:
the joined call groups sums differently; tests/test_batches.py bounds it):

    python benchmarks/bench_batch_runs.py evaluate/one_sky.yaml --mc-runs 10 --batch-runs 10 \\
        --json benchmarks/results/bench_batch_runs.json
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run_info import write_figures  # noqa: E402

from pmsr_nn.harness.scenario.loading import load_any  # noqa: E402
from pmsr_nn.methods import registry  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def largest_difference(a, b) -> tuple[float, str, int]:
    """The largest relative difference of the floats of ``a`` and ``b`` (results.json, run times
    and the environment left out), where it is, and how many other values differ."""
    worst, where, other = 0.0, "", 0

    def walk(x, y, path):
        nonlocal worst, where, other
        if isinstance(x, dict):
            for k in x:
                if k not in ("seconds_per_run", "environment", "phd_seconds_per_run"):
                    walk(x[k], y.get(k) if isinstance(y, dict) else None, f"{path}/{k}")
        elif isinstance(x, list) and isinstance(y, list) and len(x) == len(y):
            for i, (u, v) in enumerate(zip(x, y)):
                walk(u, v, f"{path}/{i}")
        elif isinstance(x, float) and isinstance(y, float):
            if not (math.isnan(x) and math.isnan(y)) and x != y:
                r = abs(x - y) / max(abs(x), abs(y), 1e-300)
                if r > worst:
                    worst, where = r, f"{path[1:]} ({x!r} and {y!r})"
        elif x != y:
            other += 1
    walk(a, b, "")
    return worst, where, other


def evaluate(scenario: Path, out: Path, rows: list[str], mc_runs: int, batch_runs: int) -> dict:
    command = [sys.executable, "-c", "import sys; from pmsr_nn.cli import main; sys.exit(main())", "evaluate",
               str(scenario), "--out", str(out), "--workers", "1", "--quiet", "--mc-runs", str(mc_runs),
               "--batch-runs", str(batch_runs), "--methods", ",".join(rows)]
    env = {k: v for k, v in os.environ.items() if k != "PMSR_WORKERS"}
    subprocess.run(command, cwd=ROOT, env={**env, "OMP_NUM_THREADS": "1"}, check=True)
    return json.loads((out / "results.json").read_text())


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenario", type=Path)
    ap.add_argument("--mc-runs", type=int, default=10)
    ap.add_argument("--batch-runs", type=int, default=10)
    ap.add_argument("--rows", nargs="*", help="rows to time (default: every batchable row of the scenario)")
    ap.add_argument("--json", type=Path, help="write the figures here")
    args = ap.parse_args()
    sc = load_any(args.scenario)
    kinds = registry()
    rows = args.rows or [m.name for m in sc.methods if kinds[m.kind].batchable]
    with tempfile.TemporaryDirectory() as tmp:
        one = evaluate(args.scenario, Path(tmp) / "one", rows, args.mc_runs, 1)
        joined = evaluate(args.scenario, Path(tmp) / "joined", rows, args.mc_runs, args.batch_runs)
    figures = {"scenario": str(args.scenario), "mc_runs": args.mc_runs, "batch_runs": args.batch_runs, "rows": {}}
    for case, c in one["cases"].items():
        for name, r in c["methods"].items():
            if r.get("seconds_per_run") is None:
                continue
            s1, sn = r["seconds_per_run"], joined["cases"][case]["methods"][name]["seconds_per_run"]
            figures["rows"][name] = {"block_by_block_s": s1, "joined_s": sn, "ratio": sn / s1}
            print(f"{name}: {s1:.2f} -> {sn:.2f} s per run ({sn / s1:.2f}x)", flush=True)
    total1 = sum(r["block_by_block_s"] for r in figures["rows"].values())
    totaln = sum(r["joined_s"] for r in figures["rows"].values())
    figures["total"] = {"block_by_block_s": total1, "joined_s": totaln, "ratio": totaln / total1}
    worst, where, other = largest_difference(one["cases"], joined["cases"])
    figures["largest_relative_difference"], figures["where"], figures["other_values_differing"] = worst, where, other
    print(f"all: {total1:.1f} -> {totaln:.1f} s per run ({totaln / total1:.2f}x); figures agree to {worst:.1e} "
          f"(relative; the largest: {where}), {other} other value(s) differ")
    write_figures(figures, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
