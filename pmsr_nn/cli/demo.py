"""``pmsr demo``: simulate, train two small networks and evaluate them, on the built-in defaults."""

from __future__ import annotations

import sys
from pathlib import Path

from ..timings import DEMO_EXPECTED  # the recorded time (pmsr_nn/timings.py); each stage's bar shows its own
from .common import mc_runs_int

DEMO_DIR = Path("runs/demo")


def add_demo(sub) -> None:
    d = sub.add_parser(
        "demo",
        help=f"the main job on its built-in default ({DEMO_EXPECTED})",
        description="Simulate a small dataset of the built-in FITEE 2023 CA recipe, train a small MDFNN and a "
        "small KalmanNet-style filter on it, evaluate them against the EKF, UKF, SI+KF and the PCRB on the three "
        "built-in trajectories, then run a small version of the flagship scenario evaluate/one_sky.yaml (four "
        "drones, 2 transmitters x 3 receivers: single-target filters, a released network, the PCRB and S-MSJPDA on "
        "detections); print both tables and write the reports (OUT/evaluation/, OUT/one_sky/). "
        f"It takes {DEMO_EXPECTED}.",
    )
    d.add_argument("--out", type=Path, default=DEMO_DIR, help=f"output folder (default {DEMO_DIR}; a previous demo there is replaced)")
    d.add_argument("--mc-runs", type=mc_runs_int, default=20, help="Monte Carlo runs per trajectory (default 20)")
    d.add_argument("--verbose", action="store_true", help="Lightning's own progress bars and messages while training")
    d.set_defaults(run=cmd_demo)


def cmd_demo(args) -> int:
    from ..harness.demo import demo_summary, run_demo

    print(f"pmsr demo: simulate, train two small networks, compare with EKF, UKF, SI+KF and the PCRB ({DEMO_EXPECTED})",
          flush=True)
    # Bars (with time left) only on a terminal: a log file keeps the one line per stage.
    res = run_demo(args.out, mc_runs=args.mc_runs, progress=sys.stderr.isatty(), verbose=args.verbose,
                   log=lambda line: print(line, flush=True))
    print("\n".join(demo_summary(res, args.out)))
    return 0
