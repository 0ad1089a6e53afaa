"""Are the fix initiator's covariances consistent? Position NEES of its fixes over many draws.

The fix initiator (:class:`pmsr_nn.trackers.fix_initiator.FixInitiator`) starts every track of a
scenario whose detections measure azimuth. Its agreement gate and each new track's covariance
read the linearised covariance ``H^-1 R H^-T`` of a pair's (bistatic range, azimuth) fix. This
script draws ``--draws`` positions uniformly over the annulus ``--radii`` (m) around the origin.
It measures each with the scenario's detection model and noise: every pair detects, no clutter.
It then prints the position NEES of:

* each pair's single fix;
* the fused fix of all agreeing pairs (the tracks' initial position; ``min_pairs`` 2).

For each, the NEES's median and mean, and the share beyond the chi-square(2) 99.9 % point (13.8),
overall and by the fix's distance from its receiver. A consistent covariance gives a median of
1.39, a mean of 2 and a share of 0.1 %.

    python evaluate/fix_consistency.py [--scenario evaluate/one_sky_bp.yaml] [--draws 4000] [--seed 0]
        [--radii 2000,12000] [--json evaluate/results/fix_consistency.json]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from datetime import date
from pathlib import Path

import torch

ROOT = Path(__file__).resolve().parents[1]
CHI2_2_999 = -2.0 * math.log(1e-3)
"""The chi-square(2) 99.9 % point: 13.82."""
DISTANCE_BANDS_M = (0.0, 3000.0, 6000.0, 9000.0, 12000.0, math.inf)
"""The bands of a fix's distance from its receiver (m) the single fixes' NEES is given for."""


def nees(err: torch.Tensor, cov: torch.Tensor) -> torch.Tensor:
    """``err (..., 2)`` under ``cov (..., 2, 2)``: ``err^T cov^-1 err`` ``(...)``."""
    return (err.unsqueeze(-2) @ torch.linalg.solve(cov, err.unsqueeze(-1))).flatten(-3)


def summary(v: torch.Tensor) -> dict:
    """The NEES sample's count, median, mean and share beyond :data:`CHI2_2_999`."""
    return {"n": int(v.numel()), "median": float(v.median()), "mean": float(v.mean()),
            "share_beyond_999": float((v > CHI2_2_999).double().mean())}


def draw_fixes(model, draws: int, radii: tuple[float, float], seed: int) -> dict:
    """NEES of the single and fused fixes of ``draws`` positions (module docstring), measured by
    ``model`` (a pair-layout :class:`~pmsr_nn.measurements.MeasurementModel` with azimuth)."""
    from pmsr_nn.trackers.fix_initiator import FixInitiator

    g = torch.Generator().manual_seed(seed)
    lo, hi = radii
    r = torch.sqrt(lo**2 + (hi**2 - lo**2) * torch.rand(draws, generator=g, dtype=torch.float64))  # uniform in area
    b = 2 * math.pi * torch.rand(draws, generator=g, dtype=torch.float64)
    n = 3 * len(model.pos_idx)
    pos_idx = list(model.pos_idx)
    x = torch.zeros(draws, n, dtype=torch.float64)
    x[:, pos_idx[0]], x[:, pos_idx[1]] = r * torch.sin(b), r * torch.cos(b)
    S, d = model.n_pairs, len(model.components)
    sd = torch.tensor(model.noise_std, dtype=torch.float64)
    z = (model.h(x).reshape(draws, S, d) + torch.randn(draws, S, d, generator=g, dtype=torch.float64) * sd).unsqueeze(2)
    ini = FixInitiator()
    pos, cov, ok = ini.fixes(z, model, n)
    truth = x[:, pos_idx]
    single = nees(pos[:, :, 0] - truth[:, None], cov[:, :, 0])  # (draws, S)
    ok = ok[:, :, 0]
    dist = (pos[:, :, 0] - model.geometry.pair_rx_positions(torch.float64)[None]).norm(dim=-1)
    bands = []
    for a, c in zip(DISTANCE_BANDS_M[:-1], DISTANCE_BANDS_M[1:]):
        sel = ok & (dist >= a) & (dist < c)
        if bool(sel.any()):
            bands.append({"from_m": a, "to_m": None if math.isinf(c) else c, **summary(single[sel])})
    other = torch.ones(n, dtype=torch.float64)
    gs, real = ini.initiate(z, torch.ones(draws, S, 1, dtype=torch.bool), model, n, other)
    first = real[:, 0]
    P = gs.P[first, 0][:, pos_idx][:, :, pos_idx]
    fused = nees(gs.x[first, 0][:, pos_idx] - truth[first], P)
    return {"single": summary(single[ok]), "single_by_distance": bands, "fused": summary(fused),
            "fused_share_of_draws": float(first.double().mean())}


def main(argv=None) -> int:
    from pmsr_nn.errors import ConfigError
    from pmsr_nn.harness.run.runner import prepare
    from pmsr_nn.harness.scenario.schema import load_scenario

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--scenario", default=str(ROOT / "evaluate" / "one_sky_bp.yaml"))
    ap.add_argument("--draws", type=int, default=4000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--radii", default="2000,12000", help="inner,outer radius (m) of the drawn positions")
    ap.add_argument("--json", help="write the record here")
    a = ap.parse_args(argv)
    try:
        radii = tuple(float(v) for v in a.radii.split(","))
        if len(radii) != 2 or not 0 <= radii[0] < radii[1]:
            raise ValueError(f"--radii must be inner,outer with 0 <= inner < outer, got {a.radii!r}")
        if a.draws < 10:
            raise ValueError(f"--draws must be at least 10, got {a.draws}")
        model = prepare(load_scenario(a.scenario)).cases[0].sensing.detection_model
        if model is None or "azimuth" not in model.components:
            raise ConfigError(f"{a.scenario}: its detections must measure azimuth (the fix initiator's input)")
    except (ConfigError, ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    start = time.perf_counter()
    with torch.no_grad():
        out = draw_fixes(model, a.draws, radii, a.seed)
    for name in ("single", "fused"):
        s = out[name]
        print(f"{name} fixes ({s['n']}): NEES median {s['median']:.2f} (1.39), mean {s['mean']:.1f} (2), "
              f"beyond the 99.9 % point {100 * s['share_beyond_999']:.1f} % (0.1 %)")
    for band in out["single_by_distance"]:
        print(f"  single, {band['from_m']:.0f}-{band['to_m'] or 'inf'} m from the receiver ({band['n']}): median "
              f"{band['median']:.2f}, beyond 99.9 % {100 * band['share_beyond_999']:.1f} %")
    scenario = Path(a.scenario).resolve()
    record = {"scenario": scenario.relative_to(ROOT).as_posix() if scenario.is_relative_to(ROOT) else a.scenario,
              "draws": a.draws, "seed": a.seed, "radii_m": list(radii), "noise_std": list(model.noise_std),
              "chi2_2_999": CHI2_2_999, **out,
              "info": {"date": date.today().isoformat(), "seconds": round(time.perf_counter() - start, 1),
                       "command": "python evaluate/fix_consistency.py " + " ".join(argv if argv is not None else sys.argv[1:])}}
    if a.json:
        Path(a.json).write_text(json.dumps(record, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
