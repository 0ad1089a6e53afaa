"""Benchmark: track-before-detect on range-Doppler maps (issue 16's targets), the seed's Table 2 time column.

The set-up is evaluate/remotesensing2020_icmb.yaml's scene and filter (three satellites, 20 frames
of 2 s, map SNRs 8, 9, 10 dB, 10 Hz x 60 m cells, 2,000-10,000 particles per component, 10,000 birth
particles per frame). Timed, in this process, the median of ``--repeats`` calls after one warm-up:

* the modified ICMB (online SNR, ascending order) on one run, for every sub-area of Table 2
  (1x1 .. 11x11 and the whole map; the whole map once), maps drawn inside the timing (the seed's
  times include everything too); the map draws alone beside them;
* the 5x5 filter on ``--batch`` runs per call (runs batched), divided by the runs;
* memory: ``--memory-runs`` runs in blocks of ``--batch`` (what ``pmsr evaluate`` does), the
  process's peak resident memory before and after.

    python benchmarks/bench_tbd.py --json benchmarks/results/bench_tbd.json
"""

from __future__ import annotations

import argparse
import resource
import sys
import time
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run_info import median_seconds, write_figures  # noqa: E402

from pmsr_nn.config import load_yaml  # noqa: E402
from pmsr_nn.harness.tbd_study import tbd_from_dict  # noqa: E402
from pmsr_nn.tbd.run import draw_maps, simulate_and_run  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]


def peak_rss_mib() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def one_call(scene, spec, runs: int, seed: int, maps_only: bool = False):
    if maps_only:
        _, product = draw_maps(scene, runs, seed)
        for k in range(scene.frames):
            product.frame(k)
        return None
    return simulate_and_run(scene, spec, runs, seed)[0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", type=Path, default=ROOT / "evaluate" / "remotesensing2020_icmb.yaml")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--batch", type=int, default=10)
    ap.add_argument("--memory-runs", type=int, default=100)
    ap.add_argument("--no-full", action="store_true", help="skip the whole-map sub-area (about a minute per run)")
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    sc = tbd_from_dict(load_yaml(args.scenario), args.scenario.parent)
    scene = sc.scene
    base = next(m for m in sc.methods if m.name == "modified ICMB")
    spec0 = sc.method_spec(base)
    import dataclasses

    figures = {"threads": torch.get_num_threads(), "frames": scene.frames, "maps": scene.P,
               "map_cells": [scene.grid.D, scene.grid.U], "subarea_seconds_per_run": {}}
    figures["maps_only_seconds_per_run"] = median_seconds(lambda: one_call(scene, spec0, 1, 0, maps_only=True), args.repeats)
    print(f"maps alone: {figures['maps_only_seconds_per_run']:.3f} s per run ({scene.grid.D} x {scene.grid.U} cells x "
          f"{scene.P} maps x {scene.frames} frames)")
    halves = [0, 1, 2, 3, 4, 5] + ([] if args.no_full else [None])
    for h in halves:
        spec = dataclasses.replace(spec0, subarea_half=h)
        name = "full" if h is None else f"{2 * h + 1}x{2 * h + 1}"
        reps = 1 if h is None else args.repeats
        s = median_seconds(lambda: one_call(scene, spec, 1, 7), reps) if h is not None else \
            (lambda t0: (one_call(scene, spec, 1, 7), time.perf_counter() - t0)[1])(time.perf_counter())
        figures["subarea_seconds_per_run"][name] = s
        print(f"modified ICMB, {name:>5} sub-area: {s:.3f} s per 20-frame run (one run per call)")
    s = median_seconds(lambda: one_call(scene, spec0, args.batch, 9), max(1, args.repeats - 1))
    figures["batched_seconds_per_run"] = s / args.batch
    print(f"modified ICMB, 5x5, {args.batch} runs per call: {s / args.batch:.3f} s per run")
    before = peak_rss_mib()
    t0 = time.perf_counter()
    for block in range(0, args.memory_runs, args.batch):
        one_call(scene, spec0, min(args.batch, args.memory_runs - block), 100 + block)
    figures["memory"] = {"runs": args.memory_runs, "block_runs": args.batch, "seconds": time.perf_counter() - t0,
                         "peak_rss_before_mib": before, "peak_rss_after_mib": peak_rss_mib()}
    print(f"{args.memory_runs} runs in blocks of {args.batch}: {figures['memory']['seconds']:.0f} s, peak RSS "
          f"{before:.0f} -> {peak_rss_mib():.0f} MiB")
    write_figures(figures, args.json)


if __name__ == "__main__":
    main()
