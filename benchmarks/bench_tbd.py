"""Benchmark: track-before-detect on range-Doppler maps (issue 16's targets), the seed's Table 2 time column.

The set-up is evaluate/remotesensing2020_icmb.yaml's case ``mixed`` and its ``modified ICMB``
method (three satellites, 20 frames of 2 s, map SNRs 8, 9, 10 dB, 10 Hz x 60 m cells, 2,000-10,000
particles per component, 10,000 birth particles per frame), through the runner's own calls
(:func:`~pmsr_nn.harness.run.blocks.draw_block`, :func:`~pmsr_nn.harness.run.blocks.call_method`). Timed,
in this process, the median of ``--repeats`` calls after one warm-up:

* the modified ICMB (online SNR, ascending order) on one run, for every sub-area of Table 2
  (1x1 .. 11x11 and the whole map; the whole map once), maps drawn inside the timing (the seed's
  times include everything too); the map draws alone beside them;
* the 5x5 filter on one run with the seed's SNR estimate (``snr_estimator: max``) beside the
  scenario's (the bias-corrected bootstrap by default): what the correction costs (one run's
  time also depends on how many particles its filter holds, which the two estimates' different
  random draws change: the batched pair below is the steadier comparison);
* the 5x5 filter on ``--batch`` runs per call (runs batched), divided by the runs, with the
  scenario's estimate and with the seed's;
* memory: ``--memory-runs`` runs in blocks of ``--batch`` (what ``pmsr evaluate`` does), the
  process's peak resident memory before and after.

    python benchmarks/bench_tbd.py --json benchmarks/results/bench_tbd.json
"""

from __future__ import annotations

import argparse
import dataclasses
import resource
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run_info import median_seconds, write_figures  # noqa: E402

from pmsr_nn.harness.run.blocks import call_method, draw_block  # noqa: E402
from pmsr_nn.harness.run.runner import prepare  # noqa: E402
from pmsr_nn.harness.scenario.schema import load_scenario  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


class Bench:
    """The scenario's first case with blocks of ``runs`` runs, and its ``modified ICMB`` method."""

    def __init__(self, path: Path, runs: int, blocks: int):
        sc = load_scenario(path)
        self.sc = sc.replace(mc_runs=runs * blocks, block_runs=runs, cases=sc.cases[:1])
        self.setup = prepare(self.sc)
        self.case = self.setup.cases[0]
        self.base = next(m for m in self.setup.methods if m.name == "modified ICMB")

    def spec(self, half, **options):
        return dataclasses.replace(self.base, options={**self.base.options, "subarea_half": half, **options})

    def call(self, spec, block: int, maps_only: bool = False):
        _, products = draw_block(self.setup, 0, block)
        if maps_only:
            for k in range(self.case.steps):
                products["rd_maps"].frame(k)
            return None
        return call_method(self.setup, spec, self.case, products, (self.sc.seed, 0, block))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", type=Path, default=ROOT / "evaluate" / "remotesensing2020_icmb.yaml")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--batch", type=int, default=10)
    ap.add_argument("--memory-runs", type=int, default=100)
    ap.add_argument("--no-full", action="store_true", help="skip the whole-map sub-area (about a minute per run)")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    one = Bench(args.scenario, 1, args.repeats + 2)
    scene = one.case.sensing.rd_maps
    grid = scene.grid
    figures = {"threads": torch.get_num_threads(), "frames": scene.frames, "maps": scene.P,
               "map_cells": [grid.D, grid.U], "subarea_seconds_per_run": {}}
    figures["maps_only_seconds_per_run"] = median_seconds(lambda: one.call(None, 0, maps_only=True), args.repeats)
    print(f"maps alone: {figures['maps_only_seconds_per_run']:.3f} s per run ({grid.D} x {grid.U} cells x "
          f"{scene.P} maps x {scene.frames} frames)")
    halves = [0, 1, 2, 3, 4, 5] + ([] if args.no_full else [None])
    for h in halves:
        spec = one.spec(h)
        name = "full" if h is None else f"{2 * h + 1}x{2 * h + 1}"
        if h is not None:
            s = median_seconds(lambda: one.call(spec, 1), args.repeats)
        else:
            t0 = time.perf_counter()
            one.call(spec, 1)
            s = time.perf_counter() - t0
        figures["subarea_seconds_per_run"][name] = s
        print(f"modified ICMB, {name:>5} sub-area: {s:.3f} s per 20-frame run (one run per call)")
    spec = one.spec(2, snr_estimator="max")
    s = median_seconds(lambda: one.call(spec, 1), args.repeats)
    figures["seed_max_estimate_5x5_seconds_per_run"] = s
    print(f"modified ICMB, 5x5, the seed's max SNR estimate: {s:.3f} s per 20-frame run (one run per call)")
    batched = Bench(args.scenario, args.batch, max(1, -(-args.memory_runs // args.batch)))
    s = median_seconds(lambda: batched.call(batched.base, 0), max(1, args.repeats - 1))
    figures["batched_seconds_per_run"] = s / args.batch
    print(f"modified ICMB, 5x5, {args.batch} runs per call: {s / args.batch:.3f} s per run")
    spec = batched.spec(2, snr_estimator="max")
    s = median_seconds(lambda: batched.call(spec, 0), max(1, args.repeats - 1))
    figures["seed_max_estimate_batched_seconds_per_run"] = s / args.batch
    print(f"modified ICMB, 5x5, the seed's max SNR estimate, {args.batch} runs per call: {s / args.batch:.3f} s per run")
    before = peak_rss_mib()
    t0 = time.perf_counter()
    for block in range(batched.sc.n_blocks):
        batched.call(batched.base, block)
    figures["memory"] = {"runs": batched.sc.mc_runs, "block_runs": args.batch, "seconds": time.perf_counter() - t0,
                         "peak_rss_before_mib": before, "peak_rss_after_mib": peak_rss_mib()}
    print(f"{batched.sc.mc_runs} runs in blocks of {args.batch}: {figures['memory']['seconds']:.0f} s, peak RSS "
          f"{before:.0f} -> {peak_rss_mib():.0f} MiB")
    write_figures(figures, args.json)


if __name__ == "__main__":
    main()
