"""SMC-PHD on one_sky: the likelihood formed in range windows against the full product, and the particle counts.

One run (block 0) of a study's SMC-PHD row, the filter alone (its labelling is the same in every
configuration): the Cartesian SMC-PHD called as the row calls it (``pmsr_nn.methods.phd.make_filter``)

* ``full``: every particle-detection pair formed (``window_component = None``), at the row's counts;
* ``windows``: only the pairs inside each particle's range window (the default), at the row's counts;
* ``windows_default_counts``: the windows at the kind's default counts (2000 per target, 200 per birth),
  where the row sets others;
* ``full_default_counts``: the full product at the default counts (the filter before issue 57).

The four alternate, ``--repeats`` times, in one process with one thread; the figures are each
one's median and the ratios of the medians. ``identical``: whether the full product and the windows
gave the same estimates bit for bit, at the row's counts and at the default counts (they form the
same numbers: ``CartesianPHD.weighted_likelihood``).

    OMP_NUM_THREADS=1 python benchmarks/bench_phd_windows.py evaluate/one_sky.yaml \\
        --json benchmarks/results/bench_phd_windows.json
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from dataclasses import replace
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run_info import write_figures  # noqa: E402
from scenario import first_block  # noqa: E402

from pmsr_nn.methods import MethodCall, method_stream  # noqa: E402
from pmsr_nn.methods.phd import OPTIONS, make_filter  # noqa: E402
from pmsr_nn.rng import seeded_generator  # noqa: E402

COUNTS = ("particles_per_target", "particles_per_birth")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenario", type=Path)
    ap.add_argument("--row", default="SMC-PHD + GTDA", help="the smc_phd row to time")
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--json", type=Path, help="write the figures here")
    args = ap.parse_args()
    torch.set_num_threads(1)
    sc, setup, case, products = first_block(args.scenario)
    (spec,) = [m for m in setup.methods if m.name == args.row]
    kind = setup.kinds[spec.name]
    seed = (sc.seed, 0, 0)
    default_spec = replace(spec, options={**spec.options, **{k: OPTIONS[k].default for k in COUNTS}})

    def run(method, windows: bool):
        call = MethodCall(method, products[kind.reads], case.alive, setup.models, case.sensing,
                          setup.resources[spec.name], seed)
        phd = make_filter(call)
        if not windows:
            phd.window_component = None
        det = call.product.scans
        t0 = time.perf_counter()
        est = phd.run(det.z, det.valid, seeded_generator(*seed, method_stream(spec.name)))
        return time.perf_counter() - t0, est

    configs = {"full": (spec, False), "windows": (spec, True), "windows_default_counts": (default_spec, True),
               "full_default_counts": (default_spec, False)}
    run(spec, True)  # warm-up, untimed
    seconds = {name: [] for name in configs}
    estimates = {}
    for r in range(args.repeats):
        for name, (method, windows) in configs.items():
            t, est = run(method, windows)
            seconds[name].append(t)
            estimates[name] = est
            print(f"repeat {r + 1}/{args.repeats} {name}: {t:.1f} s", flush=True)
    same = lambda a, b: all(torch.equal(torch.nan_to_num(getattr(a, f)), torch.nan_to_num(getattr(b, f)))
                            for f in ("x", "P", "mass", "exists", "expected", "particles"))
    identical = {"row_counts": same(estimates["full"], estimates["windows"]),
                 "default_counts": same(estimates["full_default_counts"], estimates["windows_default_counts"])}
    med = {name: statistics.median(v) for name, v in seconds.items()}
    figures = {"scenario": str(args.scenario), "row": args.row, "counts": {k: spec.option(k) for k in COUNTS},
               "seconds": seconds, "median_s": med, "identical": identical,
               "ratio_windows_to_full": med["windows"] / med["full"],
               "ratio_windows_to_full_default_counts": med["windows_default_counts"] / med["full_default_counts"],
               "ratio_counts_to_default_counts": med["windows"] / med["windows_default_counts"],
               "ratio_to_before": med["windows"] / med["full_default_counts"]}
    print(f"windows / full {figures['ratio_windows_to_full']:.2f} at the row's counts, "
          f"{figures['ratio_windows_to_full_default_counts']:.2f} at the defaults (identical estimates: {identical}); "
          f"row's counts / default counts {figures['ratio_counts_to_default_counts']:.2f}; "
          f"against the full product at the default counts {figures['ratio_to_before']:.2f}")
    write_figures(figures, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
