"""Two rows compared run by run from block banks (``pmsr evaluate --per-block``), without re-running anything.

Each block of a bank keeps every row's per-run GOSPA^p (``gospa_run``: the run's mean over its
scored scans); a block scored over other scans than its case's set scans (made before issue 55's
fix) is read as ``pmsr merge`` reads it, re-derived from its per-scan sums
(:mod:`pmsr_nn.harness.run.set_window`). For row A of bank A and row B of bank B, on the runs both banks hold, this prints:

* each row's GOSPA over those runs (the p-th root of the mean GOSPA^p, as the report gives it);
* the paired difference B - A of the runs' own GOSPA (the p-th root of each run's GOSPA^p), its
  mean ± its standard error, and how many runs are better, worse or the same (within ``--same`` m);
* the ratio A / B of the two rows' GOSPA, ± its standard error by the delta method on the paired
  runs' GOSPA^p (the runs' covariance counted), and the runs' own ratios: their range and how many
  are below ``--below``;
* the largest relative difference of the runs' GOSPA^p: 0 where the two rows are the same tracker
  on the same draws (a row re-recorded in another study).

    python evaluate/paired_banks.py evaluate/results/one_sky_stonesoup_bank evaluate/results/one_sky_stonesoup_bank --row-a "Stone Soup JPDA" --row-b BP
    python evaluate/paired_banks.py /tmp/old_bank evaluate/results/one_sky_bp_bank --row-a BP
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from pmsr_nn.errors import ConfigError
from pmsr_nn.harness.run.block_bank import bank_blocks, bank_scenario
from pmsr_nn.harness.run.block_sums import read_shard
from pmsr_nn.harness.run.set_window import rescore_runs
from pmsr_nn.harness.scenario.prepared import set_scans_after


def run_powers(bank: Path, case: str | None, row: str) -> tuple[dict[int, float], float]:
    """``{run index: GOSPA^p}`` of ``row`` in ``case`` (None: the bank's only case) over the blocks
    ``bank`` holds, and the order ``p`` of its scenario's set metrics."""
    scenario = bank_scenario(bank)
    p, runs_per_block, mc_runs = float(scenario["set_metrics"]["p"]), int(scenario["block_runs"]), int(scenario["mc_runs"])
    cases = [c["name"] for c in scenario["cases"]]
    if case is None and len(cases) != 1:
        raise ConfigError(f"{bank} has cases {', '.join(cases)}: give --case")
    case = case or cases[0]
    runs_of = lambda b: len(range(b * runs_per_block, min(mc_runs, (b + 1) * runs_per_block)))
    out: dict[int, float] = {}
    for folder in bank_blocks(bank):
        _, bs = read_shard(folder)
        qs = bs.sums.get(case, {}).get(row)
        if qs is None or "gospa_run" not in qs:
            raise ConfigError(f"{folder} has no GOSPA per run of row {row!r} in case {case!r}")
        bs.sums = {case: {row: qs}}
        rescore_runs([bs], {case: set_scans_after(qs["ospa"].shape[-1], int(scenario["warmup_steps"])).numpy()}, runs_of)
        out.update({bs.blocks[0] * runs_per_block + i: float(v) for i, v in enumerate(qs["gospa_run"])})
    return out, p


def compare(a: dict[int, float], b: dict[int, float], p: float, same_m: float = 0.05) -> dict:
    """The figures of the module docstring for the runs ``a`` and ``b`` (``{run: GOSPA^p}``) share."""
    runs = sorted(set(a) & set(b))
    if len(runs) < 2:
        raise ConfigError(f"the two banks share {len(runs)} run(s); a paired comparison needs at least 2")
    pa, pb = np.array([a[r] for r in runs]), np.array([b[r] for r in runs])
    ga, gb = pa ** (1 / p), pb ** (1 / p)
    d = gb - ga
    n = len(runs)
    ma, mb = pa.mean(), pb.mean()
    ratio = (ma / mb) ** (1 / p)
    cov = np.cov(np.stack([pa, pb]), ddof=1) / n
    grad = ratio / p * np.array([1 / ma, -1 / mb])  # d ratio / d (mean a, mean b)
    return {"runs": n, "gospa_a_m": ma ** (1 / p), "gospa_b_m": mb ** (1 / p), "paired_b_minus_a_m": d.mean(),
            "paired_se_m": d.std(ddof=1) / math.sqrt(n), "better": int((d < -same_m).sum()),
            "worse": int((d > same_m).sum()), "same": int((abs(d) <= same_m).sum()), "ratio_a_over_b": ratio,
            "ratio_se": math.sqrt(max(float(grad @ cov @ grad), 0.0)),  # a quadratic form >= 0 but for rounding
            "run_ratios": ga / np.maximum(gb, 1e-300),
            "largest_relative_difference": float(np.max(np.abs(pb - pa) / np.maximum(np.abs(pa), 1e-300)))}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bank_a", type=Path)
    ap.add_argument("bank_b", type=Path)
    ap.add_argument("--row-a", required=True, help="the row of bank A")
    ap.add_argument("--row-b", help="the row of bank B (default: --row-a)")
    ap.add_argument("--case", help="the case (default: the banks' only case)")
    ap.add_argument("--same", type=float, default=0.05, help="runs within this many metres count as the same")
    ap.add_argument("--below", type=float, default=3.0, help="count the runs whose ratio A / B is below this")
    a = ap.parse_args()
    row_b = a.row_b or a.row_a
    pa, p = run_powers(a.bank_a, a.case, a.row_a)
    pb, p_b = run_powers(a.bank_b, a.case, row_b)
    if p != p_b:
        raise ConfigError(f"the banks score GOSPA with different orders p ({p:g} and {p_b:g})")
    r = compare(pa, pb, p, a.same)
    print(f"{r['runs']} runs both banks hold; GOSPA (m): A {a.row_a!r} {r['gospa_a_m']:.2f}, B {row_b!r} "
          f"{r['gospa_b_m']:.2f}")
    print(f"paired B - A, each run's GOSPA: {r['paired_b_minus_a_m']:+.2f} ± {r['paired_se_m']:.2f} m "
          f"({r['better']} runs better, {r['worse']} worse, {r['same']} within {a.same:g} m)")
    print(f"ratio A / B of the rows' GOSPA: {r['ratio_a_over_b']:.2f} ± {r['ratio_se']:.2f}; largest relative "
          f"difference of a run's GOSPA^p: {r['largest_relative_difference']:.3g}")
    ratios = r["run_ratios"]
    print(f"runs' own ratios A / B: {ratios.min():.2f} to {ratios.max():.2f}, below {a.below:g} in "
          f"{int((ratios < a.below).sum())} of {len(ratios)}")


if __name__ == "__main__":
    try:
        main()
    except ConfigError as exc:
        raise SystemExit(f"error: {exc}") from None
