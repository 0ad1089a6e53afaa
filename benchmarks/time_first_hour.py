"""Benchmark: the wall-clock time of README.md's "Your first hour" block, command by command.

Runs every command of the block as written, in order, as the installed ``pmsr`` command of this
interpreter (``OMP_NUM_THREADS=1``), in a fresh temporary folder that links the repository's
``datasets/``, ``train/``, ``models/`` and ``evaluate/`` (so ``runs/`` and ``data/`` are written
there, not in the checkout; the folder is removed afterwards), and records each command's seconds
and exit status, the total, this process's niceness and the load average before and after:

    python benchmarks/time_first_hour.py --json benchmarks/results/first_hour_time.json

``pmsr_nn/timings.py`` quotes the recorded total and README.md the per-command times.
"""

from __future__ import annotations

import argparse
import os
import re
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run_info import write_figures  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
LINKED = ("datasets", "train", "models", "evaluate")


def first_hour_block(readme: str) -> list[str]:
    """The commands of README.md's "Your first hour" block, without their comments."""
    section = readme.split("## Your first hour", 1)[1].split("\n## ", 1)[0]
    block = re.search(r"```bash\n(.*?)```", section, flags=re.S).group(1)
    return [re.split(r"\s+#", line, maxsplit=1)[0].strip() for line in block.splitlines() if line.strip()]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--json", type=Path, help="write the figures here")
    args = ap.parse_args()
    commands = first_hour_block((ROOT / "README.md").read_text(encoding="utf-8"))
    steps, status = [], 0
    load_before = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="pmsr_first_hour_") as tmp:
        for name in LINKED:
            os.symlink(ROOT / name, Path(tmp) / name)
        for command in commands:
            argv = shlex.split(command)
            assert argv[0] == "pmsr", command
            run = [sys.executable, "-c", "import sys; from pmsr_nn.cli import main; sys.exit(main())", *argv[1:]]
            t0 = time.perf_counter()
            proc = subprocess.run(run, cwd=tmp, env={**os.environ, "OMP_NUM_THREADS": "1"}, capture_output=True,
                                  text=True)
            seconds = time.perf_counter() - t0
            steps.append({"command": command, "seconds": seconds, "returncode": proc.returncode})
            print(f"{seconds:6.1f} s  exit {proc.returncode}  {command}")
            if proc.returncode:
                print(proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else "(no stderr)")
                status = proc.returncode
                break
    total = sum(s["seconds"] for s in steps)
    print(f"{total:.0f} s in all ({total / 60:.1f} minutes)")
    write_figures({"commands": steps, "seconds": total, "minutes": total / 60, "complete": len(steps) == len(commands)
                   and status == 0, "niceness": os.nice(0), "load_average_before": list(load_before),
                   "load_average_after": list(os.getloadavg())}, args.json)
    return status


if __name__ == "__main__":
    sys.exit(main())
