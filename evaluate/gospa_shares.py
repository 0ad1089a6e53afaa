"""The shares of a row's mean GOSPA^p that are localisation, missed targets and false tracks, with
their Monte Carlo standard errors, from a block bank of one run per block (``pmsr evaluate
--per-block``), without re-running anything.

The report gives each share as the ratio of two means over the runs, ``mean(part) / mean(total)``
(each run's part and total: its per-scan GOSPA^p parts averaged over the set scans). Its standard
error here is the delta method's on the runs' (part, total) pairs, their covariance counted:

    se^2 = (var(part) / T^2 - 2 cov(part, total) part_mean / T^3 + var(total) part_mean^2 / T^4) / n

with ``T`` the mean total and ``n`` the runs. Each block must hold one run (a block's per-scan sums
add its runs, so its runs' own parts are not kept).

``--start-scans N`` splits the missed-target part in two: the scans within ``N`` of a target's birth
(from its birth scan on: a track not yet started) and the others (a track lost or dropped
for a while), so a late start is told from a lost track.

    python evaluate/gospa_shares.py evaluate/results/one_sky_bp_bank --row BP
    python evaluate/gospa_shares.py evaluate/results/one_sky_bp_bank --row BP --start-scans 3
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from pmsr_nn.errors import ConfigError
from pmsr_nn.harness.run.block_bank import bank_blocks, bank_identity, bank_scenario
from pmsr_nn.harness.run.block_sums import read_shard
from pmsr_nn.harness.scenario.prepared import set_scans_after

PARTS = {"localisation": "gospa_loc", "missed": "gospa_missed", "false": "gospa_false"}


def birth_scans(bank: Path, case: str) -> list[int]:
    """The scan of each target's birth in ``case`` (its ``birth_s`` over the recipe's interval)."""
    from pmsr_nn.simulation.recipe import TrackRecipe, load_recipe

    identity = bank_identity(bank)
    scenario = identity["scenario"]
    (c,) = [c for c in scenario["cases"] if c["name"] == case]
    if "targets" not in c:
        raise ConfigError(f"case {case!r} of {bank} names no targets with births (a world scenario): --start-scans "
                          "needs them")
    if scenario["recipe"] is None:  # the built-in recipe, as the harness takes it
        dt = TrackRecipe().motion.dt_s
    else:
        dt = load_recipe(Path(identity["base_dir"]) / scenario["recipe"]).motion.dt_s
    return [int(round(float(t.get("birth_s", 0.0)) / dt)) for t in c["targets"]]


def run_parts(bank: Path, case: str | None, row: str, start_scans: int = 0) -> dict[str, np.ndarray]:
    """``{part: (runs,)}``: each run's mean over the set scans of its GOSPA^p part (``PARTS``); with
    ``start_scans`` > 0 the missed part is split into ``missed at a start`` (scans within
    ``start_scans`` of a birth) and ``missed elsewhere`` (module docstring)."""
    scenario = bank_scenario(bank)
    if int(scenario["block_runs"]) != 1:
        raise ConfigError(f"{bank} has blocks of {scenario['block_runs']} runs: each run's parts need one run per block")
    cases = [c["name"] for c in scenario["cases"]]
    if case is None and len(cases) != 1:
        raise ConfigError(f"{bank} has cases {', '.join(cases)}: give --case")
    case = case or cases[0]
    if start_scans < 0:
        raise ConfigError(f"--start-scans must be at least 0, got {start_scans}")
    births = birth_scans(bank, case) if start_scans else []
    out: dict[str, list[float]] = {p: [] for p in PARTS}
    for folder in bank_blocks(bank):
        qs = read_shard(folder)[1].sums.get(case, {}).get(row)
        if qs is None or "gospa_false" not in qs:
            raise ConfigError(f"{folder} has no GOSPA parts of row {row!r} in case {case!r}")
        K = qs["gospa_false"].shape[-1]
        k = set_scans_after(K, int(scenario["warmup_steps"])).numpy()
        for part, q in PARTS.items():
            out[part].append(float(qs[q][0, k].mean()))
        if births:
            start = np.zeros(K, dtype=bool)
            for b in births:
                start[b:b + start_scans] = True
            missed = qs["gospa_missed"][0]
            out.setdefault("missed at a start", []).append(float((missed * start)[k].sum() / k.sum()))
    parts = {p: np.asarray(v) for p, v in out.items()}
    if births:  # the two halves of the missed part, in the order the report gives the parts
        at_start = parts.pop("missed at a start")
        parts = {"localisation": parts["localisation"], "missed at a start": at_start,
                 "missed elsewhere": parts["missed"] - at_start, "false": parts["false"]}
    return parts


def shares(parts: dict[str, np.ndarray]) -> dict[str, tuple[float, float]]:
    """``{part: (share, standard error)}`` of the runs' parts (module docstring)."""
    total = sum(parts.values())
    n, T = len(total), float(total.mean())
    if n < 2 or T <= 0:
        raise ConfigError(f"{n} run(s) with mean GOSPA^p {T:g}: a share and its error need 2 runs and a positive total")
    out = {}
    for part, v in parts.items():
        c = np.cov(np.stack([v, total]), ddof=1)
        m = float(v.mean())
        var = (c[0, 0] / T**2 - 2 * c[0, 1] * m / T**3 + c[1, 1] * m**2 / T**4) / n
        out[part] = (m / T, math.sqrt(max(var, 0.0)))  # a variance >= 0 but for rounding
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("bank", type=Path)
    ap.add_argument("--row", required=True, help="the row of the bank")
    ap.add_argument("--case", help="the case (default: the bank's only case)")
    ap.add_argument("--start-scans", type=int, default=0,
                    help="split the missed part: within this many scans of a target's birth, and elsewhere (0: no split)")
    a = ap.parse_args()
    parts = run_parts(a.bank, a.case, a.row, a.start_scans)
    n = len(parts["false"])
    print(f"{a.row!r} over {n} runs; runs with any false-track charge: {int((parts['false'] > 0).sum())}")
    for part, (share, se) in shares(parts).items():
        print(f"{part} share of the mean GOSPA^p: {100 * share:.1f} ± {100 * se:.1f} %")


if __name__ == "__main__":
    try:
        main()
    except ConfigError as exc:
        raise SystemExit(f"error: {exc}") from None
