"""Benchmark: the wall-clock time of a test tier, as `make test` (or `make test-integration`) runs it.

Runs ``OMP_NUM_THREADS=1 python -m pytest -q -n 2 --dist worksteal`` (the Makefile's `test`
target, without its set-up; ``--tier integration`` adds its ``-m "integration and not slow"``) from
the repository root, and records the seconds, pytest's closing line, the exit status, this
process's niceness and the load average before and after (other jobs on the machine slow it):

    python benchmarks/time_tests.py --json benchmarks/results/test_suite_time.json
    python benchmarks/time_tests.py --tier integration --json benchmarks/results/test_integration_time.json

``pmsr_nn/timings.py`` quotes the recorded figure (README.md's `make test` line).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run_info import write_figures  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
COMMAND = [sys.executable, "-m", "pytest", "-q", "-n", "2", "--dist", "worksteal"]
TIERS = {"default": [], "integration": ["-m", "integration and not slow"]}
"""The Makefile's tiers: the options each adds to :data:`COMMAND`."""


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", type=Path, help="write the figures here")
    ap.add_argument("--tier", choices=sorted(TIERS), default="default", help="default: make test; integration: make test-integration")
    args = ap.parse_args()
    command = COMMAND + TIERS[args.tier]
    load_before = os.getloadavg()
    t0 = time.perf_counter()
    proc = subprocess.run(command, cwd=ROOT, env={**os.environ, "OMP_NUM_THREADS": "1"}, capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    lines = [line for line in proc.stdout.splitlines() if line.strip()]
    summary = lines[-1] if lines else ""
    print(f"{seconds:.0f} s ({seconds / 60:.1f} minutes), exit {proc.returncode}: {summary}")
    shown = " ".join(f'"{a}"' if " " in a else a for a in ["python", *command[1:]])
    write_figures({"command": f"OMP_NUM_THREADS=1 {shown}", "tier": args.tier, "seconds": seconds,
                   "minutes": seconds / 60, "returncode": proc.returncode, "summary": summary, "niceness": os.nice(0),
                   "load_average_before": list(load_before), "load_average_after": list(os.getloadavg())}, args.json)
    return proc.returncode


if __name__ == "__main__":
    sys.exit(main())
