"""Benchmark: what clutter costs the SMC-PHD, adaptive births against births on every detection.

Target (issue 37, part 4): with 30 clutter points per scan a run costs at most 2x its time with
10. The scene is ``bench_phd.py``'s (``--targets`` sinusoidal tracks in the bistatic plane, all
alive throughout, Pd 0.9, 30 m / 4.5 m/s, Poisson clutter over 6.5-48 km x +-500 m/s), one draw
of ``--runs`` runs per clutter level; ``SMCPHD.run`` with ``PHDSpec(adaptive_birth=...)``, the
other settings the defaults. The four calls (adaptive / every_detection x 10 / 30 clutter points)
are interleaved, ``--rounds`` times, and timed in CPU seconds of this process
(``time.process_time``, one thread): on a machine shared with other jobs the wall clock measures
their load more than this code (CPU seconds are inflated there too, less). Printed: CPU and wall
seconds per run, the particle count after resampling and estimates per scan (the same scene
must give the same tracking), and per birth model the ratio of the fastest call at 30 to that
at 10; ``--json`` records them all (with the machine, date and command) so that a quoted figure has a file.

    python benchmarks/bench_phd_births.py --scans 400 --runs 5 --targets 3 --json benchmarks/results/bench_phd_births.json
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_phd import SD, draw, truths  # noqa: E402
from run_info import write_figures  # noqa: E402

from pmsr_nn.rng import seeded_generator  # noqa: E402
from pmsr_nn.trackers.phd import PHDSpec, SMCPHD  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scans", type=int, default=400)
    ap.add_argument("--runs", type=int, default=5, help="runs per call (the study's block: 5)")
    ap.add_argument("--targets", type=int, default=3, help="targets alive throughout (the study: up to 3 at once)")
    ap.add_argument("--rounds", type=int, default=1)
    ap.add_argument("--json", type=Path, help="write every call's figures and the ratios here")
    args = ap.parse_args()
    torch.set_num_threads(1)
    B = args.runs
    truth = truths(args.scans, args.targets)
    data = {c: draw(truth, B, 0.9, c, 2016 + c) for c in (10, 30)}
    res: dict = {}
    calls: list[dict] = []
    for r in range(args.rounds):
        for births in ("adaptive", "every_detection"):
            for c in (10, 30):
                phd = SMCPHD(PHDSpec(adaptive_birth=births == "adaptive"), torch.tensor(SD, dtype=torch.float64), 0.9,
                             c / (41500 * 1000.0), 1.0)
                t0, w0 = time.process_time(), time.perf_counter()
                est = phd.run(*data[c], seeded_generator(1, r))
                cpu, wall = time.process_time() - t0, time.perf_counter() - w0
                res.setdefault((births, c), []).append(cpu)
                calls.append({"round": r, "births": births, "clutter": c, "cpu_s_per_run": cpu / B,
                              "wall_s_per_run": wall / B, "particles_mean": float(est.particles.double().mean()),
                              "estimates_per_scan": float(est.exists.sum(-1).double().mean())})
                print(f"round {r} {births:15s} clutter {c}: cpu {cpu / B:.2f} s per run (wall {wall / B:.2f}), "
                      f"particles {est.particles.double().mean():.0f}, "
                      f"est/scan {est.exists.sum(-1).double().mean():.2f}", flush=True)
    summary = {}
    for births in ("adaptive", "every_detection"):
        a, b = min(res[(births, 10)]), min(res[(births, 30)])
        print(f"{births}: min cpu per run {a / B:.2f} s (10) {b / B:.2f} s (30) ratio {b / a:.2f}")
        summary[births] = {"min_cpu_s_per_run_clutter_10": a / B, "min_cpu_s_per_run_clutter_30": b / B,
                           "ratio_30_over_10": b / a}
    if args.json:
        write_figures({"scans": args.scans, "runs": B, "targets": args.targets, "rounds": args.rounds,
                       "threads": 1, "calls": calls, "summary": summary}, args.json)


if __name__ == "__main__":
    main()
