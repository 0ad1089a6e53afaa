"""Benchmark: the wall-clock time of `make demo`'s job, ``pmsr demo`` on its default.

Runs ``OMP_NUM_THREADS=1 pmsr demo --out DIR`` (a fresh temporary folder, removed afterwards) from
the repository root and records the seconds of the whole command, the stage times the demo
writes (``demo.json``: training per model, the one-sky stage, its own total), the exit status,
this process's niceness and the load average before and after (other jobs slow it):

    python benchmarks/time_demo.py --json benchmarks/results/demo_time.json

``pmsr_nn/timings.py`` quotes the recorded figure (README.md and ``pmsr demo``'s header).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run_info import write_figures  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", type=Path, help="write the figures here")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="pmsr_demo_time_") as tmp:
        out = Path(tmp) / "demo"
        # the installed `pmsr` command's entry point, in this interpreter
        command = [sys.executable, "-c", "import sys; from pmsr_nn.cli import main; sys.exit(main())", "demo",
                   "--out", str(out)]
        load_before = os.getloadavg()
        t0 = time.perf_counter()
        proc = subprocess.run(command, cwd=ROOT, env={**os.environ, "OMP_NUM_THREADS": "1"}, capture_output=True,
                              text=True)
        seconds = time.perf_counter() - t0
        marker = out / "demo.json"
        stages = json.loads(marker.read_text(encoding="utf-8")) if marker.is_file() else None
    print(f"{seconds:.0f} s ({seconds / 60:.1f} minutes), exit {proc.returncode}")
    write_figures({"command": "OMP_NUM_THREADS=1 pmsr demo --out DIR", "seconds": seconds, "minutes": seconds / 60,
                   "returncode": proc.returncode, "stages": stages, "niceness": os.nice(0),
                   "load_average_before": list(load_before), "load_average_after": list(os.getloadavg())}, args.json)
    return proc.returncode


if __name__ == "__main__":
    sys.exit(main())
